"""Size-aware transfer: the size map (hand-computed points) and its use by jg.learn.transfer."""

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.learn.setup.resize import SizeMap, object_size

#: a 20 cm pan onto a 16 cm, 9.5 cm tall pan: rim radius 0.10 -> 0.08 m, height 0.065 -> 0.095 m.
PAN_TO_SAUCEPAN = SizeMap(0.10, 0.065, 0.08, 0.095)
Q = np.array([0.5, 0.5, -0.5, 0.5])


def pose(x, y, z):
    return np.concatenate([[x, y, z], Q])


def test_rim_goes_to_rim_and_handle_keeps_its_distance():
    m = PAN_TO_SAUCEPAN
    # a rim pinch at the rim top lands on the target's rim top
    np.testing.assert_allclose(m(pose(0.0, 0.1, 0.065))[:3], [0.0, 0.08, 0.095], atol=1e-7)
    # inside the rim: radial and vertical scaling (0.05 * 0.8, 0.03 * 0.095 / 0.065)
    np.testing.assert_allclose(m(pose(0.03, 0.04, 0.03))[:3],
                               [0.024, 0.032, 0.03 * 0.095 / 0.065], rtol=1e-6)
    # outside the rim (a handle 10 cm beyond it) and above the top: shifted, not scaled
    np.testing.assert_allclose(m(pose(0.2, 0.0, 0.1))[:3], [0.18, 0.0, 0.13], rtol=1e-6)
    # orientations are kept
    np.testing.assert_array_equal(m(pose(0.2, 0.0, 0.1))[3:], Q.astype(np.float32))


def test_map_is_continuous_monotone_and_identity_for_equal_sizes():
    m = PAN_TO_SAUCEPAN
    r = np.linspace(0.0, 0.3, 301)
    g = np.stack([pose(x, 0.0, 0.065 * x / 0.1) for x in r])
    out = m(g)
    assert np.all(np.diff(out[:, 0]) > 0) and np.all(np.diff(out[:, 2]) > 0)
    assert np.max(np.abs(np.diff(out[:, 0]))) < 0.0011  # no jump at the rim radius
    same = SizeMap(0.1, 0.065, 0.1, 0.065)
    np.testing.assert_allclose(same(g), g.astype(np.float32), atol=1e-7)
    with pytest.raises(ValueError, match="target_radius"):
        SizeMap(0.1, 0.065, 0.0, 0.065)
    with pytest.raises(ValueError, match="7"):
        m(np.zeros((3, 6)))


def test_object_size_from_dimensions_or_mesh(box):
    pan = jg.objects.load("pan")
    assert object_size(pan) == (pytest.approx(0.10), pytest.approx(0.065))
    assert object_size(box) == (pytest.approx(0.03), pytest.approx(0.10))


def test_size_aware_transfer_maps_modes_and_sketch(box, fake_sim, small_params):
    src = jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4, seed=2,
                          params=small_params, trial=fake_sim, progress=False)
    grow = SizeMap(0.03, 0.10, 0.032, 0.104)
    tr = jg.learn.transfer(src, box, modes="source", seed=4, trial=fake_sim,
                           progress=False, size_aware=grow)
    assert tr.sketch == "source_resized" and tr.modes_kind == "source_resized"
    np.testing.assert_allclose(tr.modes, grow(src.demos.poses), atol=1e-6)
    plain = jg.learn.transfer(src, box, modes="source", seed=4, trial=fake_sim,
                              progress=False)
    np.testing.assert_allclose(tr.sketch_points, grow(plain.sketch_points), atol=1e-6)
    with pytest.raises(ValueError, match="shipped"):
        jg.learn.transfer(src, box, modes="source", trial=fake_sim, size_aware=True)
    with pytest.raises(ValueError, match="size_aware"):
        jg.learn.transfer(src, box, modes="source", trial=fake_sim, size_aware="yes")
