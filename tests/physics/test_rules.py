"""The protocol's decisions (physics/rules.py) are one code for both backends.

The rules run in numpy (MuJoCo C host side, batched float64) and in jax.numpy (MJX, per trial,
vmapped float32) with the same results, and a rule changed in one place changes the outcomes
of both backends.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp import so3
from jaxgrasp.physics import Outcome, TrialParams, load_scene, make_trial, rules
from jaxgrasp.physics import trial as T
from jaxgrasp.physics.mujoco_backend import MujocoEngine

HALF = (0.03, 0.03, 0.05)
DOWN = [0.0, 1.0, 0.0, 0.0]
SIDE_Q = [0.7071, 0.0, 0.7071, 0.0]
MIXED = np.array(  # tests/physics/test_trial.py's mixed batch: success, collision and miss
    [
        [0.0, 0.0, 0.085, *DOWN],
        [0.008, 0.01, 0.09, *DOWN],
        [0.0, 0.0, 0.05, *DOWN],
        [0.15, 0.0, 0.05, *DOWN],
        [0.0, 0.0, 0.13, *DOWN],
        [0.1, 0.0, 0.01, 1.0, 0.0, 0.0, 0.0],
        [-0.012, 0.0, 0.05, *SIDE_Q],
        [0.0, 0.0, 0.085, *DOWN],
    ],
    np.float32,
)
EXPECTED = np.array([0, 0, 2, 3, 3, 2, 0, 0])


def _both(fn_np, fn_jax, *args):
    """``fn`` batched in numpy (float64) and vmapped in jax (float32) on the same inputs."""
    a = fn_np(*[np.asarray(x, np.float64) if np.asarray(x).dtype.kind == "f" else np.asarray(x)
                for x in args])
    b = jax.vmap(fn_jax)(*[jnp.asarray(x, jnp.float32) if np.asarray(x).dtype.kind == "f"
                           else jnp.asarray(x) for x in args])
    return jax.tree.map(np.asarray, a), jax.tree.map(np.asarray, b)


def test_rules_agree_in_numpy_and_jax():
    rng = np.random.default_rng(0)
    p = TrialParams()
    n = 64
    g = np.concatenate([rng.uniform(-0.1, 0.1, (n, 3)), rng.normal(size=(n, 4))], 1)
    g[0, 3:] = 0.0  # zero quaternion: identity
    g[1, 2] = np.nan  # non-finite: the safe grasp, flagged
    g[2, 3:] *= 1e3

    corners = rng.uniform(-0.08, 0.08, (24, 3))

    def place(xp):
        def f(g):
            finite, g = rules.finite_grasps(g, xp)
            g = rules.normalize_grasps(g, xp)
            pos, quat, rot = rules.object_pose_from_grasp(g, xp)
            below = rules.below_support(g, xp.asarray(corners, g.dtype), 0.0, xp)
            return finite, g, pos, quat, rot, below
        return f

    a, b = _both(place(np), place(jnp), g)
    np.testing.assert_array_equal(a[0], b[0])
    assert not a[0][1] and a[0][[0, 2]].all()
    for x, y in zip(a[1:5], b[1:5], strict=True):
        np.testing.assert_allclose(x, y, atol=2e-6)
    np.testing.assert_array_equal(a[1][0, 3:], [1, 0, 0, 0])
    np.testing.assert_array_equal(a[5], b[5])
    assert 0 < a[5].sum() < n  # both sides of the support plane

    qpos, qvel = rng.normal(size=(n, 9)), rng.normal(size=(n, 8)) * 600
    qvel[3, 2] = np.inf
    a, b = _both(lambda q, v: rules.stable(q, v, p, np), lambda q, v: rules.stable(q, v, p), qpos,
                 qvel)
    np.testing.assert_array_equal(a, b)
    assert 0 < a.sum() < n and not a[3]

    q_s, q_t = (so3.normalize(rng.normal(size=(n, 4)), np) for _ in range(2))
    pos_s, pos_t, com = rng.normal(size=(n, 3)) * 0.05, rng.normal(size=(n, 3)) * 0.05, [0, 0, 0.04]

    def disp(xp):
        return lambda ps, qs, pt, qt: rules.displacement(
            ps, so3.unit_to_matrix(qs, xp), pt, so3.unit_to_matrix(qt, xp), xp.asarray(com), xp)

    a, b = _both(disp(np), disp(jnp), pos_s, q_s, pos_t, q_t)
    np.testing.assert_allclose(a, b, rtol=1e-5)

    dist = rng.uniform(-0.002, 0.004, (n, 12))
    geom = rng.integers(0, 5, (n, 12, 2))
    pads = (1, 3)
    a, b = _both(lambda d, g: rules.pad_distances(d, g, pads, np),
                 lambda d, g: rules.pad_distances(d, g, pads), dist, geom)
    np.testing.assert_allclose(a, b, rtol=1e-6)
    assert np.isinf(rules.pad_distances(np.zeros(0), np.zeros((0, 2), int), pads, np)).all()
    touch = rules.touching(a, p)
    fq = rng.uniform(0, 0.004, (n, 2))
    a, b = _both(lambda t, f: rules.missed(t, f, p, np), lambda t, f: rules.missed(t, f, p), touch,
                 fq)
    np.testing.assert_array_equal(a, b)
    assert 0 < a.sum() < n


def test_results_assembled_in_numpy_equal_jax():
    """The C trial assembles its results in numpy on the host: the same arrays, bit for bit,
    as the vmapped JAX assembly (every outcome, NaNs in the contacts)."""
    rng = np.random.default_rng(1)
    n, k = 256, 8
    raw = {key: rng.random(n) < 0.3 for key in ("collision", "miss", "slipped", "bad")}
    raw["max_disp"] = rng.uniform(0, 0.02, n).astype(np.float32)
    raw["max_disp"][:3] = np.nan
    raw["pad_contact"] = rng.random((n, 2)) < 0.7
    pts = rng.normal(size=(n, k, 3)).astype(np.float32)
    pts[5, 2, 1] = np.nan
    nrm = rng.normal(size=(n, k, 3)).astype(np.float32)
    msk = rng.random((n, k)) < 0.5
    eps = rng.uniform(0, 0.1, n).astype(np.float32)
    a = rules.assemble_results(raw, (pts, nrm, msk), eps, np)
    b = jax.device_get(rules.assemble_results(jax.tree.map(jnp.asarray, raw),
                                              (pts, nrm, msk), jnp.asarray(eps)))
    for f in a._fields:
        x, y = getattr(a, f), np.asarray(getattr(b, f))
        assert x.dtype == y.dtype and x.shape == y.shape, f
        np.testing.assert_array_equal(x, y, err_msg=f)
    assert set(np.unique(a.outcome)) == {int(o) for o in Outcome}
    assert np.isfinite(a.contact_points).all() and np.isfinite(a.displacement).all()
    assert (a.epsilon[~rules.graspable(a.outcome)] == 0).all()


# the MJX variant compiles a whole new MJX trial (~2 min on 2 cores): `make test-all`
@pytest.mark.parametrize("backend", ["mujoco", pytest.param("mjx", marks=pytest.mark.slow)])
def test_one_rule_changes_both_backends(backend, monkeypatch):
    """The slip rule replaced in rules.py alone (any motion at all during the hold is a slip):
    both backends' holding grasps become SLIPPED, nothing else changes."""
    strict = lambda max_disp, held, params: (max_disp > 0) | ~held  # noqa: E731
    monkeypatch.setattr(rules, "slipped", strict)
    # A TrialParams no other test uses: the MJX trial is traced anew (jit caches by params).
    scene = load_scene(jg.objects.make_box(HALF, mass=0.2), params=TrialParams(slip_tol=0.0101))
    out = np.asarray(make_trial(scene, backend=backend)(MIXED).outcome)
    want = np.where(EXPECTED == Outcome.SUCCESS, Outcome.SLIPPED, EXPECTED)
    assert out.tolist() == want.tolist()


def test_a_threshold_changes_both_backends():
    """``collision_tol`` is read by the one placement rule both backends call: a palm 1 mm
    inside the box is allowed with the default 2 mm and a collision with 0.5 mm, in both."""
    grasp = np.array([[-0.009, 0.0, 0.05, *SIDE_Q]], np.float32)
    for tol, want in ((0.002, False), (0.0005, True)):
        scene = load_scene(jg.objects.make_box(HALF, mass=0.2),
                           params=TrialParams(collision_tol=tol))
        c = T.scene_consts(scene)
        mjx_collision = T._collide_batch(c, jnp.asarray(grasp), scene.params, scene.ids)
        c_collision = MujocoEngine(scene, nthread=1).place(grasp)[1]
        assert bool(mjx_collision[0]) == bool(c_collision[0]) == want, tol
