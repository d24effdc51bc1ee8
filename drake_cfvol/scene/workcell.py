"""Workcells: a robot and its obstacles, loaded from one YAML file.

The file's schema is :mod:`drake_cfvol.scene.schema`; the queries on the
scene are :mod:`drake_cfvol.scene.queries`.

Every obstacle is a body outside the robot's model instance, welded to the
world, with proximity geometry; the floor is one of them.
"""

import copy
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.geometry import Role
from pydrake.multibody.parsing import ModelDirectives, Parser, ProcessModelDirectives
from pydrake.multibody.tree import BodyIndex, ModelInstanceIndex
from pydrake.planning import RobotDiagramBuilder

from drake_cfvol.scene import meshes as _meshes
from drake_cfvol.exceptions import UnknownCellError, WorkcellFileNotFoundError, WorkcellFormatError
from drake_cfvol.scene.arrays import SceneArrays, scene_arrays

from drake_cfvol.scene.queries import WorkcellQueries, geometry_key, robot_geometry_ids
from drake_cfvol.scene.schema import (DEFAULT_EDGE_STEP, CfvolSection, HeightMapExtent, NamedConfiguration,
                                      WorkcellFile, builtin_cells, models_dir, read_workcell_file)

__all__ = ["Obstacle", "Workcell", "WorkcellFile", "CfvolSection", "HeightMapExtent", "NamedConfiguration",
           "builtin_cells", "load_workcell", "models_dir", "geometry_key", "robot_geometry_ids"]


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

class Workcell(WorkcellQueries):
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

        self._edge_step = float(edge_step)
        self._cache: dict = {}  # results computed once (WorkcellQueries._memo)
        self._build_diagram(spec, lines)
        self._read_joints(cf, lines)
        self._read_frames(cf, lines)
        self._read_settings(cf, lines)
        self.obstacles = self._find_obstacles()
        self._geometry_owner = {gid: obs.name for obs in self.obstacles.values() for gid in obs.geometry_ids}

    def _build_diagram(self, spec, lines) -> None:
        """The RobotDiagram from the directives; the robot's instance."""
        cf, path = spec.cfvol, self.path
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

    def _read_joints(self, cf, lines) -> None:
        """The robot's joints, their kinds and limits (file overrides applied)."""
        path = self.path
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


    def _read_frames(self, cf, lines) -> None:
        """The tool and base frames and the rail joint."""
        path, plant = self.path, self.plant
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

    def _read_settings(self, cf, lines) -> None:
        """Reach, height map extent, parameter overrides, named configurations."""
        path = self.path
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
        return self._memo("scene_arrays", lambda: scene_arrays(self))

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
