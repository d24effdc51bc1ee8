"""The part of :class:`~drake_cfvol.scene.workcell.Workcell` that reads the
robot from its plant: joints, limits, frames, the held degrees of freedom,
and the settings with their defaults from the robot's geometry (reach,
height-map extent)."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.tree import JointIndex

from drake_cfvol.scene.queries import WorkcellQueries
from drake_cfvol.scene.robot import robot_instances, robot_joints

__all__ = ["WorkcellSetup"]


class WorkcellSetup(WorkcellQueries):
    """Reading the robot and the settings (a part of
    :class:`~drake_cfvol.scene.workcell.Workcell`: it uses the workcell's
    plant, robot, ``_fail`` and the queries' ``_memo``)."""

    def _note_held(self) -> None:
        """Notes the degrees of freedom outside the robot, held at the
        plant's default configuration."""
        plant = self.plant
        held = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
        held = [j for j in held if j.num_positions() > 0 and j.model_instance() != self.robot]
        if held:
            names = ", ".join(
                str(j.name()) if j.type_name() != "quaternion_floating" else f"{j.child_body().name()} (free body)"
                for j in held
            )
            self.notes.append(f"held at the plant's default configuration: {names}")

    def _read_joints(self, joint_limits, acceleration_limits=(), jerk_limits=()) -> None:
        """The robot's joints, their kinds and limits (overrides applied)."""
        plant = self.plant
        joints = robot_joints(plant, self.robot)
        self.joint_names = [j.name() for j in joints]
        if not joints:
            raise self._fail(f"the robot '{self.robot_name}' has no joints with positions.", "robot")
        self.revolute = np.array([j.type_name() == "revolute" for j in joints])
        lower = np.array([j.position_lower_limits()[0] for j in joints], float)
        upper = np.array([j.position_upper_limits()[0] for j in joints], float)
        for jname, lim in joint_limits.items():
            if jname not in self.joint_names:
                raise self._fail(
                    f"joint_limits names joint '{jname}', which the robot lacks "
                    f"(joints: {', '.join(self.joint_names)}).",
                    jname,
                )
            if not (len(lim) == 2 and float(lim[0]) < float(lim[1])):
                raise self._fail(f"joint_limits.{jname} must be [lower, upper] with lower < upper.", jname)
            i = self.joint_names.index(jname)
            lower[i], upper[i] = float(lim[0]), float(lim[1])
        self.position_lower = lower
        self.position_upper = upper
        self.velocity_limits = np.array([j.velocity_upper_limits()[0] for j in joints], float)
        model = np.array([j.acceleration_upper_limits()[0] for j in joints], float)
        self.acceleration_limits = self._per_joint(acceleration_limits, "acceleration_limits", "rad/s^2", model)
        self.jerk_limits = self._per_joint(jerk_limits, "jerk_limits", "rad/s^3", np.full(len(joints), np.inf))

    def _per_joint(self, values, key: str, unit: str, default) -> np.ndarray:
        """A per-joint limit of the settings (> 0; inf: none), or ``default`` where none is given."""
        if values is None or not len(values):
            return np.asarray(default, float)
        v = np.asarray(values, float)
        if v.shape != (len(self.joint_names),) or np.isnan(v).any() or (v <= 0).any():
            raise self._fail(
                f"{key} must be one limit > 0 per joint ({len(self.joint_names)}: {', '.join(self.joint_names)}; "
                f"{unit}, .inf: none), got {list(values)}.",
                key,
            )
        return v

    def _read_frames(self, tool_frame, base_frame, rail_joint) -> None:
        """The tool and base frames and the rail joint."""
        plant = self.plant
        self.tool_frame = self._frame(tool_frame, "tool_frame")
        self.base_frame = (
            self._robot_root(plant).body_frame() if base_frame is None else self._frame(base_frame, "base_frame")
        )
        self.rail_joint = rail_joint
        if self.rail_joint is not None and self.rail_joint not in self.joint_names:
            raise self._fail(
                f"rail_joint '{self.rail_joint}' is not a joint of the robot (joints: {', '.join(self.joint_names)}).",
                "rail_joint",
            )

    def _frame(self, name: str, key: str):
        """A frame of the robot (or of a body it moves, e.g. a gripper's) by name."""
        plant = self.plant
        if plant.HasFrameNamed(name, self.robot):
            return plant.GetFrameByName(name, self.robot)
        for inst in robot_instances(plant, self.robot)[1:]:
            if plant.HasFrameNamed(name, inst):
                return plant.GetFrameByName(name, inst)
        frames = sorted({plant.get_frame(i).name() for i in plant.GetFrameIndices(self.robot)})
        raise self._fail(
            f"{key} '{name}' is not a frame of '{self.robot_name}' (its frames: {', '.join(frames)}).", key
        )

    def _read_settings(self, reach, origin, size, params, configurations) -> None:
        """Reach, height map extent, parameter overrides, named configurations."""
        if reach is not None and not (reach >= 0 and np.isfinite(reach)):
            raise self._fail(
                f"reach must be a finite distance >= 0 (m; 0 or left out: from the robot's geometry), got {reach}.",
                "reach",
            )
        self._given_reach = float(reach) if reach else None
        self._given_extent = [None if v is None else np.asarray(v, float) for v in (origin, size)]
        for label, v in zip(("origin", "size"), self._given_extent):
            if v is not None and v.shape != (2,):
                raise self._fail(f"height_map.{label} must be [x, y] (m), got {v.size} values.", "height_map")
            if v is not None and not np.isfinite(v).all():
                raise self._fail(f"height_map.{label} must be finite numbers (m), got {v.tolist()}.", "height_map")
        size = self._given_extent[1]
        if size is not None and not (size > 0).all():
            raise self._fail(f"height_map.size must be > 0 in x and y (m), got {size.tolist()}.", "height_map")
        self.params = dict(params)
        self.configurations: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for cname, (start, goal) in configurations.items():
            start, goal = np.asarray(start, float), np.asarray(goal, float)
            for label, q in (("start", start), ("goal", goal)):
                key = f"cfvol.configurations.{cname}.{label}"
                line = key if key in self._lines else cname
                if q.shape != (self.num_joints,):
                    raise self._fail(
                        f"configurations.{cname}.{label} has {q.size} values; the robot has {self.num_joints} "
                        f"joints ({', '.join(self.joint_names)}).",
                        line,
                    )
                if not np.isfinite(q).all():
                    raise self._fail(
                        f"configurations.{cname}.{label} must be finite numbers (rad or m), got {q.tolist()}.", line
                    )
            self.configurations[str(cname)] = (start, goal)

    @property
    def reach(self) -> float:
        """The volume's activation radius, m: as given, else a bound on how
        far the robot's geometry lies from its first revolute joint's axis
        point (the kernel's lever arms)."""
        if self._given_reach is not None:
            return self._given_reach
        return self._memo("default_reach", self._default_reach)

    def _default_reach(self) -> float:
        a = self.scene_arrays()
        rev = np.flatnonzero(a.revolute)
        return float(a.reach[rev[0]].max() if len(rev) else a.reach.max())

    @property
    def height_map_origin(self) -> np.ndarray:
        """(x, y) of the height map's corner, m (default: see :attr:`height_map_size`)."""
        return self._extent()[0]

    @property
    def height_map_size(self) -> np.ndarray:
        """(x_dim, y_dim) of the height map, m: as given, else the square of
        the reach (plus 0.2 m) around the base, stretched over a rail's travel."""
        return self._extent()[1]

    def _extent(self):
        origin, size = self._given_extent
        if origin is not None and size is not None:
            return origin.copy(), size.copy()

        def make():
            pad = self.reach + 0.2
            q0 = np.clip(self.slice.q_default[self.slice.qidx], self.position_lower, self.position_upper)
            qs = [q0]
            if self.rail_joint is not None:
                j = self.joint_names.index(self.rail_joint)
                for v in self.finite_limits("the height map's extent along the rail")[0][j], self.position_upper[j]:
                    q = q0.copy()
                    q[j] = v
                    qs.append(q)
            pts = np.array([self.base_frame.CalcPoseInWorld(self.plant_context(q)).translation()[:2] for q in qs])
            lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
            return lo, hi - lo

        o, sz = self._memo("default_extent", make)
        return (origin if origin is not None else o).copy(), (size if size is not None else sz).copy()

    # -- loading helpers -------------------------------------------------

    def _robot_root(self, plant):
        bodies = [plant.get_body(b) for b in plant.GetBodyIndices(self.robot)]
        for b in bodies:
            parent = [
                j
                for j in (plant.get_joint(i) for i in plant.GetJointIndices(self.robot))
                if j.child_body().index() == b.index()
            ]
            if not parent:
                return b
        return bodies[0]
