"""Epsilon's contacts (physics/contacts.py): examining only the pieces that reach a pad's
patch gives the contacts of all pieces, on states of the 16-piece pitcher from MuJoCo C."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp import quality as Q
from jaxgrasp.physics import contacts as C
from jaxgrasp.physics import load_scene, make_trial, mujoco_backend, rules
from jaxgrasp.physics.contacts import CONTACT_PIECES, contact_consts, geom_poses, patch_reach
from jaxgrasp.physics.protocol import epsilon_fn, with_epsilon


@pytest.fixture(scope="module")
def pitcher(load_benchmark):
    obj = jg.objects.load("pitcher")
    scene = load_scene(obj)
    trial = make_trial(scene, backend="mujoco")
    g = load_benchmark("backend_agreement").agreement_poses(obj, 48, 0,
                                                            placement=trial.engine.place)
    return scene, trial, g, trial.engine(g)


def _contacts(scene, raw, max_pieces):
    cc = contact_consts(scene)
    one = lambda pre, snap: rules._contacts({"pre_q": pre, "snap_q": snap}, cc,  # noqa: E731
                                            scene.params, scene.ids, True, max_pieces)
    return jax.device_get(jax.jit(jax.vmap(one))(raw["pre_q"], raw["snap_q"]))


def _rows(raw):
    return ~(raw["collision"] | raw["bad"])


def test_culled_contacts_match_all_pieces(pitcher):
    scene, _, _, raw = pitcher
    rows = _rows(raw)
    full = _contacts(scene, raw, None)
    *culled, over = _contacts(scene, raw, CONTACT_PIECES)
    keep = rows & ~over
    assert rows.sum() >= 30 and keep.sum() >= rows.sum() - 2  # overflow is rare here
    assert full[2][keep].sum() >= 4 * keep.sum()  # real contacts on most states: teeth
    np.testing.assert_array_equal(culled[2][keep], full[2][keep])
    m = full[2][keep][..., None]
    np.testing.assert_allclose(np.where(m, culled[0][keep], 0), np.where(m, full[0][keep], 0),
                               atol=1e-6)


def test_too_few_pieces_is_flagged_and_would_be_wrong(pitcher):
    """The companion: one piece per pad misses corners on the states where two reach, and
    says so (``overflow``); the batched path recomputes those states with all pieces."""
    scene, _, _, raw = pitcher
    rows = _rows(raw)
    full = _contacts(scene, raw, None)
    *one, over = _contacts(scene, raw, 1)
    over = over & rows
    assert over.sum() >= 5
    moved = np.abs(one[0] - full[0]).max(-1) > 1e-4
    lost = (one[2] != full[2]).any(-1) | (moved & full[2]).any(-1)
    assert lost[over].sum() >= 3 and not lost[rows & ~over].any()


def _reach(scene, raw):
    cc = contact_consts(scene)
    one = lambda q: patch_reach(cc, geom_poses(cc, q), scene.params, scene.ids).any()  # noqa: E731
    return np.asarray(jax.jit(jax.vmap(one))(raw["pre_q"]))


def test_states_where_no_piece_reaches_have_no_contacts(pitcher):
    """``batch_contacts`` skips the states where no piece reaches a pad's patch (a finger
    closed past the object): all pieces give them no contact either."""
    scene, _, _, raw = pitcher
    rows, reach = _rows(raw), _reach(scene, raw)
    has = _contacts(scene, raw, None)[2].any(-1)
    assert (rows & ~reach).sum() >= 5 and has[rows & reach].sum() >= 10
    assert not has[rows & ~reach].any()


def test_a_too_strict_reach_test_would_lose_contacts(pitcher, monkeypatch):
    """The companion: a reach test 5 mm too strict calls states with contacts unreached (2 mm
    too strict still finds them all here)."""
    scene, _, _, raw = pitcher
    monkeypatch.setattr(C, "_REACH_SLACK", -5e-3)
    rows, reach = _rows(raw), _reach(scene, raw)
    has = _contacts(scene, raw, None)[2].any(-1)
    assert has[rows & ~reach].sum() >= 3


def test_batch_contacts_fall_back_to_all_pieces(pitcher, monkeypatch):
    scene, _, _, raw = pitcher
    rows = _rows(raw)
    full = _contacts(scene, raw, None)
    monkeypatch.setattr(rules, "CONTACT_PIECES", 1)
    cc = contact_consts(scene)
    got = jax.device_get(jax.jit(lambda r: rules.batch_contacts(
        r, cc, scene.params, scene.ids, renormalize=True))(raw))
    np.testing.assert_array_equal(got[2][rows], full[2][rows])
    m = full[2][rows][..., None]
    np.testing.assert_allclose(np.where(m, got[0][rows], 0), np.where(m, full[0][rows], 0),
                               atol=1e-6)
    assert not got[2][~rows].any()


def test_c_trial_equals_its_definition(pitcher):
    """The C trial computes epsilon early (from the states, for every trial with contacts on
    both pads, while the host runs the pad checks): the same results as contacts and outcome
    first, then epsilon of the graspable trials (``with_epsilon``)."""
    scene, trial, g, raw = pitcher
    res = jax.device_get(trial.host(g))
    eps = epsilon_fn(jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
                     jnp.float32(scene.obj.max_radius), scene.params.num_contacts)
    cc = contact_consts(scene)
    ref = jax.device_get(jax.jit(lambda r: with_epsilon(rules.trial_results(
        r, cc, scene.params, scene.ids, renormalize=True), eps))(raw))
    np.testing.assert_array_equal(res.outcome, ref.outcome)
    np.testing.assert_array_equal(res.contact_mask, ref.contact_mask)
    assert (ref.epsilon > 0).sum() >= 10
    np.testing.assert_allclose(res.epsilon, ref.epsilon, rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_trial_epsilon_on_many_real_contact_sets(load_benchmark):
    """The trial's epsilon (``epsilon_fn(...).batch``, jitted, all sets in one call) against
    Qhull on the contacts of 1024 non-colliding pitcher poses from MuJoCo C: never 0 where the
    origin is well inside (a basis that float32 made singular was read as "outside" and gave
    0 on 3 of 3 329 such sets on 9 objects, one of them here: docs/design.md, "Epsilon of the
    grasp wrench space"),
    never more than 1 % below Qhull, and within 1 % on all but a few (a multi-start search can
    over-estimate: 2 of those 3 329)."""
    obj = jg.objects.load("pitcher")
    scene = load_scene(obj)
    engine = make_trial(scene, backend="mujoco").engine
    g = load_benchmark("backend_agreement").agreement_poses(
        obj, 1024, 1, collision_fraction=0.0, placement=engine.place)
    raw = engine.start(g)["raw"]
    cc = contact_consts(scene)
    pts, nrm, msk = jax.device_get(jax.jit(lambda r: rules.batch_contacts(
        r, cc, scene.params, scene.ids, renormalize=True))(
        {k: raw[k] for k in ("collision", "bad", "pre_q", "snap_q")}))
    rows = np.flatnonzero(~(raw["collision"] | raw["bad"]) & np.asarray(rules.two_sided(msk)))
    assert rows.size >= 400
    pts, nrm, msk = pts[rows], nrm[rows], msk[rows]
    eps_fn = epsilon_fn(jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
                        jnp.float32(scene.obj.max_radius), scene.params.num_contacts)
    eps = np.asarray(jax.jit(eps_fn.batch)(pts, nrm, msk, np.ones(rows.size, bool)))
    ref = np.array([Q.epsilon_qhull(p, n, m, scene.friction, scene.obj.com,
                                    scene.obj.max_radius)
                    for p, n, m in zip(pts, nrm, msk, strict=True)])
    assert (ref > 1e-3).sum() >= 300
    assert not np.any((eps == 0) & (ref > 1e-3)), np.flatnonzero((eps == 0) & (ref > 1e-3))
    assert np.all(eps >= ref * 0.99 - 1e-4)  # an upper bound wherever it is off
    assert (np.abs(eps - ref) > np.maximum(1e-4, 0.01 * ref)).sum() <= 3


def test_argmax_and_reaching_first_equal_their_numpy_definitions():
    """``_argmax`` is ``argmax`` (ties: the first; a NaN: the first NaN) and
    ``_reaching_first`` is ``argsort(~reach, stable=True)[:k]``, on random patterns."""
    rng = np.random.default_rng(0)
    argmax = jax.jit(C._argmax)
    for _ in range(50):
        x = rng.integers(0, 4, 12).astype(np.float32)  # many ties
        if rng.random() < 0.3:
            x[rng.integers(0, 12, 2)] = np.nan
        assert int(argmax(jnp.asarray(x))) == int(np.argmax(x))
    for P in (5, 16, 40):
        for k in (1, 4):
            first = jax.jit(lambda r, k=k: C._reaching_first(r, k))
            for _ in range(30):
                reach = rng.random(P) < rng.random()
                np.testing.assert_array_equal(np.asarray(first(jnp.asarray(reach))),
                                              np.argsort(~reach, kind="stable")[:k])


def _shared_and_own(scene, raw, unturned=False):
    """The contacts of ``raw`` by the C trial's shared contact stage, and by the scene's own
    kinematics and hulls; with the stage's compiled-program count after the call.
    ``unturned``: the pieces' orientations in the object body dropped (a wrong placement)."""
    stage, base, _ = mujoco_backend.shared_contacts(scene.gripper, scene.params)
    early = {k: jnp.asarray(raw[k]) for k in ("collision", "bad", "pre_q", "snap_q")}
    early["closed"] = jnp.asarray(raw["miss"])
    cc = C.shared_consts(base, scene)
    if unturned:
        pos, quat = cc.pieces
        cc = cc._replace(pieces=(pos, jnp.zeros_like(quat).at[:, 0].set(1.0)))
    got = jax.device_get(stage(mujoco_backend.object_args(cc), early)[:3])
    cc = contact_consts(scene)
    own = jax.device_get(jax.jit(lambda r: rules.batch_contacts(
        r, cc, scene.params, scene.ids, renormalize=True))(early))
    return got, own, stage._cache_size()


def _same_contacts(got, own):
    np.testing.assert_array_equal(got[2], own[2])
    m = own[2][..., None]
    np.testing.assert_allclose(np.where(m, got[0], 0), np.where(m, own[0], 0), atol=1e-6)
    np.testing.assert_allclose(np.where(m, got[1], 0), np.where(m, own[1], 0), atol=1e-6)


@pytest.mark.slow  # compiles three objects' own contacts (~27 s); the pitcher's own against
# the shared stage stays in make test (test_c_trial_equals_its_definition)
def test_objects_share_one_contact_stage(pitcher, load_benchmark):
    """The C trial's contacts take the object's hulls and piece poses as arguments of padded
    sizes (the stand-in scene's kinematics place the pieces): the plate (14 pieces padded to
    16, two of them far away) and a box (1 piece padded to 4) get the contacts of their own
    scene's kinematics and hulls; the plate reuses the program compiled for the pitcher (16
    pieces, the same padded sizes), the box compiles its own. The companion: the pieces
    placed without their orientation in the object body get other contacts."""
    assert [C.padded_size(n) for n in (1, 4, 5, 7, 9, 14, 16, 17, 25, 33)] == [
        4, 4, 6, 8, 12, 16, 16, 24, 32, 48]
    scene, _, _, raw = pitcher
    got, own, count = _shared_and_own(scene, raw)
    _same_contacts(got, own)
    plate = load_scene(jg.objects.load("plate"))
    assert len(plate.ids.layout.piece_geoms) == 14
    engine = make_trial(plate, backend="mujoco").engine
    g = load_benchmark("backend_agreement").agreement_poses(
        plate.obj, 48, 1, collision_fraction=0.0, placement=engine.place)
    g = np.repeat(g[~engine(g)["miss"]], 8, axis=0)[:48]  # few random poses touch a plate:
    g[:, :3] += np.random.default_rng(0).normal(0.0, 1e-3, (len(g), 3))  # near those that do
    plate_raw = engine(g)
    got, own, plate_count = _shared_and_own(plate, plate_raw)
    assert own[2].any(axis=1).sum() >= 10
    _same_contacts(got, own)
    assert plate_count == count  # the pitcher's program
    box = load_scene(jg.objects.make_box(np.array([0.03, 0.03, 0.05]), 0.2))
    box_g = np.array([[0.0, 0.0, 0.085, 0.0, 1.0, 0.0, 0.0]] * 48, np.float32)
    box_g[:, 0] = np.linspace(-0.03, 0.03, 48)
    got, own, box_count = _shared_and_own(box, make_trial(box, backend="mujoco").engine(box_g))
    assert own[2].any(axis=1).sum() >= 10
    _same_contacts(got, own)
    assert box_count == count + 1
    got, own, _ = _shared_and_own(scene, raw, unturned=True)
    moved = (np.abs(got[0] - own[0]).max(-1) > 1e-4) & own[2]
    assert ((got[2] != own[2]) | moved).any(axis=1).sum() >= 5
