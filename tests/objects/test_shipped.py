"""The shipped kitchen objects: names, manifest/file integrity, solids, mass props, pieces."""

import hashlib

import numpy as np
import pytest
import trimesh

import jaxgrasp as jg
from jaxgrasp.objects import decompose, generate, kitchen, shipped

NAMES = ("pitcher", "pan", "plate", "tall_pitcher", "saucepan", "soup_plate", "small_jug",
         "frying_pan", "platter")


@pytest.fixture(scope="module")
def manifest():
    return shipped.manifest()


def test_names_sets_and_similar():
    assert sorted(jg.objects.names()) == sorted(NAMES)
    assert jg.objects.names("active") == ("pitcher", "pan", "plate")
    assert jg.objects.names("transfer_a") == ("tall_pitcher", "saucepan", "soup_plate")
    assert jg.objects.names("transfer_b") == ("small_jug", "frying_pan", "platter")
    assert jg.objects.similar("tall_pitcher") == "pitcher"
    assert jg.objects.similar("small_jug") == "pitcher"
    assert jg.objects.similar("frying_pan") == "pan"
    assert jg.objects.similar("soup_plate") == "plate"
    assert jg.objects.similar("plate") == "plate"
    with pytest.raises(ValueError, match="unknown object"):
        jg.objects.similar("teapot")
    with pytest.raises(ValueError, match="unknown object"):
        jg.objects.load("teapot")
    with pytest.raises(ValueError, match="unknown object set"):
        jg.objects.names("transfer_c")


def test_manifest_matches_committed_files(manifest, repo_root):
    assert sorted(manifest["objects"]) == sorted(NAMES)
    for name, entry in manifest["objects"].items():
        path = repo_root / "assets" / entry["file"]
        assert hashlib.sha256(path.read_bytes()).hexdigest() == entry["sha256"], name
        vertices, faces, pieces = shipped.read_geometry(path)
        assert len(pieces) == entry["num_pieces"]
        assert [len(p) for p in pieces] == entry["piece_vertices"]
        assert (len(vertices), len(faces)) == (entry["mesh_vertices"], entry["mesh_faces"])
        assert name in manifest["sets"][entry["set"]]
        assert entry["kind"] == jg.objects.similar(name)


@pytest.mark.parametrize("name", NAMES)
def test_object_is_a_watertight_solid_with_right_mass_properties(name):
    obj = jg.objects.load(name)
    mesh = obj.mesh
    assert obj.name == name and obj.content_hash
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert abs(mesh.bounds[0, 2]) < 1e-7 and obj.support_z == 0.0  # stands on z = 0
    # Volume: at least the revolved profile (Pappus), plus the handle; plates have none.
    profile = np.asarray(kitchen.specs()[name].profile)
    r, z = profile[:, 0], profile[:, 1]
    rn, zn = np.roll(r, -1), np.roll(z, -1)
    pappus = np.pi / 3 * np.sum((r * zn - rn * z) * (r + rn))  # 2 pi * sum(area_i * rbar_i)
    if kitchen.specs()[name].handle is None:
        assert mesh.volume == pytest.approx(pappus, rel=2e-3)
    else:
        assert pappus < mesh.volume < 1.25 * pappus
    # Mass properties recomputed from the solid by trimesh agree within 1%.
    ref = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    ref.density = kitchen.specs()[name].density
    assert obj.mass == pytest.approx(ref.mass, rel=1e-2)
    size = np.ptp(mesh.vertices, axis=0).max()
    np.testing.assert_allclose(obj.com, ref.center_mass, atol=1e-2 * size)
    np.testing.assert_allclose(obj.inertia, ref.moment_inertia,
                               atol=1e-2 * np.abs(ref.moment_inertia).max())
    assert obj.max_radius == pytest.approx(
        np.linalg.norm(ref.vertices - ref.center_mass, axis=1).max(), rel=1e-3)
    # Revolution axis z: the body is symmetric about it (handle, if any, along +x).
    assert abs(obj.com[1]) < 1e-6
    assert obj.com[0] >= -1e-6


@pytest.mark.parametrize("name", NAMES)
def test_pieces_are_small_convex_hulls(name):
    obj = jg.objects.load(name)
    assert 1 <= len(obj.pieces) <= 18
    for piece in obj.pieces:
        assert piece.shape[1] == 3 and 4 <= len(piece) <= 32
        hull = trimesh.convex.convex_hull(piece)
        assert hull.volume > 0
        assert len(hull.vertices) == len(piece)  # no interior points (MJX hull = the piece)


def test_pieces_stay_within_1mm_of_the_surface():
    """Both directions: no holes (surface -> pieces) and no bulges (revolved pieces -> solid)."""
    rng = np.random.default_rng(1)
    for name in NAMES:
        obj = jg.objects.load(name)
        spec = kitchen.specs()[name]
        points, _ = trimesh.sample.sample_surface(obj.mesh, 4000, seed=1)
        gap = decompose.distance_to_pieces(points, obj.pieces)
        assert gap.max() <= 1.0e-3, (name, gap.max())
        body = obj.pieces[: shipped.manifest()["objects"][name]["body_pieces"]]
        on_pieces = decompose.sample_hull_surfaces(body, 300, rng)
        bulge = decompose.distance_outside_profile(on_pieces, spec.profile)
        assert bulge.max() <= 1.0e-3, (name, bulge.max())


def test_graspable_sizes():
    """Rims, walls and handles fit a 0-8.5 cm parallel-jaw gripper; pitchers differ as meant."""
    specs = kitchen.specs()
    for spec in specs.values():
        assert spec.dimensions["wall"] < 0.0085
        if spec.handle is not None:
            assert 2 * max(spec.handle.half_width, spec.handle.half_thickness) < 0.085
    pitcher, tall, jug = (specs[n].dimensions for n in ("pitcher", "tall_pitcher", "small_jug"))
    assert tall["height"] > 1.3 * pitcher["height"] and tall["diameter"] < 0.9 * pitcher["diameter"]
    for a, b in (("pan", "saucepan"), ("pan", "frying_pan"), ("plate", "soup_plate"),
                 ("plate", "platter")):
        ratio = specs[a].dimensions["diameter"] / specs[b].dimensions["diameter"]
        assert 0.75 < ratio < 1.3, (a, b)


def test_transfer_pairs_close_for_pans_and_plates_far_for_pitchers():
    """The source's rim and handle land on the transfer pans and plates (measured in
    assets/README.md), the objects still differ; the pitchers stay far apart."""
    specs = kitchen.specs()
    dims = {n: s.dimensions for n, s in specs.items()}
    pan_handle = specs["pan"].handle.path
    for name in ("saucepan", "frying_pan"):
        assert dims[name]["diameter"] == dims["pan"]["diameter"]
        assert abs(dims[name]["height"] - dims["pan"]["height"]) >= 0.01
        path = specs[name].handle.path
        slope = lambda p: (p[1][1] - p[0][1]) / (p[1][0] - p[0][0])  # noqa: E731
        assert abs(path[0][1] - pan_handle[0][1]) <= 0.005
        assert slope(path) == pytest.approx(slope(pan_handle))
        assert path != pan_handle
    for name in ("plate", "soup_plate", "platter"):
        assert dims[name]["rim_clearance"] >= 0.025  # the edge pinch's lower pad fits under
    for name in ("soup_plate", "platter"):
        assert abs(dims[name]["diameter"] - dims["plate"]["diameter"]) <= 0.0101  # 5 mm in r
        assert abs(dims[name]["rim_clearance"] - dims["plate"]["rim_clearance"]) <= 0.01
        assert specs[name].profile != specs["plate"].profile
    assert dims["soup_plate"]["height"] > dims["plate"]["height"] + 0.008
    for name in ("tall_pitcher", "small_jug"):
        assert abs(dims[name]["height"] - dims["pitcher"]["height"]) > 0.05


def test_load_reads_the_stored_object_and_is_shared(monkeypatch):
    # A load is fast because it only reads what `make assets` stored: nothing is built,
    # decomposed or generated again, and a second load is a cache hit (counted, not timed).
    def rebuilt(*args, **kwargs):
        raise AssertionError("load() rebuilt the object instead of reading it")

    for mod, name in ((kitchen, "build"), (generate, "build_entry"), (decompose, "cell_pieces"),
                      (decompose, "sweep_pieces"), (decompose, "revolve")):
        monkeypatch.setattr(mod, name, rebuilt)
    shipped._load.cache_clear()
    obj = jg.objects.load("pitcher")
    assert shipped._load.cache_info().misses == 1
    assert jg.objects.load("pitcher") is obj
    assert shipped._load.cache_info().hits == 1


def test_regenerating_one_object_is_bit_for_bit(manifest, repo_root, tmp_path):
    spec = kitchen.specs()["plate"]
    entry, arrays = generate.build_entry(spec, kitchen.build(spec))
    raw = generate.write_npz(tmp_path / "plate.npz", arrays)
    assert hashlib.sha256(raw).hexdigest() == manifest["objects"]["plate"]["sha256"]
    committed = dict(manifest["objects"]["plate"])
    for key in ("file", "sha256"):
        committed.pop(key)
    assert entry == committed


@pytest.mark.slow
def test_make_assets_regenerates_everything_bit_for_bit(repo_root, tmp_path):
    generate.generate(tmp_path, renders=False, verbose=False)
    assert (tmp_path / "manifest.json").read_bytes() == (
        repo_root / "assets" / "manifest.json").read_bytes()
    for name in NAMES:
        assert (tmp_path / "objects" / f"{name}.npz").read_bytes() == (
            repo_root / "assets" / "objects" / f"{name}.npz").read_bytes()


def test_import_is_light():
    import subprocess
    import sys

    heavy = "('jax', 'mujoco', 'coacd', 'matplotlib')"
    code = ("import sys, jaxgrasp.objects as o; o.names(); "
            f"print(sorted(m for m in {heavy} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("name", [n for n in NAMES if kitchen.specs()[n].handle is not None])
def test_handle_is_fused_to_the_wall_and_stays_out_of_the_cavity(name):
    obj = jg.objects.load(name)
    assert obj.mesh.body_count == 1  # one solid: the handle ends inside the wall
    spec = kitchen.specs()[name]
    (_, _), (_, _), (rb, _), (rt, h), (rti, _), *_ = spec.profile
    nbody = shipped.manifest()["objects"][name]["body_pieces"]
    for piece in obj.pieces[nbody:]:
        r, z = np.hypot(piece[:, 0], piece[:, 1]), piece[:, 2]
        inner = rb + (rt - rb) * z / h - (rt - rti)
        assert np.all(r > inner + 1e-3)
        assert np.all(piece[:, 0] > 0)  # along +x
