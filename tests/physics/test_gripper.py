"""Gripper presets: published geometry, a grip that saturates at the force limit, and a hold."""

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.physics import Outcome, TrialParams, load_scene, make_trial
from jaxgrasp.physics.gripper import GRIPPERS, gripper


@pytest.mark.parametrize("name", list(GRIPPERS))
def test_preset_grip_saturates_at_its_force_limit(name):
    g = gripper(name)
    # the actuator force at the closed limit, target close_target: kp * |close_target|
    assert g.finger_kp * -TrialParams().close_target >= g.force_limit
    assert 0.05 <= g.max_opening <= 0.1 and g.pad_half_size[1] == 0.004


def test_published_numbers():
    franka, robotiq = gripper("franka"), gripper("robotiq_2f85")
    assert (franka.max_opening, franka.force_limit) == (0.08, 70.0)
    assert (robotiq.max_opening, robotiq.force_limit) == (0.085, 235.0)
    assert 2 * robotiq.pad_half_size[2] == pytest.approx(0.0375)


def test_unknown_gripper_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown gripper 'ur5'.*franka"):
        gripper("ur5")


# franka in `make test-all` only: one preset holding the box is the check, ~14 s each.
@pytest.mark.parametrize("name", [pytest.param("franka", marks=pytest.mark.slow), "robotiq_2f85"])
def test_preset_holds_the_box(name):
    g = gripper(name)
    # top-down on the 10 cm tall box, the pads' upper edge 3 mm above its top (palm clear)
    top_down = [0.0, 0.0, 0.1 - g.pad_half_size[2] + 0.003, 0.0, 1.0, 0.0, 0.0]
    scene = load_scene(jg.objects.make_box(), gripper=g)
    res = make_trial(scene, "mujoco")(np.asarray([top_down], np.float32))
    assert int(np.asarray(res.outcome)[0]) == Outcome.SUCCESS
    assert np.asarray(res.pad_contact)[0].all()
