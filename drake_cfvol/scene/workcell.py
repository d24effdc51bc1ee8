"""Workcells: a robot and its obstacles, loaded from one YAML file.

The file's schema is :mod:`drake_cfvol.scene.schema`; the queries on the
scene are :mod:`drake_cfvol.scene.queries`.

Every obstacle is a body outside the robot's model instance, welded to the
world, with proximity geometry; the floor is one of them.
"""

import copy
import dataclasses
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy.typing as npt
from pydrake.common.schema import Transform
from pydrake.geometry import Role, SceneGraph
from pydrake.multibody.parsing import ModelDirectives, Parser, ProcessModelDirectives
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex, ModelInstanceIndex
from pydrake.planning import RobotDiagram, RobotDiagramBuilder

from drake_cfvol.exceptions import (
    ParameterError,
    StationError,
    UnknownCellError,
    WorkcellError,
    WorkcellFileNotFoundError,
    WorkcellFormatError,
)
from drake_cfvol.io.arguments import got, real_number
from drake_cfvol.scene.arrays import SceneArrays, scene_arrays
from drake_cfvol.scene.directives import add_packages, diagram_from_directives
from drake_cfvol.scene.queries import WorkcellQueries, geometry_key, robot_geometry_ids
from drake_cfvol.scene.robot import RobotSlice, robot_bodies, robot_instances
from drake_cfvol.scene.schema import (
    DEFAULT_EDGE_STEP,
    CfvolSection,
    HeightMapExtent,
    NamedConfiguration,
    WorkcellFile,
    builtin_cells,
    models_dir,
    read_workcell_file,
)
from drake_cfvol.scene.setup import WorkcellSetup
from drake_cfvol.scene.urdf import condensed_drake_warnings

__all__ = [
    "Obstacle",
    "Workcell",
    "WorkcellFile",
    "CfvolSection",
    "HeightMapExtent",
    "NamedConfiguration",
    "builtin_cells",
    "load_workcell",
    "models_dir",
    "geometry_key",
    "robot_geometry_ids",
]


@dataclasses.dataclass(frozen=True)
class Obstacle:
    """A static obstacle of the workcell.

    Attributes:
        name: The body's name (scoped ``model::body`` when ambiguous).
        body_index: The body's index in the plant.
        geometry_ids: Its proximity geometries in the SceneGraph.
    """

    name: str
    body_index: Any
    geometry_ids: tuple


# -- the typed schema of a workcell file (yaml_load_typed) ------------------


class Workcell(WorkcellSetup, WorkcellQueries):
    """A loaded workcell: the robot, its obstacles and the cfvol settings.

    Build one with :func:`load_workcell`. The diagram is a Drake
    ``RobotDiagram`` (plant + scene graph) of the real scene; the height-map
    volume lives elsewhere (:mod:`drake_cfvol.algorithm.volume`).

    Attributes:
        name: Cell name (the YAML file's stem).
        path: The YAML file.
        diagram: The ``RobotDiagram``.
        plant: Its ``MultibodyPlant``.
        scene_graph: Its ``SceneGraph``.
        robot: The robot's ``ModelInstanceIndex``.
        joint_names: Names of the robot's k joints, in position order.
        position_lower, position_upper: Position limits (k,), rad or m; may be
            infinite when the model has none.
        velocity_limits: (k,) rad/s or m/s.
        acceleration_limits: (k,) rad/s^2 or m/s^2 (inf: none): the runtime
            filter's, the settings' or else the model's.
        jerk_limits: (k,) rad/s^3 or m/s^3 (inf: none).
        revolute: (k,) True for revolute joints, False for prismatic.
        tool_frame: The tool's ``Frame``.
        base_frame: The frame the reach is measured from.
        rail_joint: Name of the linear axis joint, or None.
        reach: Reach used by the volume's activation, m.
        height_map_origin: (x, y) of the height map's corner, m.
        height_map_size: (x_dim, y_dim), m.
        params: Parameter overrides from the file (a dict).
        configurations: Named (start, goal) pairs, each (k,) arrays.
        obstacles: Obstacles by name.
        notes: Things the loader did that the user should know (e.g. mesh
            conversions).
    """

    def __init__(self, path: Path, *, edge_step: float = DEFAULT_EDGE_STEP, embedded: bool = False):
        path = Path(path).resolve()
        self.path = path
        self.notes: list[str] = []
        spec, lines = read_workcell_file(path, embedded=embedded)
        self.spec: WorkcellFile | None = spec  # None: from a RobotDiagram
        self._lines = lines
        cf = spec.cfvol
        for key in ("robot", "tool_frame"):
            if not getattr(cf, key):
                raise WorkcellFormatError(str(path), f"'cfvol' lacks the required key '{key}'.", lines.get("cfvol"))
        if not spec.directives:
            raise WorkcellFormatError(
                str(path), "'directives' is empty: add the robot and the obstacles.", lines.get("directives")
            )
        hm = cf.height_map
        diagram, self._directives = diagram_from_directives(path, spec, lines, self.notes)
        self._setup(
            diagram,
            name=path.stem,
            robot=cf.robot,
            tool_frame=cf.tool_frame,
            base_frame=cf.base_frame,
            rail_joint=cf.rail_joint,
            reach=cf.reach or None,
            height_map_origin=hm.origin if hm and hm.origin else None,
            height_map_size=hm.size if hm and hm.size else None,
            joint_limits=cf.joint_limits,
            acceleration_limits=cf.acceleration_limits,
            jerk_limits=cf.jerk_limits,
            params=cf.params,
            configurations={n: (c.start, c.goal) for n, c in cf.configurations.items()},
            edge_step=edge_step,
        )

    @classmethod
    def FromRobotDiagram(
        cls,
        robot_diagram: RobotDiagram,
        *,
        robot: str | ModelInstanceIndex,
        tool_frame: str,
        base_frame: str | None = None,
        rail_joint: str | None = None,
        reach: float | None = None,
        height_map_origin: npt.ArrayLike | None = None,
        height_map_size: npt.ArrayLike | None = None,
        joint_limits: dict | None = None,
        acceleration_limits: npt.ArrayLike | None = None,
        jerk_limits: npt.ArrayLike | None = None,
        params: dict | None = None,
        configurations: dict | None = None,
        name: str = "station",
        edge_step: float = DEFAULT_EDGE_STEP,
    ) -> "Workcell":
        """A workcell from a user's own ``RobotDiagram`` (Drake's
        ``RobotDiagramBuilder``, finalized and built).

        The robot is one model instance; its joints are the k joints the
        bounds are for. A body its joints move (a gripper welded to the
        flange, in an instance of its own) belongs to the robot. Every
        other body with proximity geometry is an obstacle, where the plant's
        default context puts it: a gripper's fingers and a free part lying
        on a table are held there (the workcell's :attr:`notes` name them).
        The user's diagram is cloned, never changed.

        Args:
            robot_diagram: the ``RobotDiagram``.
            robot: the robot's model instance: its name (or a
                ``ModelInstanceIndex``).
            tool_frame: a frame of the robot (the push's Jacobian, the tool path).
            base_frame: the reach is measured from here (default: the robot's root body).
            rail_joint: a prismatic joint of the robot whose travel the reach follows.
            reach: the volume's activation radius, m (default: a bound on how
                far the robot's geometry lies from its first revolute joint).
            height_map_origin, height_map_size: the height map's corner (x, y)
                and size (x_dim, y_dim), m (default: the reach around the
                base, over the rail's travel).
            joint_limits: joint name -> [lower, upper] overrides, rad or m.
            acceleration_limits: (k,) rad/s^2 (m/s^2) for the runtime filter
                (default: the plant's, inf where it has none).
            jerk_limits: (k,) rad/s^3 (m/s^3) (default: none).
            params: :class:`drake_cfvol.VolumeParams` overrides.
            configurations: name -> (start, goal), each (k,).
            name: the workcell's name (records, file names).
            edge_step: Drake's edge-check step, rad or m.

        Raises:
            StationError: not a finalized RobotDiagram, an unknown robot or
                frame, a robot joint that is neither revolute nor prismatic,
                no obstacle with proximity geometry (the message says which
                and how to fix it).
        """
        if not (hasattr(robot_diagram, "plant") and hasattr(robot_diagram, "scene_graph")):
            raise StationError(
                f"Workcell.FromRobotDiagram needs a pydrake.planning.RobotDiagram (from "
                f"RobotDiagramBuilder.Build()), got {type(robot_diagram).__name__}."
            )
        if not robot_diagram.plant().is_finalized():
            raise StationError(
                "Workcell.FromRobotDiagram: the RobotDiagram's plant is not finalized; build the "
                "diagram first (RobotDiagramBuilder.Build())."
            )
        self = cls.__new__(cls)
        self.path, self.spec, self._lines, self._directives = None, None, {}, None
        self.notes = []
        clone = robot_diagram.Clone()
        # A clone forgets free bodies' default poses (drake 1.51): carry the
        # user's default positions over.
        user_plant = robot_diagram.plant()
        clone.plant().SetDefaultPositions(user_plant.GetPositions(user_plant.CreateDefaultContext()))
        self._setup(
            clone,
            name=str(name),
            robot=robot,
            tool_frame=tool_frame,
            base_frame=base_frame,
            rail_joint=rail_joint,
            reach=reach,
            height_map_origin=height_map_origin,
            height_map_size=height_map_size,
            joint_limits=joint_limits or {},
            acceleration_limits=acceleration_limits,
            jerk_limits=jerk_limits,
            params=params or {},
            configurations=configurations or {},
            edge_step=edge_step,
        )
        return self

    def _fail(self, message: str, key: str | None = None):
        """The error for a bad setting: with the file and line for a
        workcell file, else a StationError."""
        if self.path is not None:
            return WorkcellFormatError(str(self.path), message, self._lines.get(key) if key else None)
        return StationError(f"Workcell.FromRobotDiagram: {message}")

    def _setup(
        self,
        diagram,
        *,
        name,
        robot,
        tool_frame,
        base_frame,
        rail_joint,
        reach,
        height_map_origin,
        height_map_size,
        joint_limits,
        params,
        configurations,
        edge_step,
        acceleration_limits=None,
        jerk_limits=None,
    ) -> None:
        """Everything after the diagram: the robot, joints, frames, settings, obstacles."""
        self.name = name
        self.diagram = diagram
        self.plant = diagram.plant()
        self.scene_graph = diagram.scene_graph()
        self.robot = self._find_robot(robot)
        self.robot_name = self.plant.GetModelInstanceName(self.robot)
        self._edge_step = float(edge_step)
        self._cache: dict = {}  # results computed once (WorkcellQueries._memo)
        self._context = diagram.CreateDefaultContext()
        try:
            self.slice = RobotSlice(
                self.plant, self.robot, self.plant.GetPositions(self.plant.GetMyContextFromRoot(self._context))
            )
        except WorkcellError as e:
            raise self._fail(str(e)) from None
        self._note_held()
        self._read_joints(joint_limits, acceleration_limits, jerk_limits)
        self._read_frames(tool_frame, base_frame, rail_joint)
        self._read_settings(reach, height_map_origin, height_map_size, params, configurations)
        self.obstacles = self._find_obstacles()
        self._geometry_owner = {gid: obs.name for obs in self.obstacles.values() for gid in obs.geometry_ids}

    def _find_robot(self, robot):
        plant = self.plant
        if isinstance(robot, ModelInstanceIndex):
            if int(robot) >= plant.num_model_instances():
                raise self._fail(f"robot {robot} is not a model instance of the plant.", "robot")
            return robot
        if not plant.HasModelInstanceNamed(str(robot)):
            names = [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]
            where = "cfvol.robot" if self.path is not None else "robot"
            raise self._fail(
                f"{where} '{robot}' is not a model instance of the plant (there are: {', '.join(names)}).", "robot"
            )
        return plant.GetModelInstanceByName(str(robot))

    def _find_obstacles(self) -> dict[str, Obstacle]:
        plant = self.plant
        inspector = self.scene_graph.model_inspector()
        found: list[tuple[str, str, Any, tuple]] = []
        mine = set(robot_bodies(plant, self.robot))
        for i in range(plant.num_bodies()):
            body = plant.get_body(BodyIndex(i))
            if body.index() in mine or body.index() == plant.world_body().index():
                continue
            frame_id = plant.GetBodyFrameIdIfExists(body.index())
            if frame_id is None:
                continue
            geoms = tuple(inspector.GetGeometries(frame_id, Role.kProximity))
            if not geoms:
                continue
            found.append((body.name(), str(body.scoped_name()), body.index(), geoms))
        counts: dict[str, int] = {}
        for name, *_ in found:
            counts[name] = counts.get(name, 0) + 1
        obstacles = {}
        for name, scoped, index, geoms in found:
            key = name if counts[name] == 1 else scoped
            obstacles[key] = Obstacle(key, index, geoms)
        if not obstacles:
            raise self._fail(
                "the workcell has no obstacles with proximity geometry; add at least the floor as a "
                "body with a collision shape."
            )
        return obstacles

    def add_to_plant(self, plant: MultibodyPlant, parser: Parser | None = None) -> ModelInstanceIndex:
        """Adds this workcell's models to an unfinalized ``MultibodyPlant``.

        Returns:
            The robot's model instance in that plant.

        Raises:
            StationError: the workcell came from a RobotDiagram (its models
                are the user's; use :meth:`build_scene`, or the user's own
                plant with :func:`drake_cfvol.systems.AddCoManipulation`).
        """
        self.add_models(plant, parser)
        return plant.GetModelInstanceByName(self.robot_name)

    def add_models(self, plant: MultibodyPlant, parser: Parser | None = None) -> list:
        """:meth:`add_to_plant`, returning Drake's ``ModelInstanceInfo`` of
        every model added (for ``ApplyDriverConfigs``)."""
        if self._directives is None:
            raise StationError(
                f"workcell '{self.name}' came from a RobotDiagram, so it cannot add its models to another plant; "
                "use Workcell.build_scene() (a clone of that diagram), or wire the systems into your own station "
                "with drake_cfvol.systems.AddCoManipulation."
            )
        assert self.path is not None and self.spec is not None  # from a file: it kept its directives
        parser = parser or Parser(plant)
        add_packages(parser.package_map(), self.path, self.spec.cfvol.package_paths, self._lines)
        with condensed_drake_warnings(log=False):  # said once, when the workcell was loaded
            return ProcessModelDirectives(ModelDirectives(directives=self._directives), plant, parser)

    def add_robot_to_plant(self, plant: MultibodyPlant, parser: Parser | None = None) -> ModelInstanceIndex:
        """Adds the robot alone (and the model instances it carries, e.g. a
        gripper) to an unfinalized plant: a controller's model. A weld of
        the robot to an obstacle (a pedestal) becomes a weld to the world at
        the obstacle frame's pose in this workcell.

        Returns:
            The robot's model instance in that plant.

        Raises:
            StationError: the workcell came from a RobotDiagram.
        """
        if self._directives is None:
            raise StationError(
                f"workcell '{self.name}' came from a RobotDiagram: build your controller's plant from your own models."
            )
        mine = {self.plant.GetModelInstanceName(i) for i in robot_instances(self.plant, self.robot)}
        ctx = self.plant.GetMyContextFromRoot(self._context)
        kept = []
        for d in self._directives:
            if d.add_model is not None and d.add_model.name in mine:
                kept.append(d)
            elif d.add_weld is not None and d.add_weld.child.split("::")[0] in mine:
                d = copy.deepcopy(d)
                parent = d.add_weld.parent
                if parent != "world" and parent.split("::")[0] not in mine:
                    X_WP = self._scoped_frame(parent).CalcPoseInWorld(ctx)
                    X_PC = d.add_weld.X_PC.GetDeterministicValue() if d.add_weld.X_PC is not None else None
                    d.add_weld.parent = "world"
                    d.add_weld.X_PC = Transform(X_WP if X_PC is None else X_WP @ X_PC)
                kept.append(d)
        assert self.path is not None and self.spec is not None  # from a file: it kept its directives
        parser = parser or Parser(plant)
        add_packages(parser.package_map(), self.path, self.spec.cfvol.package_paths, self._lines)
        with condensed_drake_warnings(log=False):
            ProcessModelDirectives(ModelDirectives(directives=kept), plant, parser)
        return plant.GetModelInstanceByName(self.robot_name)

    def _scoped_frame(self, scoped: str):
        """A frame of this workcell's plant by its scoped name ``model::frame``."""
        model, _, name = scoped.rpartition("::")
        return self.plant.GetFrameByName(name, self.plant.GetModelInstanceByName(model))

    def build_scene(
        self, add_geometry: Callable[[MultibodyPlant, SceneGraph], object] | None = None, *, time_step: float = 0.0
    ) -> tuple[RobotDiagram, ModelInstanceIndex]:
        """Builds a fresh ``RobotDiagram`` of this workcell.

        Args:
            add_geometry: called as ``add_geometry(plant, scene_graph)`` to
                add geometry (e.g. the volume's boxes): before the plant is
                finalized for a workcell file; for a workcell from a
                RobotDiagram, on a clone of it (a finalized plant: register
                anchored geometry on the SceneGraph).
            time_step: the plant's time step, s (a workcell from a
                RobotDiagram keeps the diagram's own).

        Returns:
            (robot diagram, robot model instance)
        """
        if self._directives is None:
            diagram = self.diagram.Clone()
            diagram.plant().SetDefaultPositions(self.slice.q_default)
            if add_geometry is not None:
                add_geometry(diagram.plant(), diagram.scene_graph())
            return diagram, diagram.plant().GetModelInstanceByName(self.robot_name)
        builder = RobotDiagramBuilder(time_step=time_step)
        self.add_to_plant(builder.plant(), builder.parser())
        if add_geometry is not None:
            add_geometry(builder.plant(), builder.scene_graph())
        builder.plant().Finalize()
        diagram = builder.Build()
        return diagram, diagram.plant().GetModelInstanceByName(self.robot_name)

    # -- cached models of the scene ----------------------------------------

    def scene_arrays(self) -> SceneArrays:
        """The robot chain, robot shapes and obstacle shapes as arrays for the
        compiled kernel (:func:`drake_cfvol.scene.arrays.scene_arrays`), built once."""
        return self._memo("scene_arrays", lambda: scene_arrays(self))

    def __repr__(self) -> str:
        return (
            f"Workcell(name={self.name!r}, robot={self.robot_name!r}, k={self.num_joints}, "
            f"obstacles={list(self.obstacles)})"
        )


class WorkcellOptions(TypedDict, total=False):
    """:func:`load_workcell`'s keyword arguments, passed to :class:`Workcell`."""

    edge_step: float
    embedded: bool


def load_workcell(name_or_path: str | Path, **kwargs: Unpack[WorkcellOptions]) -> Workcell:
    """Loads a built-in workcell by name, or a workcell YAML file by path.

    Args:
        name_or_path: ``"automotive"``, ``"aerospace"`` or a path to a YAML file.
        **kwargs: Passed to :class:`Workcell` (``edge_step``).

    Raises:
        UnknownCellError: neither a built-in name nor a file path.
        WorkcellFileNotFoundError: a file path that does not exist.
        WorkcellFormatError: the file is malformed (file and line in the message).
    """
    cells = builtin_cells()
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ParameterError(
            f"load_workcell: name_or_path must be a built-in cell's name ({', '.join(sorted(cells))}) or a workcell "
            f"file's path, got {got(name_or_path)}."
        )
    unknown = sorted(set(kwargs) - {"edge_step", "embedded"})
    if unknown:
        raise ParameterError(f"load_workcell: unknown argument(s) {', '.join(unknown)}; it takes edge_step.")
    if "edge_step" in kwargs and not 0 < real_number(kwargs["edge_step"], "load_workcell: edge_step") < math.inf:
        raise ParameterError(
            f"load_workcell: edge_step must be a finite number > 0 (rad or m), got {kwargs['edge_step']}."
        )
    key = str(name_or_path)
    if key in cells:
        return Workcell(cells[key], **kwargs)
    path = Path(key)
    if path.suffix.lower() in (".yaml", ".yml") or path.exists() or "/" in key or "\\" in key:
        if not path.is_file():
            raise WorkcellFileNotFoundError(key, cells)
        return Workcell(path, **kwargs)
    raise UnknownCellError(key, cells)
