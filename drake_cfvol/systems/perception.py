"""The cell camera: a depth camera over the cell, the system that turns
its points into an obstacle map (SPEC 12), and their settings
(:class:`PerceptionConfig`)."""

import dataclasses
import math
import typing
from collections.abc import Iterable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    ClippingRange,
    ColorRenderCamera,
    Convex,
    DepthRange,
    DepthRenderCamera,
    GeometryInstance,
    MakeRenderEngineVtk,
    Mesh,
    PerceptionProperties,
    RenderCameraCore,
    RenderEngineVtkParams,
    Role,
    SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.perception import BaseField, DepthImageToPointCloud, PointCloud
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantValueSource
from pydrake.systems.sensors import CameraInfo, ImageDepth32F, ImageLabel16I, RgbdSensor

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.online.obstacle_map import MapGrid, ObstacleMap, PerceptionParams
from drake_cfvol.scene.robot import robot_bodies
from drake_cfvol.scene.workcell import Workcell

__all__ = [
    "make_renderable",
    "floor_points",
    "ObstacleMapper",
    "AddCellCamera",
    "CellCamera",
    "AddCellModel",
    "CellModel",
    "CAMERA_RENDERER",
    "MODEL_RENDERER",
    "overhead_pose",
    "PerceptionConfig",
]


@dataclasses.dataclass
class PerceptionConfig:
    """The cell camera and its obstacle map.

    Attributes:
        camera_period: s between camera images; > 0.
        width, height: the camera's image, px (at least 16 x 16).
        cell: the obstacle map's cell side, m; > 0.
        obstacle_speed: the speed assumed for what the camera sees, m/s
            (>= 0): the map lends each occupied cell's height to the cells
            it could reach before newer bounds are in force.
    """

    camera_period: float = 0.05
    width: int = 320
    height: int = 240
    cell: float = 0.05
    obstacle_speed: float = 0.5


#: The renderer that draws the real cell (everything with a perception role).
CAMERA_RENDERER = "cell_camera"
#: The renderer that draws the cell's model (the known obstacles and the
#: robot at its known pose, in a SceneGraph of their own: :func:`AddCellModel`).
MODEL_RENDERER = "cell_model"


class ObstacleMapper(LeafSystem):
    """Points of the cell camera -> the obstacle map (:class:`ObstacleMap`).

    .. pydrake_system::

        name: ObstacleMapper
        input_ports:
        - point_cloud
        - depth_image
        - model_depth_image
        - model_label_image
        output_ports:
        - obstacle_map
        - occupied_cells

    At each update (every ``period`` s) a pixel of ``depth_image`` is *new*
    where it is nearer than ``model_depth_image`` (the cell model rendered
    from the same camera) by more than ``params.depth_tolerance``; where
    they agree it shows the robot (its label in ``model_label_image``: the
    cells behind it keep what they had) or the known cell (its cell is seen
    clear). ``point_cloud`` (the depth image in the world frame, pixel by
    pixel: Drake's ``DepthImageToPointCloud``) gives the points. A pixel
    with no return in either image (beyond the modelled floor) sees the
    floor plane z = 0 where its ray meets it (given the camera's
    ``camera_info`` and ``X_WC``). The map is the system's state.

    Args:
        grid: the map's grid.
        robot_labels: the render labels of the robot's geometry.
        params: the perception settings.
        period: s between images.
        offset: s before the first.
        camera_info, X_WC: the camera's intrinsics and pose (None: pixels
            without a return say nothing).
    """

    def __init__(
        self,
        grid: MapGrid,
        robot_labels: Iterable[int],
        *,
        params: PerceptionParams = PerceptionParams(),
        period: float = 0.05,
        offset: float = 0.0,
        camera_info: CameraInfo | None = None,
        X_WC: RigidTransform | None = None,
    ):
        super().__init__()
        if not period > 0:
            raise ParameterError(f"ObstacleMapper: period must be > 0 s, got {period!r}.")
        self.grid, self.params, self.period = grid, params, float(period)
        self._robot_labels = np.array(sorted(int(v) for v in robot_labels), np.int64)
        self._floor = None if camera_info is None or X_WC is None else floor_points(camera_info, X_WC)
        self.point_cloud_input = self.DeclareAbstractInputPort("point_cloud", AbstractValue.Make(PointCloud()))
        self.depth_image_input = self.DeclareAbstractInputPort("depth_image", AbstractValue.Make(ImageDepth32F()))
        self.model_depth_image_input = self.DeclareAbstractInputPort(
            "model_depth_image", AbstractValue.Make(ImageDepth32F())
        )
        self.model_label_image_input = self.DeclareAbstractInputPort(
            "model_label_image", AbstractValue.Make(ImageLabel16I())
        )
        self._map = self.DeclareAbstractState(AbstractValue.Make(ObstacleMap.empty(grid)))
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self.period, offset_sec=float(offset), update=self._update
        )
        self.obstacle_map_output = self.DeclareStateOutputPort("obstacle_map", self._map)
        self.occupied_cells_output = self.DeclareVectorOutputPort(
            "occupied_cells",
            1,
            lambda c, o: o.SetAtIndex(0, float(c.get_abstract_state(self._map).get_value().occupied)),
            prerequisites_of_calc={self.abstract_state_ticket(self._map)},
        )

    def classify(
        self, depth: np.ndarray, model_depth: np.ndarray, model_label: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(new, seen, robot): per pixel, something the model lacks; the
        known cell (not the robot) seen as the model has it; the robot seen
        where the model has it."""
        d = np.asarray(depth, float).reshape(-1)
        m = np.asarray(model_depth, float).reshape(-1)
        lab = np.asarray(model_label).reshape(-1)
        valid = np.isfinite(d)
        new = valid & ~(d >= m - self.params.depth_tolerance)  # m = inf: the model sees nothing there
        robot = np.isin(lab, self._robot_labels) & ~new
        seen = valid & ~new & ~robot
        return new, seen, robot

    def _update(self, context, state) -> None:
        cloud = self.point_cloud_input.Eval(context)
        depth = self.depth_image_input.Eval(context).data
        model = self.model_depth_image_input.Eval(context).data
        label = self.model_label_image_input.Eval(context).data
        new, seen, robot = self.classify(depth, model, label)
        X = cloud.xyzs()  # (3, N) float32, read where it lies
        # The pixels are taken where they lie (a mask per kind), never gathered.
        seen_sources, hidden_sources = [(X, seen)], [(X, robot)]
        if self._floor is not None:
            hidden_sources.append((self._floor, robot))
            none = ~np.isfinite(np.asarray(depth, float).reshape(-1)) & ~np.isfinite(
                np.asarray(model, float).reshape(-1)
            )
            seen_sources.append((self._floor, none))
        old = context.get_abstract_state(self._map).get_value()
        state.get_mutable_abstract_state(self._map).set_value(
            old.integrate_sources([(X, new)], seen_sources, context.get_time(), self.params, hidden_sources)
        )


def floor_points(camera_info, X_WC: RigidTransform) -> np.ndarray:
    """(3, w h) where each pixel's ray (row by row, as Drake's point clouds)
    meets the floor plane z = 0, m (inf where it does not, going up)."""
    u, v = np.meshgrid(np.arange(camera_info.width()), np.arange(camera_info.height()))
    d_C = np.stack(
        [
            (u.ravel() + 0.5 - camera_info.center_x()) / camera_info.focal_x(),
            (v.ravel() + 0.5 - camera_info.center_y()) / camera_info.focal_y(),
            np.ones(u.size),
        ]
    )
    d_W = X_WC.rotation().matrix() @ d_C
    p = X_WC.translation()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d_W[2] < 0, -p[2] / d_W[2], np.inf)
    return p[:, None] + t * d_W


def overhead_pose(origin, size, fov_y: float, aspect: float, margin: float = 0.5) -> RigidTransform:
    """X_WC of a camera looking straight down at the centre of a floor
    rectangle (origin, size), high enough that the rectangle grown by
    ``margin`` fills its view (fov_y rad, width/height ``aspect``)."""
    cx, cy = origin[0] + size[0] / 2, origin[1] + size[1] / 2
    half_y = math.tan(fov_y / 2)
    half_x = half_y * aspect
    h = max((size[0] / 2 + margin) / half_x, (size[1] / 2 + margin) / half_y)
    # Camera frame: z forward (down), x right, y down in the image.
    return RigidTransform(RotationMatrix.MakeXRotation(math.pi), [cx, cy, h])


def _obj_without_normals(shape) -> bool:
    """A Mesh from an OBJ file that has no vertex normals (Drake's VTK
    renderer refuses those)."""
    if not isinstance(shape, Mesh) or shape.extension() != ".obj" or not shape.source().is_path():
        return False
    with open(shape.source().path(), errors="replace") as f:
        return not any(line.startswith("vn ") for line in f)


def make_renderable(scene_graph, plant) -> int:
    """Gives every perception mesh of ``plant`` that the renderer cannot draw
    (an OBJ without normals) a stand-in: its convex hull (Drake's
    ``Convex``) on the same frame, with the mesh's perception properties,
    the mesh itself losing the perception role. The camera and the cell
    model then see the same hulls. Returns how many were replaced."""
    inspector = scene_graph.model_inspector()
    source = plant.get_source_id()
    n = 0
    for gid in inspector.GetAllGeometryIds(Role.kPerception):
        if inspector.GetOwningSourceName(gid) != inspector.GetName(source) or not _obj_without_normals(
            inspector.GetShape(gid)
        ):
            continue
        shape = inspector.GetShape(gid)
        props = PerceptionProperties(inspector.GetPerceptionProperties(gid))
        proxy = scene_graph.RegisterGeometry(
            source,
            inspector.GetFrameId(gid),
            GeometryInstance(
                inspector.GetPoseInFrame(gid),
                Convex(shape.source().path(), shape.scale3()),
                f"{inspector.GetName(gid)}_hull",
            ),
        )
        scene_graph.AssignRole(source, proxy, props)
        scene_graph.RemoveRole(source, gid, Role.kPerception)
        n += 1
    return n


class CellModel(typing.NamedTuple):
    """What :func:`AddCellModel` added: the known cell in a SceneGraph of
    its own, posed from ``position_input`` (the robot's commanded
    position)."""

    plant: object
    scene_graph: object
    robot: object
    position_input: object


def AddCellModel(builder: DiagramBuilder, *, workcell: Workcell, name: str = "cell_model") -> CellModel:
    """Adds the cell's model (its known obstacles and the robot, a
    kinematic plant and a SceneGraph of their own) to someone's builder:
    what the cell camera expects to see. Connect the robot's position to
    ``position_input``."""
    from pydrake.geometry import SceneGraph
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.systems.rendering import MultibodyPositionToGeometryPose

    scene_graph = builder.AddNamedSystem(f"{name}_scene_graph", SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.set_name(f"{name}_plant")
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    robot = workcell.add_to_plant(plant)
    plant.Finalize()
    make_renderable(scene_graph, plant)
    to_pose = builder.AddNamedSystem(f"{name}_to_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
    return CellModel(plant, scene_graph, robot, to_pose.get_input_port())


class CellCamera(typing.NamedTuple):
    """What :func:`AddCellCamera` added."""

    camera: RgbdSensor
    model_camera: RgbdSensor
    to_point_cloud: DepthImageToPointCloud
    mapper: ObstacleMapper
    X_WC: RigidTransform


def _renderer(scene_graph, name: str) -> None:
    if not scene_graph.HasRenderer(name):
        scene_graph.AddRenderer(name, MakeRenderEngineVtk(RenderEngineVtkParams()))


def robot_render_labels(plant, scene_graph, robot) -> set[int]:
    """The render labels of the robot's perception geometry."""
    inspector = scene_graph.model_inspector()
    labels = set()
    for b in robot_bodies(plant, robot):
        frame = plant.GetBodyFrameIdIfExists(plant.get_body(b).index())
        if frame is None:
            continue
        for gid in inspector.GetGeometries(frame, Role.kPerception):
            props = inspector.GetPerceptionProperties(gid)
            if props.HasProperty("label", "id"):
                labels.add(int(props.GetProperty("label", "id")))
    return labels


def AddCellCamera(
    builder: DiagramBuilder,
    *,
    scene_graph: SceneGraph,
    model: CellModel,
    grid: MapGrid,
    params: PerceptionParams = PerceptionParams(),
    width: int = PerceptionConfig.width,
    height: int = PerceptionConfig.height,
    fov_y: float = math.radians(70.0),
    period: float = PerceptionConfig.camera_period,
    offset: float = 0.0,
    X_WC: RigidTransform | None = None,
) -> CellCamera:
    """Adds an overhead depth camera over the map's grid and its obstacle
    mapper to someone's builder: a camera on the station's SceneGraph (the
    real cell: everything with a perception role) and a model camera on the
    cell model's (:func:`AddCellModel`), both Drake ``RgbdSensor`` with
    ``RenderEngineVtk``, same pose and intrinsics; Drake's
    ``DepthImageToPointCloud`` (world frame); an :class:`ObstacleMapper`.
    Give virtual geometry (the volume V's boxes) no perception role, and
    meshes the renderer cannot draw a stand-in (:func:`make_renderable`).

    Args:
        builder: the DiagramBuilder holding ``scene_graph``.
        scene_graph: the station's SceneGraph.
        model: the cell model (the robot's geometry there is filtered out).
        grid: the obstacle map's grid (the camera looks at its centre).
        params: the perception settings.
        width, height, fov_y: the images, px, and the vertical field of
            view, rad.
        period, offset: the mapper's update, s.
        X_WC: the camera's pose (default :func:`overhead_pose`).

    Returns:
        The :class:`CellCamera`.
    """
    _renderer(scene_graph, CAMERA_RENDERER)
    _renderer(model.scene_graph, MODEL_RENDERER)
    info = CameraInfo(width=int(width), height=int(height), fov_y=float(fov_y))
    if X_WC is None:
        size = (grid.shape[0] * grid.side, grid.shape[1] * grid.side)
        X_WC = overhead_pose(grid.origin, size, fov_y, width / height)
    far = 3.0 * float(np.linalg.norm(X_WC.translation())) + 10.0

    def sensor(sg, renderer: str, name: str) -> RgbdSensor:
        core = RenderCameraCore(renderer, info, ClippingRange(0.05, far), RigidTransform())
        s = builder.AddNamedSystem(
            name,
            RgbdSensor(
                sg.world_frame_id(),
                X_WC,
                ColorRenderCamera(core, False),
                DepthRenderCamera(core, DepthRange(0.06, far - 0.01)),
            ),
        )
        builder.Connect(sg.get_query_output_port(), s.query_object_input_port())
        return s

    camera = sensor(scene_graph, CAMERA_RENDERER, "cell_camera")
    model_camera = sensor(model.scene_graph, MODEL_RENDERER, "cell_model_camera")
    to_cloud = builder.AddNamedSystem("cell_point_cloud", DepthImageToPointCloud(info, fields=BaseField.kXYZs))
    pose = builder.AddNamedSystem("cell_camera_pose", ConstantValueSource(AbstractValue.Make(X_WC)))
    builder.Connect(camera.depth_image_32F_output_port(), to_cloud.depth_image_input_port())
    builder.Connect(pose.get_output_port(), to_cloud.camera_pose_input_port())
    mapper = builder.AddNamedSystem(
        "obstacle_mapper",
        ObstacleMapper(
            grid,
            robot_render_labels(model.plant, model.scene_graph, model.robot),
            params=params,
            period=period,
            offset=offset,
            camera_info=info,
            X_WC=X_WC,
        ),
    )
    builder.Connect(to_cloud.point_cloud_output_port(), mapper.point_cloud_input)
    builder.Connect(camera.depth_image_32F_output_port(), mapper.depth_image_input)
    builder.Connect(model_camera.depth_image_32F_output_port(), mapper.model_depth_image_input)
    builder.Connect(model_camera.label_image_output_port(), mapper.model_label_image_input)
    return CellCamera(camera, model_camera, to_cloud, mapper, X_WC)
