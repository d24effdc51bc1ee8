"""Dynamic runs: a time-stepping plant, the robot under Drake's
InverseDynamicsController on a plant of the robot alone, the push as real
forces, the safety filter on the measured configuration."""

import numpy as np
import pytest

from drake_cfvol.comanip import run_scenario
from drake_cfvol.comanip.dynamics import _control_plant


@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
def test_control_plant_is_the_robot_alone_where_the_cell_has_it(cell, request):
    """The controller's plant holds the robot's k joints, all actuated, and
    puts every link where the cell does (the weld to a pedestal kept) on
    random configurations; its masses are the robot's own."""
    wc = request.getfixturevalue(cell)
    control = _control_plant(wc, 0.001)
    robot = control.GetModelInstanceByName(wc.robot_name)
    assert control.num_positions() == wc.num_joints == control.num_actuated_dofs()
    ctx = control.CreateDefaultContext()
    for q in np.random.default_rng(0).uniform(wc.position_lower, wc.position_upper, (10, wc.num_joints)):
        control.SetPositions(ctx, q)
        wctx = wc.plant_context(q)
        for b in control.GetBodyIndices(robot):
            body = control.get_body(b)
            X = wc.plant.GetBodyByName(body.name(), wc.robot).EvalPoseInWorld(wctx)
            np.testing.assert_allclose(body.EvalPoseInWorld(ctx).GetAsMatrix4(), X.GetAsMatrix4(), atol=1e-12)
    total = sum(control.get_body(b).default_mass() for b in control.GetBodyIndices(robot))
    assert total > 1000.0  # the published arm mass plus a 100 kg gripper (tools/make_models.py)


@pytest.mark.slow
def test_dynamic_automotive_push_keeps_the_margin_on_the_measured_robot(tmp_path):
    """The automotive pushes (250 N at the tool, 900 N m on a joint, 300 N
    toward the nearest obstacle) as real forces on a 1 ms plant under the
    inverse-dynamics driver: the measured robot never collides and keeps the
    margin (Drake's distances through the plant's SceneGraph), it tracks the
    command with a real error, the push deforms the motion, the path ends."""
    s = run_scenario(
        "automotive_push",
        tmp_path,
        record=False,
        plot=False,
        svg=False,
        scenario_text="{simulation: {plant_config: {time_step: 0.001}}, bounds: {certify: null}}",
    )
    assert s.dynamic and s.collisions == 0 and s.problems == []
    assert s.min_clearance_m >= s.clearance_m - 0.002
    assert 1e-4 < s.tracking.tracking_error_max < 0.05
    assert s.max_deviation > 0.1
    logs = np.load(tmp_path / "logs.npz")
    q = logs["update_measured_position"]
    assert np.abs(q[-1] - logs["nominal"][-1]).max() < 2e-3
