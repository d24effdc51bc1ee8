"""Workcells: a robot and its obstacles, loaded from one YAML file.

A workcell file holds Drake model directives (``directives:``) for the robot
and the obstacles, and a ``cfvol:`` section::

    directives:
    - add_model: {name: abb, file: package://drake_cfvol_models/...urdf}
    - add_weld: {parent: world, child: abb::base_link}
    - add_model: {name: cell, file: package://drake_cfvol_models/cells/...sdf}
    cfvol:
      robot: abb                 # model instance of the robot
      tool_frame: tcp            # frame of the robot (Jacobian, tool path)
      base_frame: base_link      # reach is measured from here ...
      rail_joint: null           # ... or along this prismatic joint's travel
      reach: 2.8                 # m, the activation radius of the volume
      height_map: {origin: [x, y], size: [x_dim, y_dim]}   # m, on the floor
      package_paths: {my_pkg: relative/or/absolute/dir}     # optional
      joint_limits: {joint: [lower, upper]}                 # optional overrides
      params: {h_max: 1.5, ...}                             # VolumeParams overrides
      configurations:
        path1: {start: [...], goal: [...]}                  # rad / m

Every obstacle is a body outside the robot's model instance, welded to the
world, with proximity geometry; the floor is one of them.

The file is read with pydrake's ``yaml_load_typed`` into
:class:`WorkcellFile` (``directives: list[ModelDirective]`` and
:class:`CfvolSection`), as Drake's hardware_sim reads its scenarios: a key
that is not part of the schema, anywhere, is an error that names the key and
its line.
"""


import copy
import dataclasses
import functools
import os
import re
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.geometry import Role
from pydrake.multibody.parsing import (
    ModelDirective,
    ModelDirectives,
    Parser,
    ProcessModelDirectives,
)
from pydrake.multibody.tree import BodyIndex, ModelInstanceIndex
from pydrake.planning import RobotDiagramBuilder, SceneGraphCollisionChecker

from drake_cfvol.scene import meshes as _meshes
from drake_cfvol.exceptions import (
    CollisionError,
    ConfigurationError,
    DimensionError,
    JointLimitError,
    MissingJointLimitsError,
    UnknownCellError,
    WorkcellFileNotFoundError,
    WorkcellError,
    WorkcellFormatError,
)
from drake_cfvol.scene.arrays import SceneArrays, scene_arrays

__all__ = ["Obstacle", "Workcell", "WorkcellFile", "CfvolSection", "HeightMapExtent", "NamedConfiguration",
           "builtin_cells", "load_workcell", "models_dir"]

#: Distance between configurations at which Drake's edge checks sample (rad or
#: m, Euclidean in joint space).
DEFAULT_EDGE_STEP = 0.01


def models_dir() -> Path:
    """Returns the folder of the bundled models (holds ``package.xml``):
    ``$DRAKE_CFVOL_MODELS`` if set, else the ``drake_cfvol.models`` package
    data (the repository's ``models/``, shipped inside the wheel).

    Raises:
        WorkcellError: the folder is missing.
    """
    env = os.environ.get("DRAKE_CFVOL_MODELS")
    folder = Path(env) if env else Path(str(resources.files("drake_cfvol.models")))
    if not (folder / "package.xml").is_file():
        raise WorkcellError(
            f"drake_cfvol's models folder is missing ({folder}/package.xml not found). Reinstall the "
            "package (`pip install drake-cfvol` or `pip install .` from a checkout), or point "
            "$DRAKE_CFVOL_MODELS at a folder holding the models' package.xml.")
    return folder


def builtin_cells() -> dict[str, Path]:
    """Returns the built-in workcells, by name."""
    return {p.stem: p for p in sorted((models_dir() / "cells").glob("*.yaml"))}


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

@dataclasses.dataclass
class HeightMapExtent:
    """The height map's extent on the floor.

    Attributes:
        origin: (x, y) of its corner, m.
        size: (x_dim, y_dim), m.
    """

    origin: list[float] = dataclasses.field(default_factory=list)
    size: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class NamedConfiguration:
    """A named start/goal pair, rad (m for prismatic joints)."""

    start: list[float] = dataclasses.field(default_factory=list)
    goal: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class CfvolSection:
    """The ``cfvol:`` section of a workcell file.

    Attributes:
        robot: the robot's model instance.
        tool_frame: a frame of the robot (Jacobian, tool path).
        base_frame: the reach is measured from here (default: the robot's root body).
        rail_joint: a prismatic joint whose travel the reach follows, or None.
        reach: the activation radius of the volume, m.
        height_map: the height map's extent.
        package_paths: package name -> folder (relative to the file).
        joint_limits: joint -> [lower, upper] overrides, rad or m.
        params: :class:`drake_cfvol.VolumeParams` overrides.
        configurations: named start/goal pairs.
    """

    robot: str = ""
    tool_frame: str = ""
    base_frame: str | None = None
    rail_joint: str | None = None
    reach: float = 0.0
    height_map: HeightMapExtent | None = None
    package_paths: dict[str, str] = dataclasses.field(default_factory=dict)
    joint_limits: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    params: dict[str, float] = dataclasses.field(default_factory=dict)
    configurations: dict[str, NamedConfiguration] = dataclasses.field(default_factory=dict)


def geometry_key(inspector, geometry_id) -> tuple[str, str]:
    """(frame name, geometry name): a geometry's name that holds across
    plants built from the same models."""
    return inspector.GetName(inspector.GetFrameId(geometry_id)), inspector.GetName(geometry_id)


def robot_geometry_ids(plant, robot) -> tuple[set, set]:
    """Proximity geometry ids of a robot's links in a finalized plant, and of
    those its joints move.

    Returns:
        (every, moving)
    """
    moved = set(plant.GetBodiesKinematicallyAffectedBy(list(plant.GetJointIndices(robot))))
    every, moving = set(), set()
    for b in plant.GetBodyIndices(robot):
        ids = plant.GetCollisionGeometriesForBody(plant.get_body(b))
        every.update(ids)
        if b in moved:
            moving.update(ids)
    return every, moving


@dataclasses.dataclass
class WorkcellFile:
    """A workcell file: Drake model directives plus the ``cfvol:`` section
    (loaded with ``yaml_load_typed``, as Drake's hardware_sim scenarios)."""

    directives: list[ModelDirective] = dataclasses.field(default_factory=list)
    cfvol: CfvolSection = dataclasses.field(default_factory=CfvolSection)


def _key_lines(text: str) -> dict[str, int]:
    """First line (1-based) of every mapping key in a YAML text, by key and by
    dotted path."""
    out: dict[str, int] = {}
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return out

    def walk(node, prefix):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                name = str(k.value)
                line = k.start_mark.line + 1
                out.setdefault(name, line)
                out.setdefault(prefix + name, line)
                walk(v, prefix + name + ".")
        elif isinstance(node, yaml.SequenceNode):
            for item in node.value:
                walk(item, prefix)

    walk(root, "")
    return out


def read_workcell_file(path: Path) -> tuple[WorkcellFile, dict[str, int]]:
    """Reads and type-checks a workcell file.

    Returns:
        (the typed file, key -> line)

    Raises:
        WorkcellFormatError: unreadable, not YAML, an unknown key (named, with
            its line), or a value of the wrong type.
    """
    try:
        text = path.read_text()
    except OSError as e:
        raise WorkcellFormatError(str(path), f"cannot read the file ({e.strerror}).") from e
    try:
        data = yaml.safe_load(text)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        line = mark.line + 1 if mark is not None else None
        raise WorkcellFormatError(str(path), f"not valid YAML: {e.problem or e}. Fix the syntax there.", line) from e
    if not isinstance(data, dict):
        raise WorkcellFormatError(str(path), "expected a mapping with 'directives:' and 'cfvol:' at the top.", 1)
    lines = _key_lines(text)
    for key in ("directives", "cfvol"):
        if data.get(key) is None:
            raise WorkcellFormatError(str(path), f"'(top level)' lacks the required key '{key}'.", 1)
    try:
        typed = yaml_load_typed(schema=WorkcellFile, data=text)
    except Exception as e:  # Drake raises RuntimeError / ValueError / TypeError here.
        msg = str(e)
        unknown = re.search(r"fields \[([^\]]*)\] were unknown", msg)
        if unknown:
            names = [n.strip(" '\"") for n in unknown.group(1).split(",")]
            line = lines.get(names[0])
            raise WorkcellFormatError(
                str(path), f"unknown key {', '.join(repr(n) for n in names)}: not part of a workcell file. "
                "Check its spelling (see the drake_cfvol.scene.workcell docstring for the keys).", line) from e
        raise WorkcellFormatError(str(path), f"a value has the wrong type: {msg}. Fix it there.") from e
    return typed, lines


class Workcell:
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

    def __init__(self, path: Path, *, edge_step: float = DEFAULT_EDGE_STEP):
        path = Path(path).resolve()
        self.path = path
        self.name = path.stem
        self.notes: list[str] = []
        spec, lines = read_workcell_file(path)
        self.spec = spec
        self._lines = lines
        cf = spec.cfvol
        for key in ("robot", "tool_frame"):
            if not getattr(cf, key):
                raise WorkcellFormatError(str(path), f"'cfvol' lacks the required key '{key}'.", lines.get("cfvol"))
        if not spec.directives:
            raise WorkcellFormatError(str(path), "'directives' is empty: add the robot and the obstacles.",
                                      lines.get("directives"))

        builder = RobotDiagramBuilder(time_step=0.0)
        parser = builder.parser()
        self._add_packages(parser.package_map())
        self._directives = self._prepare_directives(spec.directives, parser.package_map())
        try:
            ProcessModelDirectives(ModelDirectives(directives=self._directives), builder.plant(), parser)
        except Exception as e:  # Drake raises RuntimeError / ValueError here.
            raise WorkcellFormatError(
                str(path), f"Drake cannot load the model directives: {e}", lines.get("directives")) from e
        plant = builder.plant()
        if not plant.HasModelInstanceNamed(cf.robot):
            names = [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]
            raise WorkcellFormatError(
                str(path), f"cfvol.robot '{cf.robot}' is not a model instance of the directives "
                f"(there are: {', '.join(names)}).", lines.get("robot"))
        self.robot = plant.GetModelInstanceByName(cf.robot)
        self.robot_name = cf.robot
        plant.Finalize()
        self.diagram = builder.Build()
        self.plant = self.diagram.plant()
        self.scene_graph = self.diagram.scene_graph()
        self._context = self.diagram.CreateDefaultContext()
        self._edge_step = float(edge_step)
        self._scene_arrays: SceneArrays | None = None

        plant = self.plant
        if plant.num_positions() != plant.num_positions(self.robot):
            raise WorkcellFormatError(
                str(path), "only the robot may have degrees of freedom: weld every obstacle to "
                "the world (add_weld, or <static>true</static> in SDF).")
        joints = [plant.get_joint(j) for j in plant.GetJointIndices(self.robot)]
        joints = sorted((j for j in joints if j.num_positions() > 0), key=lambda j: j.position_start())
        for j in joints:
            if j.num_positions() != 1:
                raise WorkcellFormatError(
                    str(path), f"joint '{j.name()}' has {j.num_positions()} positions; only revolute "
                    "and prismatic joints are supported.")
        self.joint_names = [j.name() for j in joints]
        self.revolute = np.array([j.type_name() == "revolute" for j in joints])
        lower = plant.GetPositionLowerLimits().copy()
        upper = plant.GetPositionUpperLimits().copy()
        for jname, lim in cf.joint_limits.items():
            if jname not in self.joint_names:
                raise WorkcellFormatError(
                    str(path), f"cfvol.joint_limits names joint '{jname}', which the robot lacks "
                    f"(joints: {', '.join(self.joint_names)}).", lines.get(jname))
            if not (len(lim) == 2 and float(lim[0]) < float(lim[1])):
                raise WorkcellFormatError(
                    str(path), f"cfvol.joint_limits.{jname} must be [lower, upper] with lower < upper.",
                    lines.get(jname))
            i = self.joint_names.index(jname)
            lower[i], upper[i] = float(lim[0]), float(lim[1])
        self.position_lower = lower
        self.position_upper = upper
        self.velocity_limits = plant.GetVelocityUpperLimits().copy()

        try:
            self.tool_frame = plant.GetFrameByName(cf.tool_frame, self.robot)
        except RuntimeError as e:
            raise WorkcellFormatError(
                str(path), f"cfvol.tool_frame '{cf.tool_frame}' is not a frame of '{cf.robot}'.",
                lines.get("tool_frame")) from e
        if cf.base_frame is None:
            self.base_frame = self._robot_root(plant).body_frame()
        else:
            try:
                self.base_frame = plant.GetFrameByName(cf.base_frame, self.robot)
            except RuntimeError as e:
                raise WorkcellFormatError(
                    str(path), f"cfvol.base_frame '{cf.base_frame}' is not a frame of '{cf.robot}'.",
                    lines.get("base_frame")) from e
        self.rail_joint = cf.rail_joint
        if self.rail_joint is not None and self.rail_joint not in self.joint_names:
            raise WorkcellFormatError(
                str(path), f"cfvol.rail_joint '{self.rail_joint}' is not a joint of the robot "
                f"(joints: {', '.join(self.joint_names)}).", lines.get("rail_joint"))
        self.reach = float(cf.reach or 0.0)
        hm = cf.height_map
        self.height_map_origin = np.asarray(hm.origin if hm and hm.origin else [np.nan, np.nan], float)
        self.height_map_size = np.asarray(hm.size if hm and hm.size else [np.nan, np.nan], float)
        for label, v in (("origin", self.height_map_origin), ("size", self.height_map_size)):
            if v.shape != (2,):
                raise WorkcellFormatError(str(path), f"cfvol.height_map.{label} must be [x, y] (m), got "
                                          f"{v.size} values.", lines.get("height_map"))
        self.params = dict(cf.params)
        self.configurations: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for cname, pair in cf.configurations.items():
            start, goal = np.asarray(pair.start, float), np.asarray(pair.goal, float)
            for label, q in (("start", start), ("goal", goal)):
                if q.shape != (self.num_joints,):
                    raise WorkcellFormatError(
                        str(path), f"cfvol.configurations.{cname}.{label} has {q.size} values; the robot "
                        f"has {self.num_joints} joints ({', '.join(self.joint_names)}).",
                        lines.get(f"cfvol.configurations.{cname}.{label}", lines.get(cname)))
            self.configurations[str(cname)] = (start, goal)
        self.obstacles = self._find_obstacles()
        self._geometry_owner = {gid: obs.name for obs in self.obstacles.values() for gid in obs.geometry_ids}

    # -- loading helpers -------------------------------------------------

    def _robot_root(self, plant):
        bodies = [plant.get_body(b) for b in plant.GetBodyIndices(self.robot)]
        for b in bodies:
            parent = [j for j in (plant.get_joint(i) for i in plant.GetJointIndices(self.robot))
                      if j.child_body().index() == b.index()]
            if not parent:
                return b
        return bodies[0]

    def _add_packages(self, package_map) -> None:
        """The bundled models' package, then the file's ``package_paths``."""
        package_map.AddPackageXml(str(models_dir() / "package.xml"))
        for pname, ppath in self.spec.cfvol.package_paths.items():
            folder = (self.path.parent / str(ppath)).resolve()
            if not folder.is_dir():
                raise WorkcellFormatError(
                    str(self.path), f"cfvol.package_paths.{pname}: folder '{folder}' does not exist.",
                    self._lines.get(pname, self._lines.get("package_paths")))
            if package_map.Contains(str(pname)):
                package_map.Remove(str(pname))
            package_map.Add(str(pname), str(folder))

    def _prepare_directives(self, directives: list, package_map) -> list:
        """Resolves relative model files and converts STL meshes (Drake 1.51
        refuses STL collision meshes); the typed directives are copied, not
        changed."""
        out = []
        path = self.path
        for d in directives:
            d = copy.deepcopy(d)
            if d.add_model is not None:
                url = str(d.add_model.file)
                if url.startswith("package://"):
                    try:
                        resolved = Path(package_map.ResolveUrl(url))
                    except Exception as e:
                        raise WorkcellFormatError(str(path), _meshes.package_url_error(url, e, package_map) + ".",
                                                  self._lines.get("directives")) from None
                elif url.startswith("file://"):
                    resolved = Path(url[len("file://"):])
                else:
                    resolved = (path.parent / url).resolve()
                if not resolved.is_file():
                    raise WorkcellFormatError(
                        str(path), f"model file '{url}' not found (looked at {resolved}).",
                        self._lines.get("directives"))
                converted, notes = _meshes.convert_stl_references(resolved, package_map)
                self.notes.extend(notes)
                d.add_model.file = "file://" + str(converted)
            out.append(d)
        return out

    def _find_obstacles(self) -> dict[str, Obstacle]:
        plant = self.plant
        inspector = self.scene_graph.model_inspector()
        found: list[tuple[str, str, Any, tuple]] = []
        for i in range(plant.num_bodies()):
            body = plant.get_body(BodyIndex(i))
            if body.model_instance() == self.robot or body.index() == plant.world_body().index():
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
            raise WorkcellFormatError(
                str(self.path), "the workcell has no obstacles with proximity geometry; add at least "
                "the floor as a body with a collision shape.")
        return obstacles

    def add_to_plant(self, plant, parser=None):
        """Adds this workcell's models to an unfinalized ``MultibodyPlant``.

        Returns:
            The robot's model instance in that plant.
        """
        parser = parser or Parser(plant)
        self._add_packages(parser.package_map())
        ProcessModelDirectives(ModelDirectives(directives=self._directives), plant, parser)
        return plant.GetModelInstanceByName(self.robot_name)

    def build_scene(self, add_geometry=None, *, time_step: float = 0.0):
        """Builds a fresh ``RobotDiagram`` of this workcell.

        Args:
            add_geometry: called as ``add_geometry(plant)`` before the plant
                is finalized (e.g. to register the volume's boxes).
            time_step: the plant's time step, s.

        Returns:
            (robot diagram, robot model instance)
        """
        builder = RobotDiagramBuilder(time_step=time_step)
        self.add_to_plant(builder.plant(), builder.parser())
        if add_geometry is not None:
            add_geometry(builder.plant())
        builder.plant().Finalize()
        diagram = builder.Build()
        return diagram, diagram.plant().GetModelInstanceByName(self.robot_name)

    # -- cached models of the scene ----------------------------------------

    def scene_arrays(self) -> SceneArrays:
        """The robot chain, robot shapes and obstacle shapes as arrays for the
        compiled kernel (:func:`drake_cfvol.scene.arrays.scene_arrays`), built once."""
        if self._scene_arrays is None:
            self._scene_arrays = scene_arrays(self)
        return self._scene_arrays

    def obstacle_distances(self, q, max_distance: float, *, moving_only: bool = False,
                           changeable_only: bool = False) -> dict[str, float]:
        """Smallest signed distance per obstacle to the robot at ``q`` (real
        geometry, Drake), for the obstacles within ``max_distance``, m. With
        ``moving_only``, only the robot's links that its joints move count
        (a fixed base resting on its pedestal says nothing about a push);
        with ``changeable_only``, moreover only the pairs whose distance a
        joint motion changes (:meth:`invariant_pairs`: a turret turning above
        its round pedestal, a rail carriage gliding above the floor)."""
        invariant = self.invariant_pairs() if changeable_only else frozenset()  # poses the context: first
        self.plant_context(q)
        sg = self.scene_graph
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self._context))
        owner = self._geometry_owner
        fixed = self.fixed_robot_geometries() if (moving_only or changeable_only) else frozenset()
        out: dict[str, float] = {}
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=max_distance):
            a, b = owner.get(pair.id_A), owner.get(pair.id_B)
            if (a is None) == (b is None):
                continue  # robot-robot or obstacle-obstacle
            r, o = (pair.id_B, pair.id_A) if a is not None else (pair.id_A, pair.id_B)
            if r in fixed or (r, o) in invariant:
                continue
            name = a if a is not None else b
            out[name] = min(out.get(name, np.inf), pair.distance)
        return out

    def nearest_obstacle(self, q, max_distance: float = 5.0):
        """The obstacle nearest to the robot's moving links at ``q`` (Drake,
        real geometry), among the pairs whose distance a joint motion
        changes (:meth:`invariant_pairs`).

        Returns:
            (name, distance m, p_WR, p_WO): the witness points on the robot and
            on the obstacle, world frame; None if nothing is within
            ``max_distance``.
        """
        invariant = self.invariant_pairs()  # poses the context: first
        self.plant_context(q)
        sg = self.scene_graph
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self._context))
        owner, fixed = self._geometry_owner, self.fixed_robot_geometries()
        best = None
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=max_distance):
            a, b = owner.get(pair.id_A), owner.get(pair.id_B)
            if (a is None) == (b is None):
                continue
            robot_id, p_R, name, obs_id, p_O = ((pair.id_B, pair.p_BCb, a, pair.id_A, pair.p_ACa) if a is not None
                                                else (pair.id_A, pair.p_ACa, b, pair.id_B, pair.p_BCb))
            if robot_id in fixed or (robot_id, obs_id) in invariant:
                continue
            if best is None or pair.distance < best[1]:
                best = (name, pair.distance, query.GetPoseInWorld(robot_id) @ p_R,
                        query.GetPoseInWorld(obs_id) @ p_O)
        return best

    def invariant_pairs(self, *, samples: int = 12, seed: int = 0, tol: float = 1e-6) -> frozenset:
        """(robot geometry id, obstacle geometry id) pairs, moving links only,
        whose signed distance no joint motion changes: equal within ``tol``
        (m) at the default configuration and ``samples`` seeded uniform
        configurations within the position limits (nominal +- pi for a joint
        without limits). A push cannot bring such a pair closer, so a run's
        clearance leaves them out (:meth:`obstacle_distances`). Computed once."""
        if getattr(self, "_invariant", None) is not None:
            return self._invariant
        k = self.num_joints
        q0 = self.plant.GetPositions(self.plant.CreateDefaultContext(), self.robot)
        lo = np.where(np.isfinite(self.position_lower), self.position_lower, q0 - np.pi)
        hi = np.where(np.isfinite(self.position_upper), self.position_upper, q0 + np.pi)
        Q = np.vstack([q0, np.random.default_rng(seed).uniform(lo, hi, (samples, k))])
        _, moving = robot_geometry_ids(self.plant, self.robot)
        pairs = [(r, o) for r in sorted(moving, key=lambda g: g.get_value())
                 for o in sorted(self._geometry_owner, key=lambda g: g.get_value())]
        sg = self.scene_graph
        D = np.full((len(Q), len(pairs)), np.nan)
        for n, q in enumerate(Q):
            self.plant_context(q)
            query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self._context))
            for m, (r, o) in enumerate(pairs):
                try:
                    D[n, m] = query.ComputeSignedDistancePairClosestPoints(r, o).distance
                except RuntimeError:
                    pass  # a shape pair Drake cannot measure: never called invariant
        spread = np.nanmax(D, axis=0) - np.nanmin(D, axis=0) if len(Q) else np.zeros(len(pairs))
        ok = np.all(np.isfinite(D), axis=0) & (spread <= tol)
        self._invariant = frozenset(p for p, keep in zip(pairs, ok) if keep)
        return self._invariant

    def invariant_pair_names(self) -> frozenset:
        """:meth:`invariant_pairs` as ((frame name, geometry name) of the
        robot's geometry, same of the obstacle's): names that hold in any
        plant the workcell was added to (:meth:`add_to_plant`)."""
        inspector = self.scene_graph.model_inspector()
        return frozenset((geometry_key(inspector, r), geometry_key(inspector, o)) for r, o in self.invariant_pairs())

    def fixed_robot_geometries(self) -> frozenset:
        """Proximity geometry ids of the robot's bodies that no joint moves
        (e.g. a base welded to its pedestal)."""
        if getattr(self, "_fixed_ids", None) is None:
            every, moving = robot_geometry_ids(self.plant, self.robot)
            self._fixed_ids = frozenset(every - moving)
        return self._fixed_ids

    # -- queries ---------------------------------------------------------

    @property
    def num_joints(self) -> int:
        """k, the robot's number of joints."""
        return len(self.joint_names)

    @property
    def context(self):
        """A diagram context owned by the workcell (do not keep references)."""
        return self._context

    def plant_context(self, q: np.ndarray | None = None):
        """Returns the workcell's plant context, set to ``q`` if given."""
        ctx = self.plant.GetMyMutableContextFromRoot(self._context)
        if q is not None:
            self.plant.SetPositions(ctx, np.asarray(q, float))
        return ctx

    @functools.cached_property
    def checker(self):
        """A Drake ``SceneGraphCollisionChecker`` of the real scene (obstacles
        + self-collision, adjacent links filtered)."""
        return SceneGraphCollisionChecker(
            model=self.diagram, robot_model_instances=[self.robot],
            edge_step_size=self._edge_step, env_collision_padding=0.0, self_collision_padding=0.0)

    def padded_checker(self, clearance: float):
        """A ``SceneGraphCollisionChecker`` that calls a configuration nearer
        than ``clearance`` (m) to an obstacle or to the robot itself
        colliding (Drake's collision padding); one per distinct value."""
        clearance = float(clearance)
        if clearance == 0.0:
            return self.checker
        if getattr(self, "_padded_checkers", None) is None:
            self._padded_checkers = {}
        cache = self._padded_checkers
        if clearance not in cache:
            cache[clearance] = SceneGraphCollisionChecker(
                model=self.diagram, robot_model_instances=[self.robot], edge_step_size=self._edge_step,
                env_collision_padding=clearance, self_collision_padding=clearance)
        return cache[clearance]

    def clearance(self, q, influence: float = 1.0) -> float:
        """The robot's signed distance to the obstacles and to itself at
        ``q`` (m; the smallest pair, by Drake; ``influence`` if none is
        nearer)."""
        d = np.asarray(self.checker.CalcRobotClearance(np.asarray(q, float), influence).distances())
        return float(d.min()) if d.size else float(influence)

    def finite_limits(self, needed_for: str) -> tuple[np.ndarray, np.ndarray]:
        """Returns the position limits, raising if any is infinite."""
        bad = [n for n, lo, hi in zip(self.joint_names, self.position_lower, self.position_upper)
               if not (np.isfinite(lo) and np.isfinite(hi))]
        if bad:
            raise MissingJointLimitsError(bad, needed_for)
        return self.position_lower.copy(), self.position_upper.copy()

    def validate_configuration(self, q, what: str = "configuration", *, check_limits: bool = True,
                               tolerance: float = 1e-9) -> np.ndarray:
        """Checks a configuration's size and limits; returns it as an array.

        Raises:
            DimensionError: ``q`` is not (k,).
            JointLimitError: a joint lies outside its limits.
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (self.num_joints,):
            raise DimensionError(
                what, self.num_joints, q.shape[0] if q.ndim == 1 else q.shape,
                f"The robot's joints are {', '.join(self.joint_names)}.")
        if not np.all(np.isfinite(q)):
            bad = [f"{n} = {v}" for n, v in zip(self.joint_names, q) if not np.isfinite(v)]
            raise ConfigurationError(f"{what} has a value that is not a finite number: {', '.join(bad)}. Give every "
                                     "joint a finite position (rad or m).")
        if check_limits:
            for n, v, lo, hi in zip(self.joint_names, q, self.position_lower, self.position_upper):
                if v < lo - tolerance or v > hi + tolerance:
                    raise JointLimitError(what, n, float(v), float(lo), float(hi))
        return q

    def colliding_pairs(self, q) -> list[tuple[str, str]]:
        """Names the pairs of bodies in collision at ``q`` (real scene)."""
        self.plant_context(q)
        sg_context = self.scene_graph.GetMyContextFromRoot(self._context)
        query = self.scene_graph.get_query_output_port().Eval(sg_context)
        inspector = query.inspector()
        pairs = set()
        for pp in query.ComputePointPairPenetration():
            a = self.plant.GetBodyFromFrameId(inspector.GetFrameId(pp.id_A)).name()
            b = self.plant.GetBodyFromFrameId(inspector.GetFrameId(pp.id_B)).name()
            pairs.add(tuple(sorted((a, b))))
        return sorted(pairs)

    def is_free(self, q) -> bool:
        """True if ``q`` is free of collision with the real scene."""
        return bool(self.checker.CheckConfigCollisionFree(np.asarray(q, float)))

    def require_free(self, q, what: str) -> None:
        """Raises :class:`CollisionError` naming the bodies if ``q`` collides."""
        if not self.is_free(q):
            raise CollisionError(what, self.colliding_pairs(q))

    def configuration(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Returns the named (start, goal) pair."""
        if name not in self.configurations:
            raise WorkcellError(
                f"Cell '{self.name}' has no configuration '{name}'. It has: "
                f"{', '.join(self.configurations) or '(none)'}; add it under cfvol.configurations.")
        s, g = self.configurations[name]
        return s.copy(), g.copy()

    def tool_position(self, q) -> np.ndarray:
        """p_WT: the tool frame's origin in the world at ``q``, m."""
        ctx = self.plant_context(q)
        return self.tool_frame.CalcPoseInWorld(ctx).translation().copy()

    def __repr__(self) -> str:
        return (f"Workcell(name={self.name!r}, robot={self.robot_name!r}, k={self.num_joints}, "
                f"obstacles={list(self.obstacles)})")


def load_workcell(name_or_path: str | Path, **kwargs) -> Workcell:
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
    key = str(name_or_path)
    if key in cells:
        return Workcell(cells[key], **kwargs)
    path = Path(key)
    if path.suffix.lower() in (".yaml", ".yml") or path.exists() or "/" in key or "\\" in key:
        if not path.is_file():
            raise WorkcellFileNotFoundError(key, cells)
        return Workcell(path, **kwargs)
    raise UnknownCellError(key, cells)
