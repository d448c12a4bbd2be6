"""Batch-shape buckets: a session running 1...1024 grasps per call compiles the trial a
bounded number of times, and the padded rows change no result of the real ones."""

import _thread
import logging
import threading

import jax
import mujoco
import numpy as np
import pytest
from mujoco import rollout as mj_rollout

import jaxgrasp as jg
from jaxgrasp.learn.sim import Simulator
from jaxgrasp.physics import Outcome, load_scene, make_trial, mujoco_backend, rules
from jaxgrasp.physics.contacts import contact_consts
from jaxgrasp.physics.inputs import PAD_GRASP, bucket_size, pad_grasps
from jaxgrasp.physics.mujoco_backend import piece_sizes
from jaxgrasp.physics.protocol import result_shapes

DOWN = [0.0, 1.0, 0.0, 0.0]  # top-down approach, pads close along the box's y
SIDE_Q = [0.7071, 0.0, 0.7071, 0.0]
GRASPS = np.array(
    [
        [0.0, 0.0, 0.085, *DOWN],  # success
        [0.0, 0.0, 0.05, *DOWN],  # palm inside the box: collision
        [-0.012, 0.0, 0.05, *SIDE_Q],  # side grasp: success
        [0.15, 0.0, 0.05, *DOWN],  # beside: miss
        [0.008, 0.01, 0.09, *DOWN],
        [0.0, 0.0, 0.13, *DOWN],
        [0.1, 0.0, 0.01, 1.0, 0.0, 0.0, 0.0],
        [0.0, 0.004, 0.08, *DOWN],
        [-0.01, 0.0, 0.048, *SIDE_Q],
    ],
    np.float32,
)


@pytest.fixture(scope="module")
def box_scene():
    return load_scene(jg.objects.make_box(np.array([0.03, 0.03, 0.05]), 0.2))


def test_bucket_size_and_padding():
    assert [bucket_size(n) for n in (0, 1, 7, 8, 9, 16, 17, 1000, 1024)] == [
        8, 8, 8, 8, 16, 16, 32, 1024, 1024]
    assert bucket_size(3, 1) == 4 and bucket_size(1, 1) == 1
    assert len({bucket_size(n) for n in range(1, 1025)}) == 8
    with pytest.raises(ValueError, match="min_bucket"):
        bucket_size(3, 0)
    g = pad_grasps(GRASPS[:3], 8)
    assert g.shape == (8, 7) and g.dtype == np.float32
    np.testing.assert_array_equal(g[:3], GRASPS[:3])
    np.testing.assert_array_equal(g[3:], np.broadcast_to(PAD_GRASP, (5, 7)))


def test_c_trial_buckets_compiles_and_keeps_results(box_scene):
    """B = 1..9 compile twice (buckets 8 and 16); B = 3 equals the first rows of B = 4 and of
    B = 9 (another compiled shape, other padding); padded rows collide."""
    trial = make_trial(box_scene, backend="mujoco")
    res = {b: jax.device_get(trial(GRASPS[:b])) for b in range(1, 10)}
    assert trial.jitted._cache_size() <= 2
    assert all(r.outcome.shape == (b,) for b, r in res.items())
    # Traced (outer jit/vmap): the caller's compilation owns the shape, nothing is padded.
    assert jax.eval_shape(trial, jax.ShapeDtypeStruct((3, 7), np.float32)).outcome.shape == (3,)
    assert set(res[9].outcome.tolist()) >= {Outcome.SUCCESS, Outcome.COLLISION, Outcome.MISS}
    for other in (res[4], res[9]):
        np.testing.assert_array_equal(res[3].outcome, other.outcome[:3])
        np.testing.assert_allclose(res[3].epsilon, other.epsilon[:3], rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(res[3].displacement, other.displacement[:3], atol=1e-6)
    pad = jax.device_get(trial(pad_grasps(GRASPS[:1], 2)))
    assert pad.outcome[1] == Outcome.COLLISION and pad.epsilon[1] == 0.0


@pytest.mark.slow  # large host calls; the buckets' rows are kept in the test above
def test_c_trial_pipeline_pieces_keep_rows(box_scene, monkeypatch):
    """A large host call runs in engine pieces, each finished in parts on worker threads
    (overlapping the next piece): with pieces of 8 (the smallest bucket, to keep shapes
    small), 16 grasps in 2 pieces give, row for row, the outcomes of the same grasps simulated
    and finished in one piece, and the same epsilon up to float32 batch effects."""
    assert [piece_sizes(n, 2) for n in (5, 9, 16, 64, 256, 1000)] == [
        (5, 5), (16, 8), (16, 8), (64, 32), (256, 128), (512, 256)]
    monkeypatch.setattr(mujoco_backend, "MIN_PIECE", 8)
    assert piece_sizes(16, 2) == (8, 8)
    trial = make_trial(box_scene, backend="mujoco")
    g = np.concatenate([GRASPS, GRASPS[:7]])  # 16 rows: 2 pieces
    calls = trial.engine.num_calls
    res = jax.device_get(trial(g))
    assert trial.engine.num_calls == calls + 2
    whole = jax.device_get(trial.tail(contact_consts(box_scene), trial.engine(g)))
    np.testing.assert_array_equal(res.outcome, whole.outcome)
    np.testing.assert_array_equal(res.contact_mask, whole.contact_mask)
    np.testing.assert_allclose(res.epsilon, whole.epsilon, rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(res.outcome[9:], res.outcome[:7])  # same grasps, pieces
    assert set(res.outcome.tolist()) >= {Outcome.SUCCESS, Outcome.COLLISION, Outcome.MISS}
    assert trial(GRASPS[:0]).outcome.shape == (0,)  # no grasps: an empty result, no error


def test_c_trial_skips_epsilon_where_a_finger_closed(box_scene, monkeypatch):
    """The engine flags, right after the rollout, the trials with a finger at its closed
    limit (float64, as the miss rule decides them): each is a MISS, so the early stage
    computes no epsilon for them. The companion shows the flag is what decides: flagging
    every trial leaves no epsilon at all."""
    trial = make_trial(box_scene, backend="mujoco")
    rolled = trial.engine.start(GRASPS)
    raw = trial.engine.finish(rolled)
    assert rolled["closed"].any() and np.all(raw["miss"][rolled["closed"]])
    assert np.any(jax.device_get(trial(GRASPS)).epsilon > 0)
    start = trial.engine._start

    def all_closed(g):
        out = start(g)
        return {**out, "closed": np.ones_like(out["closed"])}

    monkeypatch.setattr(trial.engine, "_start", all_closed)
    assert np.all(jax.device_get(trial(GRASPS)).epsilon == 0)


def test_c_trial_parts_per_calling_thread(box_scene, monkeypatch):
    """The host pipeline finishes a piece in parallel parts when a Python thread calls it
    (jg.learn.Simulator, a user), and in one part per piece when XLA's callback thread does
    (a sampler's host callback: there parallel parts contend, docs/design.md); same rows
    either way."""
    monkeypatch.setattr(mujoco_backend, "MIN_PIECE", 8)
    trial = make_trial(box_scene, backend="mujoco")
    seen = []
    early = mujoco_backend._Pipeline._early

    def record(self, raw, *signal):
        seen.append(len(raw["collision"]))
        return early(self, raw, *signal)

    monkeypatch.setattr(mujoco_backend._Pipeline, "_early", record)
    g = np.concatenate([GRASPS, GRASPS, GRASPS[:6]])  # 24 rows: 2 pieces of 16 when padded
    assert piece_sizes(32, 2) == (16, 8)
    host = trial.host(pad_grasps(g, 32))
    assert sorted(seen) == [8, 8, 8, 8]
    seen.clear()
    # A thread Python's threading did not start (as XLA's) is a threading._DummyThread.
    out, done = {}, threading.Event()

    def foreign():
        out["res"] = trial.host(pad_grasps(g, 32))
        done.set()

    _thread.start_new_thread(foreign, ())
    assert done.wait(120)
    assert sorted(seen) == [16, 16]
    np.testing.assert_array_equal(out["res"].outcome, host.outcome)
    np.testing.assert_allclose(out["res"].epsilon, host.epsilon, rtol=1e-4, atol=1e-6)
    assert set(host.outcome[:24].tolist()) >= {Outcome.SUCCESS, Outcome.MISS}


def test_simulator_buckets(box_scene):
    """The Simulator (the learning path) pads each call to its bucket with PAD_GRASP rows and
    returns only the real rows (a host-level stand-in trial records the sizes it sees)."""
    sizes = []

    def host_trial(g):
        g = np.asarray(g)
        sizes.append(len(g))
        return {"x": g[:, 0].copy(), "pad": (g == np.asarray(PAD_GRASP, np.float32)).all(1)}

    sim = Simulator(box_scene, trial=host_trial)
    assert not sim.traceable
    for b in range(1, 10):
        out = sim(GRASPS[:b])
        np.testing.assert_array_equal(out["x"], GRASPS[:b, 0])
        assert not out["pad"].any()
    assert set(sizes) == {8, 16} and sim.num_trials == 45
    assert [sim.call_size(n) for n in (1, 8, 9, 2000)] == [8, 8, 16, 1024]
    sizes.clear()
    assert len(sim(np.tile(GRASPS, (300, 1)))["x"]) == 2700 and sizes == [1024] * 3
    assert Simulator(box_scene, trial=host_trial, batch_size=5).call_size(3) == 8
    assert Simulator(box_scene, trial=host_trial, min_bucket=None).call_size(3) == 3


def test_c_trial_result_shapes_are_its_tails(box_scene):
    """The C trial declares its callback's result shapes without tracing its tail (seconds on
    each new object): they are the tail's on a real raw trial."""
    trial = make_trial(box_scene, backend="mujoco")
    for b in (1, 9):
        raw = trial.engine(GRASPS[:b])
        want = jax.eval_shape(trial.tail, contact_consts(box_scene), raw)
        got = result_shapes(b, box_scene.params.num_contacts)
        assert jax.tree.structure(got) == jax.tree.structure(want)
        for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            assert (g.shape, g.dtype) == (w.shape, w.dtype)


def test_outcomes_alone_are_the_whole_trials(box_scene, monkeypatch):
    """``Simulator.outcomes`` on MuJoCo C (the host's decisions, no contacts or epsilon)
    gives the whole trial's outcome codes, every kind of outcome and a row that is not a pose
    included, runs no JAX tail, and counts its trials; a trial without ``outcomes`` falls
    back to the whole trial."""
    sim = Simulator(box_scene, backend="mujoco", batch_size=8)
    g = np.concatenate([GRASPS, GRASPS + np.float32(0.003)])
    g[4, 3:] = 0.0  # a zero quaternion: no pose, a COLLISION
    whole = np.asarray(sim(g).outcome)
    assert set(whole.tolist()) >= {Outcome.SUCCESS, Outcome.COLLISION, Outcome.MISS}
    assert whole[4] == Outcome.COLLISION

    def no_tail(*a, **k):
        raise AssertionError("the JAX tail ran")

    monkeypatch.setattr(sim.trial.host, "early", no_tail)
    before = sim.num_trials
    np.testing.assert_array_equal(sim.outcomes(g), whole)
    assert sim.num_trials == before + len(g)
    monkeypatch.undo()
    sim.max_bucket = 5  # several calls
    np.testing.assert_array_equal(sim.outcomes(g), whole)
    fallback = Simulator(box_scene, trial=lambda x: sim.trial(x))
    np.testing.assert_array_equal(fallback.outcomes(g), whole)


def test_unstable_rollouts_log_instead_of_printing(box_scene, tmp_path, monkeypatch, caplog,
                                                  capfd):
    """MuJoCo's default warning handler prints an unstable rollout's warning and appends it
    to MUJOCO_LOG.TXT in the working directory; once an engine exists its warnings (from the
    rollout threads too) go to the logger instead, and a handler the process set is kept."""
    monkeypatch.chdir(tmp_path)
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom size=".1"/></body></worldbody></mujoco>')
    datas = [mujoco.MjData(m) for _ in range(2)]
    state = np.zeros((4, mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)))
    state[:, 8:14] = 1e300  # velocities MuJoCo calls unstable
    before = mujoco.get_mju_user_warning()
    try:
        mujoco.set_mju_user_warning(None)  # MuJoCo's default
        mj_rollout.rollout(m, datas, state, nstep=2)
        assert (tmp_path / "MUJOCO_LOG.TXT").exists()
        (tmp_path / "MUJOCO_LOG.TXT").unlink()
        capfd.readouterr()
        mujoco_backend.MujocoEngine(box_scene, nthread=2)
        with caplog.at_level(logging.DEBUG, logger=mujoco_backend.__name__):
            mj_rollout.rollout(m, datas, state, nstep=2)
        assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
        assert "WARNING" not in capfd.readouterr().out
        assert sum("unstable" in r.getMessage() for r in caplog.records) == 4
        mine = lambda msg: None  # noqa: E731
        mujoco.set_mju_user_warning(mine)
        mujoco_backend.MujocoEngine(box_scene, nthread=1)
        assert mujoco.get_mju_user_warning() is mine
    finally:
        mujoco.set_mju_user_warning(before)


def test_c_trial_early_failure_raises_not_hangs(box_scene, monkeypatch):
    """An error in the early stage on a worker reaches the caller (which waits for the
    workers to dispatch: it must not wait forever)."""
    trial = make_trial(box_scene, backend="mujoco")

    def broken(self, raw, *signal):
        raise RuntimeError("early stage failed")

    monkeypatch.setattr(mujoco_backend._Pipeline, "_early", broken)
    with pytest.raises(RuntimeError, match="early stage failed"):
        trial.host(GRASPS)


def test_contact_options_keep_the_geometry(box_scene):
    """The C trial compiles its contacts with other XLA options (no YNNPACK fusions, where
    this jaxlib has the option): the same contact set, the points equal up to float32
    round-off of other summation orders (here 1 µm)."""
    from jaxgrasp.physics import rules

    options = mujoco_backend.contact_options()
    if options is None:
        pytest.skip("this jaxlib has no YNN fusion option: the C trial uses XLA's defaults")
    assert options == mujoco_backend._CONTACT_OPTIONS
    trial = make_trial(box_scene, backend="mujoco")
    raw = {k: jax.numpy.asarray(v) for k, v in trial.engine(GRASPS).items()}
    cc = contact_consts(box_scene)

    def contacts(raw):
        return rules.batch_contacts(raw, cc, box_scene.params, box_scene.ids, renormalize=True)

    plain = jax.device_get(jax.jit(contacts)(raw))
    tuned = jax.device_get(jax.jit(contacts, compiler_options=options)(raw))
    np.testing.assert_array_equal(tuned[2], plain[2])
    assert plain[2].any()
    for a, b in zip(tuned[:2], plain[:2], strict=True):
        np.testing.assert_allclose(np.where(plain[2][..., None], a, 0),
                                   np.where(plain[2][..., None], b, 0), atol=1e-6)


def test_contact_options_fall_back_to_defaults(monkeypatch):
    """A jaxlib without the option gets XLA's defaults (None), not an error."""
    monkeypatch.setattr(mujoco_backend, "_CONTACT_OPTIONS", {"xla_no_such_option": True})
    mujoco_backend.contact_options.cache_clear()
    try:
        assert mujoco_backend.contact_options() is None
    finally:
        mujoco_backend.contact_options.cache_clear()


def test_trial_compiles_its_contacts_with_the_options(box_scene, monkeypatch):
    """make_mujoco_trial hands contact_options() to its contacts' compilation: an option XLA
    does not know fails the trial's first call."""
    monkeypatch.setattr(mujoco_backend, "contact_options", lambda: {"xla_no_such_option": True})
    # the shared stage uncached: one built before this test has the real options
    monkeypatch.setattr(mujoco_backend, "shared_contacts",
                        mujoco_backend.shared_contacts.__wrapped__)
    trial = mujoco_backend.make_mujoco_trial(box_scene)
    with pytest.raises(Exception, match="xla_no_such_option"):
        trial.host(GRASPS)


@pytest.mark.slow  # compiles the trial under an outer jit (~20 s)
def test_c_trial_concrete_call_equals_traced_call(box_scene):
    """Concrete grasps are padded to their bucket, traced ones (under an outer jit) are not:
    the same fields and dtypes; the host's decisions equal, the JAX stages' floats (compiled
    for other batch shapes) equal up to round-off."""
    trial = make_trial(box_scene, backend="mujoco")
    direct = trial(GRASPS[:5])
    assert isinstance(direct.outcome, jax.Array)
    traced = jax.device_get(jax.jit(trial)(GRASPS[:5]))
    direct = jax.device_get(direct)
    for f, a in direct._asdict().items():
        b = getattr(traced, f)
        assert a.dtype == b.dtype and a.shape == b.shape, f
    for f in ("outcome", "unstable", "pad_contact", "displacement", "contact_mask"):
        np.testing.assert_array_equal(getattr(direct, f), getattr(traced, f), err_msg=f)
    assert set(direct.outcome.tolist()) >= {Outcome.SUCCESS, Outcome.COLLISION, Outcome.MISS}
    np.testing.assert_allclose(direct.epsilon, traced.epsilon, rtol=1e-4, atol=1e-6)
    for f in ("contact_points", "contact_normals"):
        np.testing.assert_allclose(getattr(direct, f), getattr(traced, f), atol=1e-5, err_msg=f)


def test_c_engine_flags_unsound_rollouts(box_scene, monkeypatch):
    """The engine's stability check (a fast path when every state is sound) flags exactly the
    trials :func:`rules.stable` fails: a NaN position, a speed over ``max_speed``; a sound
    rollout flags none."""
    engine = make_trial(box_scene, backend="mujoco").engine
    g = GRASPS[[0, 2, 4, 7]]  # none collides
    states = engine.rollout(engine.place(g)[0])
    nq, nv = engine.nq, engine.nv
    assert not engine.start(g)["raw"]["bad"].any()
    bad_states = states.copy()
    bad_states[0, 40, 1] = np.nan  # a position of trial 0
    bad_states[2, 70, 1 + nq + 3] = 2 * box_scene.params.max_speed  # a speed of trial 2
    monkeypatch.setattr(engine, "rollout", lambda q: bad_states.copy())
    bad = engine.start(g)["raw"]["bad"]
    with np.errstate(invalid="ignore"):
        want = ~rules.stable(bad_states[:, :, 1:1 + nq], bad_states[:, :, 1 + nq:1 + nq + nv],
                             box_scene.params, np).all(axis=1)
    np.testing.assert_array_equal(bad, want)
    np.testing.assert_array_equal(bad, [True, False, True, False])
