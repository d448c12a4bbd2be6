"""The any-object set: 24 shipped pybullet random objects, credited, small, loadable by name."""

import hashlib
import re

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.objects import any_object

#: Named pybullet meshes stay out of the set: only random_urdfs ids.
NAMED = ("duck", "bunny", "teddy", "sphere", "cube", "table", "tray")


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def test_the_set_is_24_credited_random_objects():
    entries = jg.objects.any_object_set()
    assert len(entries) == any_object.SET_SIZE == 24
    total = 0
    for name, e in entries.items():
        assert re.fullmatch(r"random_\d{3}", name) and name == f"random_{e['id']}"
        assert not any(n in name for n in NAMED)
        data = e["path"].read_bytes()
        assert hashlib.sha256(data).hexdigest() == e["sha256"]
        assert e["scale"] == 0.015 and e["volume_cm3"] >= 1.0
        total += len(data)
    assert total < 3_000_000
    root = any_object.set_dir()
    source = (root / "SOURCE.md").read_text()
    assert "pybullet 3.2.7" in source and "zlib" in source and "default_rng(0)" in source
    assert all(e["id"] in source for e in entries.values())
    assert "must not be misrepresented" in (root / "LICENSE.txt").read_text()
    shapes = {e["shape"].split(",")[0] for e in entries.values()}
    assert {"flat", "round"} <= shapes  # mixed shapes, not one kind


def test_the_draw_order_is_the_documented_one():
    order = [f"{int(i):03d}" for i in np.random.default_rng(any_object.DRAW_SEED).permutation(
        1000)]
    ids = [e["id"] for e in jg.objects.any_object_set().values()]
    positions = [order.index(i) for i in ids]
    assert positions == sorted(positions)  # kept in draw order, skipped ones left out


def test_load_by_name_everywhere():
    obj = jg.objects.load_any("random_511")  # convex: one piece, no CoACD
    assert obj.name == "random_511" and obj.set == "any_object" and len(obj.pieces) == 1
    assert obj.support_z == 0.0 and obj.mass > 0
    np.testing.assert_allclose(np.sort(obj.mesh.extents),
                               np.sort(jg.objects.any_object_set()["random_511"]
                                       ["extents_mm"]) / 1e3, atol=1e-4)
    assert jg.learn.inputs.resolve_object("random_511").content_hash == obj.content_hash
    with pytest.raises(ValueError, match="unknown any-object 'random_999'"):
        jg.objects.load_any("random_999")
    with pytest.raises(ValueError, match="unknown object 'teapot'"):
        jg.objects.load_any("teapot")


@pytest.mark.parametrize(("extents", "solidity", "label"), [
    ((0.03, 0.09, 0.12), 0.7, "flat"), ((0.03, 0.03, 0.09), 0.9, "elongated"),
    ((0.03, 0.08, 0.18), 0.6, "flat, elongated"), ((0.09, 0.09, 0.12), 0.3, "round, concave")])
def test_shape_class(extents, solidity, label):
    assert any_object.shape_class(extents, solidity) == label
