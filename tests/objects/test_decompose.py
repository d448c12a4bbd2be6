"""Geometry helpers: revolve, analytic sector pieces, swept handles, exact distances."""

import numpy as np
import pytest
import trimesh

from jaxgrasp.objects import decompose, kitchen


def test_revolve_is_watertight_with_the_pappus_volume():
    profile = [(0.0, 0.0), (0.05, 0.0), (0.05, 0.1), (0.0, 0.1)]
    v, f = decompose.revolve(profile, 64)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.volume > 0
    expected = 0.5 * 64 * np.sin(2 * np.pi / 64) * 0.05**2 * 0.1  # inscribed 64-gon prism
    assert mesh.volume == pytest.approx(expected, rel=1e-9)
    with pytest.raises(ValueError, match="counter-clockwise"):
        decompose.revolve(profile[::-1], 16)


def test_distance_to_pieces_is_exact_on_a_cube():
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    points = np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 1.3], [1.3, 1.4, 0.5], [1.3, 1.4, 1.2],
                       [-0.2, 0.5, 0.5]])
    d = decompose.distance_to_pieces(points, [cube], cutoff=10.0)
    np.testing.assert_allclose(d, [0.0, 0.3, 0.5, np.sqrt(0.09 + 0.16 + 0.04), 0.2], atol=1e-12)
    # Beyond the cutoff a lower bound is returned, never more than the true distance.
    far = decompose.distance_to_pieces(points[3:4], [cube], cutoff=0.1)
    assert 0.3 <= far[0] <= np.sqrt(0.29)


def test_distance_outside_profile():
    profile = [(0.0, 0.0), (0.1, 0.0), (0.1, 0.05), (0.0, 0.05)]
    pts = np.array([[0.05, 0.0, 0.02], [0.0, 0.13, 0.02], [0.12, 0.0, 0.08], [0, 0, -0.01]])
    d = decompose.distance_outside_profile(pts, profile)
    np.testing.assert_allclose(d, [0.0, 0.03, np.hypot(0.02, 0.03), 0.01], atol=1e-12)


@pytest.mark.parametrize("tolerance", [0.5e-3, 2e-3])
def test_sector_pieces_meet_their_tolerance(tolerance):
    """Smaller tolerance -> more sectors; the measured deviation obeys the bound both ways."""
    profile, cells = kitchen.cup_profile(0.12, 0.06, 0.07, 0.004, 0.006)
    profile = np.asarray(profile)
    pieces = []
    for cell in cells:
        pieces += decompose.cell_pieces(profile, cell, tolerance=tolerance)
    assert all(len(p) <= 32 for p in pieces)
    v, f = decompose.revolve(profile, 256)
    mesh = trimesh.Trimesh(v, f, process=False)
    points, _ = trimesh.sample.sample_surface(mesh, 4000, seed=0)
    gap = decompose.distance_to_pieces(points, pieces)
    bulge = decompose.distance_outside_profile(
        decompose.sample_hull_surfaces(pieces, 400, np.random.default_rng(0)), profile)
    assert gap.max() <= tolerance * 1.02 + 1e-4  # + chord error of the 256-segment mesh
    assert bulge.max() <= tolerance * 1.02
    assert max(gap.max(), bulge.max()) > 0.5 * tolerance  # the bound is tight, not vacuous
    # Sector count follows d = r |n_r| (1 - cos h) / (1 + cos h) <= tolerance.
    n_expected = 3
    while 0.07 * decompose._chord_factor(np.pi / n_expected) > tolerance:
        n_expected += 1
    assert len(pieces) == 1 + n_expected


def test_sweep_pieces_are_exact_prisms_with_mitred_joints():
    path = np.array([[0.0, 0, 0.0], [0.05, 0, 0.0], [0.05, 0, -0.08]])
    section = decompose.chamfered_rectangle(0.005, 0.01, 0.002)
    pieces = decompose.sweep_pieces(path, section)
    assert [len(p) for p in pieces] == [16, 16]
    a, b = (trimesh.convex.convex_hull(p) for p in pieces)
    # Mitred prisms: volume = section area x centre-line length, and they meet on the mitre
    # plane without overlap or gap.
    section_area = 0.01 * 0.02 - 2 * 0.002**2
    assert a.volume + b.volume == pytest.approx(section_area * 0.13, rel=1e-9)
    union = trimesh.boolean.union([a, b], engine="manifold")
    assert union.volume == pytest.approx(a.volume + b.volume, rel=1e-5)
