"""Grasp files: every format round-trips, ACRONYM's frame is Franka's, bad files are refused."""

import json
from pathlib import Path

import h5py
import jsonschema
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.learn.files import export as E

DOCS_SCHEMA = Path(__file__).resolve().parents[2] / "docs" / "grasps.schema.json"


@pytest.fixture(scope="module")
def fake_result(box, fake_sim, small_params):
    return jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4, seed=3,
                           params=small_params, trial=fake_sim, progress=False)


def test_selection_is_the_distinct_successes(fake_result):
    g = E.select_grasps(fake_result)
    assert len(g.grasps) == len(fake_result.grasps) > 0
    np.testing.assert_allclose(g.grasps, fake_result.grasps, atol=1e-6)
    assert (g.outcome == 0).all() and (g.epsilon > 0).all()
    every = E.select_grasps(fake_result, outcome="all", distinct=False)
    assert len(every.grasps) == fake_result.outcomes.size
    with pytest.raises(ValueError, match="outcome must be one of"):
        E.select_grasps(fake_result, outcome="won")


@pytest.mark.parametrize("suffix", [".npz", ".json", ".h5"])
def test_round_trip(tmp_path, fake_result, suffix):
    path = E.export_grasps(fake_result, tmp_path / f"g{suffix}", outcome="all")
    back = E.load_grasps(path)
    ref = E.select_grasps(fake_result, outcome="all")
    np.testing.assert_allclose(back.transforms, ref.transforms, atol=1e-9)
    np.testing.assert_allclose(back.grasps, ref.grasps, atol=1e-9)
    np.testing.assert_array_equal(back.outcome, ref.outcome)
    np.testing.assert_allclose(back.epsilon, ref.epsilon)
    np.testing.assert_allclose(back.width, ref.width)
    assert (back.object_name, back.object_hash) == (fake_result.object_name,
                                                    fake_result.object_hash)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_acronym_layout_puts_franka_fingertips_at_the_grasp_center(tmp_path, fake_result):
    path = E.export_grasps(fake_result, tmp_path / "g.h5", mesh_file="pitcher.obj")
    ours = E.select_grasps(fake_result)
    with h5py.File(path, "r") as f:
        t = np.asarray(f["grasps/transforms"])
        ok = np.asarray(f["grasps/qualities/flex/object_in_gripper"])
        assert f["object/file"][()].decode() == "pitcher.obj"
        assert float(f["object/scale"][()]) == 1.0
    assert t.shape == (len(ours.grasps), 4, 4) and (ok == 1).all()
    # ACRONYM: fingertips TCP ahead of the hand along +z, fingers closing along x
    tcp = t[:, :3, :3] @ np.array([0.0, 0.0, E.ACRONYM_TCP]) + t[:, :3, 3]
    np.testing.assert_allclose(tcp, ours.grasps[:, :3], atol=1e-9)
    np.testing.assert_allclose(t[:, :3, 0], ours.transforms[:, :3, 1], atol=1e-9)
    np.testing.assert_allclose(t[:, :3, 2], ours.transforms[:, :3, 2], atol=1e-9)


def test_plain_acronym_file_reads(tmp_path):
    """A file with only ACRONYM's own keys (as its dataset ships) loads."""
    q = np.array([[0.9, 0.1, -0.3, 0.2]]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    g = np.concatenate([[[0.01, 0.02, 0.1]], q], axis=1)
    t = E.to_transforms(g) @ E._ACRONYM_IN_GRASP
    with h5py.File(tmp_path / "Mug_abc.h5", "w") as f:
        f["grasps/transforms"] = t
        f["grasps/qualities/flex/object_in_gripper"] = np.array([1])
        f["object/file"] = "meshes/Mug/abc.obj"
        f["object/scale"] = 0.5
    back = E.load_grasps(tmp_path / "Mug_abc.h5")
    np.testing.assert_allclose(back.grasps, g, atol=1e-9)
    assert back.object_name == "abc" and back.outcome.tolist() == [0]


def test_json_schema_in_docs_is_the_module_schema():
    assert json.loads(DOCS_SCHEMA.read_text()) == json.loads(json.dumps(E.SCHEMA))


def test_bad_files_are_refused(tmp_path, fake_result):
    with pytest.raises(ValueError, match="unknown grasp file type"):
        E.export_grasps(fake_result, tmp_path / "g.csv")
    assert not list(tmp_path.iterdir())
    with pytest.raises(FileNotFoundError, match="no such grasp file"):
        E.load_grasps(tmp_path / "none.h5")
    (tmp_path / "torn.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 20)
    (tmp_path / "other.json").write_text(json.dumps({"format": "something-else"}))
    (tmp_path / "text.npz").write_text("not a zip")
    for name in ("torn.h5", "other.json", "text.npz"):
        with pytest.raises(ValueError, match="not a valid grasp file|not an intact"):
            E.load_grasps(tmp_path / name)
    path = E.export_grasps(fake_result, tmp_path / "g.json")
    doc = json.loads(path.read_text())
    doc["grasps"][0]["transform"][0][0] = 7.0
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="not all rigid"):
        E.load_grasps(path)
    jsonschema.validate(json.loads(E.export_grasps(fake_result, path).read_text()), E.SCHEMA)
