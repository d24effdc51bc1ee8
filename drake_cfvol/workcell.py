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
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drake_cfvol import _meshes
from drake_cfvol.exceptions import (
    CollisionError,
    DimensionError,
    JointLimitError,
    MissingJointLimitsError,
    UnknownCellError,
    WorkcellError,
    WorkcellFormatError,
)

__all__ = ["Obstacle", "Workcell", "builtin_cells", "load_workcell", "models_dir"]

#: Distance between configurations at which Drake's edge checks sample (rad or
#: m, Euclidean in joint space).
DEFAULT_EDGE_STEP = 0.01


def models_dir() -> Path:
    """Returns the folder of the bundled models (holds ``package.xml``):
    ``$DRAKE_CFVOL_MODELS`` if set, else ``models/`` beside the package (a
    repository checkout or an editable install).

    Raises:
        WorkcellError: the folder is missing.
    """
    import os

    folder = Path(os.environ.get("DRAKE_CFVOL_MODELS") or Path(__file__).resolve().parent.parent / "models")
    if not (folder / "package.xml").is_file():
        raise WorkcellError(
            f"drake_cfvol's models folder is missing ({folder}/package.xml not found). Install from a "
            "checkout with `pip install -e .`, or point $DRAKE_CFVOL_MODELS at the repository's models/.")
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


class _LineLoader(yaml.SafeLoader):
    """A YAML loader that remembers the line of every mapping."""


def _construct_mapping(loader, node):
    mapping = _Mapping(loader.construct_mapping(node, deep=True))
    mapping.line = node.start_mark.line + 1
    mapping.key_lines = {k.value: k.start_mark.line + 1 for k, _ in node.value if hasattr(k, "value")}
    return mapping


class _Mapping(dict):
    line: int | None = None
    key_lines: dict = {}


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _read_yaml(path: Path) -> _Mapping:
    try:
        text = path.read_text()
    except OSError as e:
        raise WorkcellFormatError(str(path), f"cannot read the file ({e.strerror}).") from e
    try:
        data = yaml.load(text, Loader=_LineLoader)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        line = mark.line + 1 if mark is not None else None
        raise WorkcellFormatError(str(path), f"not valid YAML: {e.problem or e}. Fix the syntax there.", line) from e
    if not isinstance(data, dict):
        raise WorkcellFormatError(str(path), "expected a mapping with 'directives:' and 'cfvol:' at the top.", 1)
    return data


def _need(mapping: dict, key: str, path: Path, where: str, kind=None):
    if key not in mapping or mapping[key] is None:
        raise WorkcellFormatError(
            str(path), f"'{where}' lacks the required key '{key}'.", getattr(mapping, "line", None)
        )
    value = mapping[key]
    if kind is not None and not isinstance(value, kind):
        line = getattr(mapping, "key_lines", {}).get(key, getattr(mapping, "line", None))
        raise WorkcellFormatError(
            str(path), f"'{where}.{key}' must be a {kind.__name__}, got {type(value).__name__}.", line
        )
    return value


class Workcell:
    """A loaded workcell: the robot, its obstacles and the cfvol settings.

    Build one with :func:`load_workcell`. The diagram is a Drake
    ``RobotDiagram`` (plant + scene graph) of the real scene; the height-map
    volume lives elsewhere (:mod:`drake_cfvol.volume`).

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
        data = _read_yaml(path)
        self._raw = data
        directives = _need(data, "directives", path, "(top level)", list)
        cf = _need(data, "cfvol", path, "(top level)", dict)
        robot_name = _need(cf, "robot", path, "cfvol", str)
        tool_name = _need(cf, "tool_frame", path, "cfvol", str)

        from pydrake.multibody.parsing import (
            LoadModelDirectivesFromString,
            ProcessModelDirectives,
        )
        from pydrake.planning import RobotDiagramBuilder

        builder = RobotDiagramBuilder(time_step=0.0)
        parser = builder.parser()
        package_map = parser.package_map()
        package_map.AddPackageXml(str(models_dir() / "package.xml"))
        self._add_package_paths(cf.get("package_paths"), package_map, path, cf)
        directives = self._prepare_directives(directives, package_map, path)
        self._directives = directives
        self._package_paths = cf.get("package_paths")
        try:
            model_directives = LoadModelDirectivesFromString(yaml.safe_dump({"directives": directives}))
            ProcessModelDirectives(model_directives, builder.plant(), parser)
        except Exception as e:  # Drake raises RuntimeError / ValueError here.
            raise WorkcellFormatError(
                str(path), f"Drake cannot load the model directives: {e}",
                getattr(data, "key_lines", {}).get("directives"),
            ) from e
        plant = builder.plant()
        if not plant.HasModelInstanceNamed(robot_name):
            names = self._instance_names(plant)
            raise WorkcellFormatError(
                str(path), f"cfvol.robot '{robot_name}' is not a model instance of the directives "
                f"(there are: {', '.join(names)}).", cf.key_lines.get("robot"))
        self.robot = plant.GetModelInstanceByName(robot_name)
        self.robot_name = robot_name
        plant.Finalize()
        self.diagram = builder.Build()
        self.plant = self.diagram.plant()
        self.scene_graph = self.diagram.scene_graph()
        self._context = self.diagram.CreateDefaultContext()
        self._edge_step = float(edge_step)

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
        for jname, lim in (cf.get("joint_limits") or {}).items():
            if jname not in self.joint_names:
                raise WorkcellFormatError(
                    str(path), f"cfvol.joint_limits names joint '{jname}', which the robot lacks "
                    f"(joints: {', '.join(self.joint_names)}).", cf.key_lines.get("joint_limits"))
            if not (isinstance(lim, list) and len(lim) == 2 and float(lim[0]) < float(lim[1])):
                raise WorkcellFormatError(
                    str(path), f"cfvol.joint_limits.{jname} must be [lower, upper] with lower < upper.",
                    cf.key_lines.get("joint_limits"))
            i = self.joint_names.index(jname)
            lower[i], upper[i] = float(lim[0]), float(lim[1])
        self.position_lower = lower
        self.position_upper = upper
        self.velocity_limits = plant.GetVelocityUpperLimits().copy()

        try:
            self.tool_frame = plant.GetFrameByName(tool_name, self.robot)
        except RuntimeError as e:
            raise WorkcellFormatError(
                str(path), f"cfvol.tool_frame '{tool_name}' is not a frame of '{robot_name}'.",
                cf.key_lines.get("tool_frame")) from e
        base_name = cf.get("base_frame")
        if base_name is None:
            self.base_frame = self._robot_root(plant).body_frame()
        else:
            try:
                self.base_frame = plant.GetFrameByName(base_name, self.robot)
            except RuntimeError as e:
                raise WorkcellFormatError(
                    str(path), f"cfvol.base_frame '{base_name}' is not a frame of '{robot_name}'.",
                    cf.key_lines.get("base_frame")) from e
        self.rail_joint = cf.get("rail_joint")
        if self.rail_joint is not None and self.rail_joint not in self.joint_names:
            raise WorkcellFormatError(
                str(path), f"cfvol.rail_joint '{self.rail_joint}' is not a joint of the robot.",
                cf.key_lines.get("rail_joint"))
        self.reach = float(cf.get("reach", 0.0) or 0.0)
        hm = cf.get("height_map") or {}
        self.height_map_origin = np.asarray(hm.get("origin", [np.nan, np.nan]), float)
        self.height_map_size = np.asarray(hm.get("size", [np.nan, np.nan]), float)
        self.params = dict(cf.get("params") or {})
        self.configurations: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for cname, pair in (cf.get("configurations") or {}).items():
            start = np.asarray(_need(pair, "start", path, f"cfvol.configurations.{cname}", list), float)
            goal = np.asarray(_need(pair, "goal", path, f"cfvol.configurations.{cname}", list), float)
            for label, q in (("start", start), ("goal", goal)):
                if q.shape != (self.num_joints,):
                    raise WorkcellFormatError(
                        str(path), f"cfvol.configurations.{cname}.{label} has {q.size} values; the robot "
                        f"has {self.num_joints} joints ({', '.join(self.joint_names)}).",
                        pair.key_lines.get(label))
            self.configurations[str(cname)] = (start, goal)
        self.obstacles = self._find_obstacles()

    # -- loading helpers -------------------------------------------------

    @staticmethod
    def _instance_names(plant) -> list[str]:
        from pydrake.multibody.tree import ModelInstanceIndex

        return [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]

    def _robot_root(self, plant):
        bodies = [plant.get_body(b) for b in plant.GetBodyIndices(self.robot)]
        for b in bodies:
            parent = [j for j in (plant.get_joint(i) for i in plant.GetJointIndices(self.robot))
                      if j.child_body().index() == b.index()]
            if not parent:
                return b
        return bodies[0]

    def _add_package_paths(self, spec, package_map, path: Path, cf) -> None:
        if spec is None:
            return
        base = path.parent
        if isinstance(spec, dict):
            for pname, ppath in spec.items():
                folder = (base / str(ppath)).resolve()
                if not folder.is_dir():
                    raise WorkcellFormatError(
                        str(path), f"cfvol.package_paths.{pname}: folder '{folder}' does not exist.",
                        cf.key_lines.get("package_paths"))
                package_map.Add(str(pname), str(folder))
        elif isinstance(spec, list):
            for ppath in spec:
                folder = (base / str(ppath)).resolve()
                if not folder.is_dir():
                    raise WorkcellFormatError(
                        str(path), f"cfvol.package_paths: folder '{folder}' does not exist.",
                        cf.key_lines.get("package_paths"))
                package_map.PopulateFromFolder(str(folder))
        else:
            raise WorkcellFormatError(
                str(path), "cfvol.package_paths must map package names to folders, or list folders "
                "to search for package.xml files.", cf.key_lines.get("package_paths"))

    def _prepare_directives(self, directives: list, package_map, path: Path) -> list:
        """Resolves relative model files and converts STL meshes (Drake 1.51
        refuses STL collision meshes)."""
        out = []
        for d in directives:
            d = dict(d) if isinstance(d, dict) else d
            if isinstance(d, dict) and isinstance(d.get("add_model"), dict):
                am = dict(d["add_model"])
                url = str(am.get("file", ""))
                if url.startswith("package://"):
                    try:
                        resolved = Path(package_map.ResolveUrl(url))
                    except Exception as e:
                        raise WorkcellFormatError(
                            str(path), f"cannot resolve '{url}': {e}. Name the package's folder in "
                            "cfvol.package_paths.", getattr(d, "line", None)) from e
                elif url.startswith("file://"):
                    resolved = Path(url[len("file://"):])
                else:
                    resolved = (path.parent / url).resolve()
                if not resolved.is_file():
                    raise WorkcellFormatError(
                        str(path), f"model file '{url}' not found (looked at {resolved}).",
                        getattr(d, "line", None))
                converted, notes = _meshes.convert_stl_references(resolved, package_map)
                self.notes.extend(notes)
                am["file"] = "file://" + str(converted)
                d = {"add_model": am}
            out.append(_plain(d))
        return out

    def _find_obstacles(self) -> dict[str, Obstacle]:
        from pydrake.geometry import Role
        from pydrake.multibody.tree import BodyIndex

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
        from pydrake.multibody.parsing import LoadModelDirectivesFromString, Parser, ProcessModelDirectives

        parser = parser or Parser(plant)
        parser.package_map().AddPackageXml(str(models_dir() / "package.xml"))
        self._add_package_paths(self._package_paths, parser.package_map(), self.path, self._raw["cfvol"])
        ProcessModelDirectives(LoadModelDirectivesFromString(yaml.safe_dump({"directives": self._directives})),
                               plant, parser)
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
        from pydrake.planning import RobotDiagramBuilder

        builder = RobotDiagramBuilder(time_step=time_step)
        self.add_to_plant(builder.plant(), builder.parser())
        if add_geometry is not None:
            add_geometry(builder.plant())
        builder.plant().Finalize()
        diagram = builder.Build()
        return diagram, diagram.plant().GetModelInstanceByName(self.robot_name)

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
        from pydrake.planning import SceneGraphCollisionChecker

        return SceneGraphCollisionChecker(
            model=self.diagram, robot_model_instances=[self.robot],
            edge_step_size=self._edge_step, env_collision_padding=0.0, self_collision_padding=0.0)

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
            raise DimensionError(what, "finite values", q.tolist())
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


def _plain(obj):
    """Turns loader mappings back into plain dicts (for yaml.safe_dump)."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_plain(v) for v in obj]
    return obj


def load_workcell(name_or_path: str | Path, **kwargs) -> Workcell:
    """Loads a built-in workcell by name, or a workcell YAML file by path.

    Args:
        name_or_path: ``"automotive"``, ``"aerospace"`` or a path to a YAML file.
        **kwargs: Passed to :class:`Workcell` (``edge_step``).

    Raises:
        UnknownCellError: neither a built-in name nor an existing file.
        WorkcellFormatError: the file is malformed (file and line in the message).
    """
    cells = builtin_cells()
    key = str(name_or_path)
    if key in cells:
        return Workcell(cells[key], **kwargs)
    path = Path(key)
    if path.suffix.lower() in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise UnknownCellError(key, cells)
        return Workcell(path, **kwargs)
    raise UnknownCellError(key, cells)
