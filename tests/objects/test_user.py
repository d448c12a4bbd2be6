"""from_mesh: a small generated mesh end to end, the cache, and every kind of bad input."""

import numpy as np
import pytest
import trimesh

import jaxgrasp as jg
from jaxgrasp.objects import user
from jaxgrasp.objects.user import MeshError


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def _l_shape() -> trimesh.Trimesh:
    """A non-convex L (two boxes): 8 x 4 x 2 cm foot and a 2 x 4 x 8 cm upright."""
    a = trimesh.creation.box(extents=(0.08, 0.04, 0.02))
    a.apply_translation((0.04, 0.02, 0.01))
    b = trimesh.creation.box(extents=(0.02, 0.04, 0.08))
    b.apply_translation((0.01, 0.02, 0.04))
    return trimesh.boolean.union([a, b], engine="manifold")


@pytest.fixture(scope="module")
def l_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "l_shape.obj"
    _l_shape().export(path)
    return path


def test_nonconvex_mesh_end_to_end_and_cached(l_file, tmp_path):
    ref = _l_shape()
    obj = jg.objects.from_mesh(l_file, density=800.0)
    assert obj.name == "l_shape" and obj.kind == "user" and obj.support_z == 0.0
    assert obj.mesh.is_watertight
    assert obj.mass == pytest.approx(800.0 * ref.volume, rel=1e-6)
    np.testing.assert_allclose(obj.com, ref.center_mass, atol=1e-9)
    assert 2 <= len(obj.pieces) <= 16
    assert all(4 <= len(p) <= 32 for p in obj.pieces)
    # The pieces cover the L: every surface sample is close to a piece.
    from jaxgrasp.objects import decompose

    pts, _ = trimesh.sample.sample_surface(ref, 2000, seed=0)
    assert decompose.distance_to_pieces(pts, obj.pieces).max() < 5e-3
    cached = list((tmp_path / "cache" / "jaxgrasp" / "objects").glob("*.npz"))
    assert len(cached) == 1 and cached[0].stem == obj.content_hash
    again = jg.objects.from_mesh(l_file, mass=0.5, name="ell")
    assert again.name == "ell" and again.mass == pytest.approx(0.5)
    assert len(again.pieces) == len(obj.pieces)
    for p, q in zip(again.pieces, obj.pieces, strict=True):
        np.testing.assert_array_equal(p, q)


def test_convex_mesh_is_one_piece_and_repaired(tmp_path):
    box = trimesh.creation.box(extents=(0.03, 0.05, 0.1))
    # Unmerged vertices (a "triangle soup") and flipped winding: both repairable.
    soup = trimesh.Trimesh(box.triangles.reshape(-1, 3), np.arange(36).reshape(-1, 3)[:, ::-1],
                           process=False)
    path = tmp_path / "box.stl"
    soup.export(path)
    obj = jg.objects.from_mesh(path, cache=False)
    assert obj.mesh.is_watertight and obj.mesh.volume == pytest.approx(0.03 * 0.05 * 0.1)
    assert len(obj.pieces) == 1 and len(obj.pieces[0]) == 8
    assert obj.mesh.bounds[0, 2] == pytest.approx(0.0)  # stands on the table
    assert obj.mass == pytest.approx(user.DEFAULT_DENSITY * 0.03 * 0.05 * 0.1)


def test_millimetre_mesh_warns_and_scale_fixes_it(tmp_path):
    box = trimesh.creation.box(extents=(30.0, 50.0, 80.0))  # millimetres
    path = tmp_path / "mm_box.ply"
    box.export(path)
    with pytest.warns(UserWarning, match="millimetres"):
        jg.objects.from_mesh(path, cache=False)
    obj = jg.objects.from_mesh(path, scale=0.001, cache=False)
    assert obj.dimensions["height"] == pytest.approx(0.08)


def test_reduce_hull_keeps_at_most_32_vertices():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    pts = user.reduce_hull(sphere.vertices, 32)
    assert len(pts) == 32
    assert trimesh.convex.convex_hull(pts).volume > 0.75 * sphere.volume


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


CUBE_OBJ = """v 0 0 0\nv 0.05 0 0\nv 0.05 0.05 0\nv 0 0.05 0\nv 0 0 0.05\nv 0.05 0 0.05
v 0.05 0.05 0.05\nv 0 0.05 0.05
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7
f 4 1 5\nf 4 5 8
"""


@pytest.mark.parametrize(
    "name, text, match",
    [
        ("mesh.txt", "v 0 0 0\n", "unsupported format"),
        ("empty.obj", "", "empty mesh"),
        ("comment.obj", "# nothing here\n", "empty mesh"),
        ("nan.obj", CUBE_OBJ.replace("v 0.05 0 0\n", "v nan 0 0\n"), "NaN/inf"),
        ("inf.obj", CUBE_OBJ.replace("v 0.05 0 0\n", "v inf 0 0\n"), "NaN/inf"),
        ("flat.obj", "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0.05 0.05 0\nf 1 2 3\nf 2 4 3\n"
                     "f 1 3 2\nf 2 3 4\n", "zero volume"),
        ("open.obj", "\n".join(CUBE_OBJ.splitlines()[:-6]) + "\n", "not watertight"),
        ("fin.obj", CUBE_OBJ + "v 0.1 0.0 0.02\nf 1 2 9\n", "not watertight"),
        ("huge.obj", CUBE_OBJ.replace("0.05", "5000"), "absurd size"),
        ("tiny.obj", CUBE_OBJ.replace("0.05", "0.0001"), "absurd size"),
        ("garbage.stl", "solid x\n facet normal oops\n", "could not read|empty mesh"),
    ],
)
def test_bad_input_gets_a_clear_error_naming_the_file(tmp_path, name, text, match):
    path = _write(tmp_path, name, text)
    with pytest.raises(MeshError, match=match) as err:
        jg.objects.from_mesh(path, cache=False)
    assert name in str(err.value)


def test_missing_file_and_bad_arguments(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such mesh file"):
        jg.objects.from_mesh(tmp_path / "nope.obj")
    path = _write(tmp_path, "cube.obj", CUBE_OBJ)
    with pytest.raises(MeshError, match="scale"):
        jg.objects.from_mesh(path, scale=-1.0)
    with pytest.raises(MeshError, match="not both"):
        jg.objects.from_mesh(path, density=1.0, mass=1.0)
    with pytest.raises(MeshError, match="density"):
        jg.objects.from_mesh(path, density=float("nan"))
    assert jg.objects.from_mesh(path, cache=False).mesh.volume == pytest.approx(0.05**3)


def test_small_hole_is_closed(tmp_path):
    path = _write(tmp_path, "holed.obj", "\n".join(CUBE_OBJ.splitlines()[:-1]) + "\n")
    obj = jg.objects.from_mesh(path, cache=False)
    assert obj.mesh.is_watertight and obj.mesh.volume == pytest.approx(0.05**3)
