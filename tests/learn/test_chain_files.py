"""Chain files: save/load round trip, atomic writes, and clear errors (fake trial: instant)."""

import json

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.learn.files import atomic as R


@pytest.fixture(scope="module")
def fake_result(box, fake_sim, small_params):
    return jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4, seed=3,
                           params=small_params, trial=fake_sim, progress=False)


def test_result_fields_and_counts(fake_result, small_params):
    r = fake_result
    s, c = small_params.num_steps, 4
    assert r.positions.shape == (s, c, 7) and r.proposals.shape == (s, c, 7)
    assert r.outcomes.shape == (s, c) and r.counts.shape == (c, 4)
    # every proposal is counted exactly once, burn-in included
    np.testing.assert_array_equal(r.counts.sum(axis=1), s)
    for k in range(4):
        np.testing.assert_array_equal(r.counts[:, k], (r.outcomes == k).sum(axis=0))
    g = r.grasps
    assert g.ndim == 2 and g.shape[1] == 7 and len(g) <= (r.outcomes == 0).sum()
    np.testing.assert_allclose(np.linalg.norm(g[:, 3:], axis=1), 1.0, atol=1e-6)
    assert np.all(g[:, 3] >= 0)
    assert len(np.unique(np.round(g, 6), axis=0)) == len(g)
    assert 0 <= r.acceptance_rate.min() and r.acceptance_rate.max() <= 1
    assert r.jump_rate.shape == (c,) and r.modes.shape[1] == 7
    assert r.sketch_points.shape == (small_params.sketch_size, 7)


def test_save_load_round_trip(tmp_path, fake_result, box):
    fake_result.save(tmp_path / "run")
    back = jg.learn.load(tmp_path / "run", box)
    for name in ("positions", "proposals", "outcomes", "epsilons", "accepted", "is_jump",
                 "initial_positions", "modes", "sketch_points"):
        np.testing.assert_array_equal(getattr(back, name), getattr(fake_result, name))
    np.testing.assert_array_equal(back.demos.poses, fake_result.demos.poses)
    np.testing.assert_array_equal(back.demos.results.outcome, fake_result.demos.results.outcome)
    np.testing.assert_array_equal(back.grasps, fake_result.grasps)
    assert back.params == fake_result.params and back.seed == 3
    assert (back.method, back.sketch, back.workflow) == ("kameleon_darting", "random", "active")
    meta = json.loads((tmp_path / "run" / "result.json").read_text())
    assert meta["object"]["name"] == box.name and meta["params"]["iterations"] == 40
    assert meta["counts"]["success"] == fake_result.counts[:, 0].tolist()
    assert {"jax", "numpy", "jaxgrasp"} <= set(meta["versions"])
    # nothing but the two files (no temporaries left behind)
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["result.json", "result.npz"]
    with np.load(tmp_path / "run" / "result.npz", allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)


def test_load_wrong_object(tmp_path, fake_result):
    fake_result.save(tmp_path)
    other = jg.objects.make_box(name="other_box")
    with pytest.raises(ValueError, match="other_box"):
        jg.learn.load(tmp_path, other)


def test_load_mismatched_dims(tmp_path, fake_result):
    fake_result.save(tmp_path)
    arrays, meta = R.read_npz_json(tmp_path, "result")
    arrays["positions"] = arrays["positions"][:, :, :6]
    R.write_npz_json(tmp_path, "result", arrays, meta)
    with pytest.raises(ValueError, match="positions.*shape"):
        jg.learn.load(tmp_path)


def test_load_torn_or_missing(tmp_path, fake_result):
    with pytest.raises(ValueError, match="no chain file"):
        jg.learn.load(tmp_path / "nothing")
    fake_result.save(tmp_path)
    arrays, _ = R.read_npz_json(tmp_path, "result")
    arrays["outcomes"] = arrays["outcomes"] * 0
    (tmp_path / "result.npz").write_bytes(R.npz_bytes(arrays))  # npz without its JSON
    with pytest.raises(ValueError, match="checksum"):
        jg.learn.load(tmp_path)


def test_atomic_write_keeps_old_file_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "f.bin"
    R.atomic_write_bytes(path, b"old")

    def boom(*_):
        raise OSError("disk full")

    monkeypatch.setattr(R.os, "replace", boom)
    with pytest.raises(OSError):
        R.atomic_write_bytes(path, b"new")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["f.bin"]


def test_object_arrays_refused():
    with pytest.raises(ValueError, match="object"):
        R.npz_bytes({"x": np.array([{"a": 1}], dtype=object)})


def test_result_validates_shapes(fake_result):
    import dataclasses

    with pytest.raises(ValueError, match="proposals"):
        dataclasses.replace(fake_result, proposals=fake_result.proposals[:, :2])


def test_unique_grasps_canonical():
    g = np.array([[0, 0, 0, 1, 0, 0, 0], [0, 0, 0, -1, 0, 0, 0], [0, 0, 0, 2, 0, 0, 0],
                  [0.01, 0, 0, 0, 1, 0, 0]], float)
    u = jg.learn.unique_grasps(g)
    np.testing.assert_allclose(u, [[0, 0, 0, 1, 0, 0, 0], [0.01, 0, 0, 0, 1, 0, 0]])


def test_bad_arguments(box, fake_sim, small_params):
    kw = dict(chains=4, params=small_params, trial=fake_sim, progress=False)
    with pytest.raises(ValueError, match="method"):
        jg.learn.active(box, method="hmc", **kw)
    with pytest.raises(ValueError, match="sketch"):
        jg.learn.active(box, sketch="clever", **kw)
    with pytest.raises(ValueError, match="chains"):
        jg.learn.active(box, **{**kw, "chains": 0})
    with pytest.raises(ValueError, match="seed"):
        jg.learn.active(box, seed=-1, **kw)
    with pytest.raises(ValueError, match="checkpoint_every"):
        jg.learn.active(box, checkpoint_every=0, **kw)
