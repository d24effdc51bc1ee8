"""The cell camera's obstacle map (drake_cfvol.systems.perception) against
boxes placed by hand, on the mesh test robot and a built-in cell."""

import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

import drake_cfvol as cf
from drake_cfvol.comanip.online import map_grid
from drake_cfvol.online import PerceptionParams
from drake_cfvol.systems import AddCellCamera, AddCellModel, MovingBoxes, MovingObstacle
from drake_cfvol.systems.perception import make_renderable

MESH_CELL = "tests/data/mesh_cell.yaml"


def _map(wc, boxes, q, params):
    """The obstacle map after the camera's first image: the robot at q, the
    boxes standing still."""
    builder = DiagramBuilder()
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    wc.add_to_plant(plant)
    plant.Finalize()
    make_renderable(scene_graph, plant)
    moving = builder.AddSystem(MovingBoxes(scene_graph, boxes))
    builder.Connect(moving.geometry_pose_output, scene_graph.get_source_pose_port(moving.source_id))
    model = AddCellModel(builder, workcell=wc)
    grid = map_grid(wc, params.cell)
    camera = AddCellCamera(builder, scene_graph=scene_graph, model=model, grid=grid, params=params, period=0.1)
    q_src = builder.AddSystem(ConstantVectorSource(q))
    to_pose = builder.AddSystem(MultibodyPositionToGeometryPose(plant))
    builder.Connect(q_src.get_output_port(), to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
    builder.Connect(q_src.get_output_port(), model.position_input)
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(0.05)
    mapper = camera.mapper
    return mapper.obstacle_map_output.Eval(mapper.GetMyContextFromRoot(sim.get_context()))


CASES = {
    "mesh": (
        MESH_CELL,
        [
            MovingObstacle("crate", [0.3, 0.3, 0.5], [[0.0, 0.8, -0.8, 0.25]]),
            MovingObstacle("post", [0.2, 0.4, 0.8], [[0.0, -0.75, 0.7, 0.4]]),
        ],
    ),
    "automotive": ("automotive", [MovingObstacle("cart", [0.8, 0.8, 1.2], [[0.0, 3.4, 2.0, 0.6]])]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_camera_map_matches_the_true_boxes(case):
    """Every cell a box stands on reads the box's top (rounded up to the
    height step); every cell farther than the dilation plus one cell from
    every box reads 0: the robot, the floor and the known cell are not in
    the map."""
    name, boxes = CASES[case]
    wc = cf.load_workcell(name)
    params = PerceptionParams(cell=0.05, dilation=1)
    q = np.asarray(wc.configuration("path1")[0])
    m = _map(wc, boxes, q, params)
    g = m.grid
    near = np.zeros(g.shape, bool)
    for b in boxes:
        c, half = b.position(0.0), np.asarray(b.box) / 2
        i, j, _ = g.cells_of(
            np.array([c[0] - half[0], c[0] + half[0] - 1e-9]), np.array([c[1] - half[1], c[1] + half[1] - 1e-9])
        )
        top = c[2] + half[2]
        under = m.heights[i[0] : i[1] + 1, j[0] : j[1] + 1]
        assert under.min() >= top - 1e-6, f"{b.name}: a cell under it reads {under.min():.3f} m < {top} m"
        assert under.max() <= top + params.height_step + 1e-6
        r = params.dilation + 1
        near[max(i[0] - r, 0) : i[1] + r + 1, max(j[0] - r, 0) : j[1] + r + 1] = True
    assert np.all(m.heights[~near] == 0.0), f"{np.count_nonzero(m.heights[~near])} cells away from the boxes occupied"


def test_without_new_boxes_the_map_is_empty():
    """The cell as the model has it (robot, obstacles, floor) gives an empty map."""
    wc = cf.load_workcell("automotive")
    q = np.asarray(wc.configuration("path2")[0])
    m = _map(wc, [], q, PerceptionParams())
    assert m.occupied == 0
