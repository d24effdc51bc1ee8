"""A scenario's online settings (moving obstacles, perception, online
bounds: docs/spec.md, SPEC 12) and their checks."""

import dataclasses

from drake_cfvol.exceptions import ParameterError, ScenarioError

__all__ = ["OnlineConfig", "check_online"]


@dataclasses.dataclass
class OnlineConfig:
    """Online re-estimation and perception settings (used when the scenario
    has ``moving_obstacles``; docs/spec.md, SPEC 12).

    Attributes:
        camera_period: s between camera images.
        bounds_period: s between bounds updates (an update computed at t is
            in force from t + bounds_period).
        horizon: stretches ahead of the path index searched again at an
            update.
        cell: the obstacle map's cell side, m.
        obstacle_speed: the speed assumed for what the camera sees, m/s:
            the map lends each occupied cell's height to the cells it could
            reach before the next bounds are in force.
        width, height: the camera's image, px.
    """

    camera_period: float = 0.05
    bounds_period: float = 0.05
    horizon: int = 8
    cell: float = 0.05
    obstacle_speed: float = 0.5
    width: int = 320
    height: int = 240



def check_online(scenario, where) -> None:
    """Moving obstacles (items counted from 1), the perception mode and the
    online settings."""
    for i, o in enumerate(scenario.moving_obstacles, 1):
        try:
            o.check()
        except ParameterError as e:
            raise ScenarioError(where, f"moving_obstacles item {i}", str(e)) from None
    names = [o.name for o in scenario.moving_obstacles]
    if len(set(names)) != len(names):
        raise ScenarioError(where, "moving_obstacles", f"need distinct names, got {names}")
    if scenario.perception not in (None, "camera", "truth"):
        raise ScenarioError(where, "perception", f"must be camera or truth (or left out), got "
                            f"{scenario.perception!r}")
    if scenario.perception_mode is not None and scenario.plant_config is not None:
        raise ScenarioError(where, "moving_obstacles" if scenario.perception is None else "perception",
                            "work in kinematic runs only: leave plant_config out")
    if scenario.perception == "truth" and not scenario.moving_obstacles:
        raise ScenarioError(where, "perception", "is truth, which gives the moving obstacles' poses: add "
                            "moving_obstacles (or use camera)")
    o = scenario.online
    for name in ("camera_period", "bounds_period", "cell"):
        if not getattr(o, name) > 0:
            raise ScenarioError(where, f"online.{name}", f"must be > 0, got {getattr(o, name)!r}")
    if not o.obstacle_speed >= 0:
        raise ScenarioError(where, "online.obstacle_speed", f"must be >= 0 m/s, got {o.obstacle_speed!r}")
    if not o.horizon >= 1:
        raise ScenarioError(where, "online.horizon", f"must be >= 1 stretch, got {o.horizon!r}")
    if not (o.width >= 16 and o.height >= 16):
        raise ScenarioError(where, "online.width", f"the camera needs at least 16 x 16 px, got {o.width} x "
                            f"{o.height}")
