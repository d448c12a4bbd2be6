"""The trial protocol on a shipped kitchen object (the pitcher), both backends.

Poses are hand-placed in the pitcher's object frame (w, x, y, z quaternions):
Q_X approaches from above with the jaws closing along x, so a pose on the wall at y = 0
pinches the rim wall radially.
"""

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.physics import Outcome, load_scene, make_trial

Q_X = [0.0, 0.70710678, 0.70710678, 0.0]
Q_Y = [0.0, 1.0, 0.0, 0.0]
POSES = {
    "rim_x": ([-0.055, 0.0, 0.20, *Q_X], Outcome.SUCCESS),
    "rim_y": ([0.0, 0.055, 0.20, *Q_Y], Outcome.SUCCESS),
    "through_base": ([0.0, 0.0, 0.004, *Q_X], Outcome.COLLISION),
    "beside": ([0.30, 0.30, 0.10, *Q_X], Outcome.MISS),
    "above": ([0.0, 0.0, 0.40, *Q_X], Outcome.MISS),
}
NAMES = list(POSES)
GRASPS = np.array([POSES[n][0] for n in NAMES], np.float32)
EXPECTED = np.array([POSES[n][1] for n in NAMES])


def _check(res, expected):
    out = np.asarray(res.outcome)
    assert (out == expected).all(), dict(zip(NAMES, out.tolist(), strict=True))
    assert np.isfinite(np.asarray(res.epsilon)).all()
    ok = expected == Outcome.SUCCESS
    assert (np.asarray(res.displacement)[ok] < 0.01).all()
    assert np.asarray(res.pad_contact)[ok].all()


@pytest.fixture(scope="module")
def pitcher():
    return jg.objects.load("pitcher")


def test_pitcher_outcomes_mujoco(pitcher):
    _check(make_trial(load_scene(pitcher), backend="mujoco")(GRASPS), EXPECTED)


@pytest.mark.slow
def test_pitcher_outcomes_mjx(pitcher):
    """MJX compiles the 16-piece pitcher scene in ~100 s on 2 CPU cores: slow."""
    _check(make_trial(load_scene(pitcher), backend="mjx")(GRASPS), EXPECTED)
