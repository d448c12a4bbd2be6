"""Symmetry moves: the z-axis planes turn a grasp like a rigid rotation, and Kameleon + GDMC
with them still samples its target exactly (exact samples in, quantiles out)."""

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp import so3
from jaxgrasp.mcmc import symmetry
from jaxgrasp.types import SamplingAlgorithm

# the module (jaxgrasp.mcmc.kameleon_darting is the function of the same name)
kd = importlib.import_module("jaxgrasp.mcmc.kameleon_darting")


def retraced(alg):
    """The same sampler as a new function object: traced afresh (with a swapped move), not
    taken from a cache."""
    bound = alg.step.func
    step = jax.tree_util.Partial(lambda key, state, **kw: bound(key, state, **kw),
                                 **alg.step.keywords)
    return SamplingAlgorithm(alg.init, step)


@pytest.mark.compile_bound
def test_z_axis_planes_are_a_rigid_turn_about_z():
    key = jax.random.key(0)
    q = so3.random_quaternion(key)
    g = jnp.concatenate([jnp.array([0.05, -0.02, 0.1]), q])
    angle = 0.7
    out = symmetry.rotate(g, symmetry.Z_AXIS_PLANES, angle)
    r = so3.from_axis_angle(jnp.array([0.0, 0.0, 1.0]), angle)
    np.testing.assert_allclose(out[:3], so3.rotate(r, g[:3]), atol=1e-6)
    np.testing.assert_allclose(out[3:], so3.multiply(r, q), atol=1e-6)
    # orthogonal: norms kept, and the opposite angle undoes it
    np.testing.assert_allclose(jnp.linalg.norm(out[3:]), jnp.linalg.norm(q), rtol=1e-6)
    back = symmetry.rotate(out, symmetry.Z_AXIS_PLANES, -angle)
    np.testing.assert_allclose(back, g, atol=1e-6)
    with pytest.raises(ValueError, match="distinct"):
        symmetry.check_planes(((0, 1, 1.0), (1, 2, 1.0)), 7)


# A 3-d target that is NOT invariant under turns of the (0, 1) plane: a Gaussian off the axis,
# anisotropic, with a second mode; a symmetry move is accepted only where pi agrees.
MODES = jnp.array([[2.0, 0.0, 0.0], [-1.0, -1.5, 1.0]])
SDS = jnp.array([[0.3, 0.8, 0.5], [0.6, 0.3, 0.4]])
WEIGHTS = jnp.array([0.6, 0.4])
N_CHAINS, N_STEPS, ADAPT = 400, 300, 50
PLANES = ((0, 1, 1.0),)


def mixture_logdensity(x, modes, sds):
    comps = (jnp.log(WEIGHTS) - 0.5 * jnp.sum(((x - modes) / sds) ** 2, -1)
             - jnp.sum(jnp.log(sds), -1))
    return jax.scipy.special.logsumexp(comps)


def mixture_draws(key, n, modes, sds):
    k1, k2 = jax.random.split(key)
    labels = jax.random.bernoulli(k1, WEIGHTS[1], (n,)).astype(jnp.int32)
    return modes[labels] + sds[labels] * jax.random.normal(k2, (n, modes.shape[1]))


def logdensity(x):
    return mixture_logdensity(x, MODES, SDS)


def exact_draws(key, n):
    return mixture_draws(key, n, MODES, SDS)


def _algorithm(**kw):
    sketch = exact_draws(jax.random.key(1), 400)
    return jg.mcmc.kameleon_darting(
        logdensity, sketch, MODES, epsilon=1.0, gamma=0.3, nu=0.1, sigma=1.0,
        adapt_steps=ADAPT, target_acceptance=0.3, p_check=0.8, symmetry_planes=PLANES,
        p_symmetry=0.4, symmetry_scale=1.0, **kw)


def _z_scores(alg, key):
    x0 = exact_draws(jax.random.key(2), N_CHAINS)  # exact start: a right kernel keeps it
    positions, infos = jg.mcmc.sample(key, alg, x0, N_STEPS)
    tail = np.asarray(positions[ADAPT + 50:], np.float64)
    probs = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    ref = np.quantile(np.asarray(exact_draws(jax.random.key(3), 200_000)), probs, axis=0)
    z = []
    for dim in range(3):
        ind = (tail[:, :, dim, None] < ref[:, dim]).mean(axis=0)  # (C, 5): per chain
        z.append((ind.mean(axis=0) - probs) / (ind.std(axis=0, ddof=1) / np.sqrt(N_CHAINS)))
    return np.asarray(z), infos


def test_kameleon_darting_with_symmetry_moves_is_exact():
    z, infos = _z_scores(_algorithm(), jax.random.key(4))
    assert np.all(np.abs(z) < 4.5), z
    # the moves are taken and some are accepted (the test exercises them)
    turned = ~np.asarray(infos.is_jump) & (np.asarray(infos.acceptance_rate) < 1)
    assert turned.any() and np.asarray(infos.is_accepted).mean() > 0.1


def test_a_biased_turn_is_detected(monkeypatch):
    """Companion: turning by N(0.5, 1) (not symmetric) with the same acceptance is biased."""
    def shifted(key, x, planes, scale):
        return symmetry.rotate(x, planes, 0.5 + scale * jax.random.normal(key, (), x.dtype))

    monkeypatch.setattr(kd.symmetry, "symmetry_proposal", shifted)
    z, _ = _z_scores(retraced(_algorithm()), jax.random.key(4))
    assert np.max(np.abs(z)) > 8, z


@pytest.mark.compile_bound
def test_without_planes_the_sampler_is_unchanged():
    """No planes: the same draws as a sampler built without the symmetry arguments."""
    sketch = exact_draws(jax.random.key(1), 200)
    a = jg.mcmc.kameleon_darting(logdensity, sketch, MODES, gamma=0.3, nu=0.1, sigma=1.0)
    b = jg.mcmc.kameleon_darting(logdensity, sketch, MODES, gamma=0.3, nu=0.1, sigma=1.0,
                                 symmetry_planes=(), p_symmetry=0.0)
    x0 = exact_draws(jax.random.key(2), 8)
    pa, _ = jg.mcmc.sample(jax.random.key(5), a, x0, 20)
    pb, _ = jg.mcmc.sample(jax.random.key(5), b, x0, 20)
    np.testing.assert_array_equal(pa, pb)
    with pytest.raises(ValueError, match="p_symmetry"):
        jg.mcmc.kameleon_darting(logdensity, sketch, MODES, p_check=0.5,
                                 symmetry_planes=PLANES, p_symmetry=0.6)


def test_pivot_planes_turn_the_grasp_about_its_closing_axis():
    """Right multiplication by a turn about the grasp frame's y axis; the centre stays."""
    q = so3.random_quaternion(jax.random.key(1))
    g = jnp.concatenate([jnp.array([0.05, -0.02, 0.1]), q])
    angle = -0.6
    out = symmetry.rotate(g, symmetry.PIVOT_PLANES, angle)
    r = so3.from_axis_angle(jnp.array([0.0, 1.0, 0.0]), angle)
    np.testing.assert_allclose(out[:3], g[:3])
    np.testing.assert_allclose(out[3:], so3.multiply(q, r), atol=1e-6)
    # the closing axis (grasp y) seen from the object is unchanged
    y = lambda quat: so3.rotate(quat, jnp.array([0.0, 1.0, 0.0]))  # noqa: E731
    np.testing.assert_allclose(y(out[3:]), y(q), atol=1e-6)


GROUPS = (((0, 1, 1.0),), ((1, 2, 0.5),))


def _mixture_algorithm():
    sketch = exact_draws(jax.random.key(1), 400)
    return jg.mcmc.kameleon_darting(
        logdensity, sketch, MODES, epsilon=1.0, gamma=0.3, nu=0.1, sigma=1.0,
        adapt_steps=ADAPT, target_acceptance=0.3, p_check=0.8, symmetry_planes=GROUPS,
        p_symmetry=0.4, symmetry_scale=jnp.array([1.0, 2.0]), symmetry_weights=[0.3, 0.7])


@pytest.mark.slow  # a second companion; the 7-d test below carries one in `make test`
def test_a_state_dependent_choice_of_turn_is_detected(monkeypatch):
    """Companion: choosing the group from the state (x_0 > 2 -> group 0) breaks the symmetry
    of the proposal; with the same acceptance the chain is biased."""
    def by_state(key, x, groups, scales, weights):
        pick = jnp.where(x[0] > 2.0, 0, 1)
        angle = scales[pick] * jax.random.normal(key, (), x.dtype)
        return jnp.where(pick == 0, symmetry.rotate(x, groups[0], angle),
                         symmetry.rotate(x, groups[1], angle))

    monkeypatch.setattr(kd.symmetry, "mixture_proposal", by_state)
    z, _ = _z_scores(retraced(_mixture_algorithm()), jax.random.key(6))
    assert np.max(np.abs(z)) > 8, z


def test_a_slide_moves_the_grasp_along_its_approach_axis():
    q = so3.random_quaternion(jax.random.key(2))
    g = jnp.concatenate([jnp.array([0.05, -0.02, 0.1]), 2.0 * q])  # lifted: |q| != 1
    out = symmetry.move(g, symmetry.APPROACH_SLIDE, 0.03)
    np.testing.assert_allclose(out[3:], g[3:])
    np.testing.assert_allclose(out[:3] - g[:3], 0.03 * so3.rotate(q, jnp.array([0.0, 0.0, 1.0])),
                               atol=1e-6)
    np.testing.assert_allclose(symmetry.move(out, symmetry.APPROACH_SLIDE, -0.03), g, atol=1e-6)
    with pytest.raises(ValueError, match="slide"):
        symmetry.check_groups(symmetry.APPROACH_SLIDE, 3)


# A 7-d target (position, lifted quaternion) that no turn, pivot or slide leaves invariant.
MODES7 = jnp.array([[1.0, 0.5, 0.0, 0.8, 0.2, -0.3, 0.1],
                    [-0.5, -1.0, 0.5, 0.1, -0.7, 0.4, 0.5]])
SDS7 = jnp.array([[0.3, 0.5, 0.4, 0.2, 0.3, 0.25, 0.2],
                  [0.4, 0.3, 0.3, 0.3, 0.2, 0.3, 0.25]])


def logdensity7(x):
    return mixture_logdensity(x, MODES7, SDS7)


def exact_draws7(key, n):
    return mixture_draws(key, n, MODES7, SDS7)


GRASP_MOVES = (symmetry.Z_AXIS_PLANES, symmetry.PIVOT_PLANES, symmetry.APPROACH_SLIDE)


def _grasp_moves_z(key, moves=GRASP_MOVES, scales=(0.5, 0.5, 0.5), weights=(0.3, 0.3, 0.4),
                   modes=MODES7, sds=SDS7, **kw):
    def target(x):
        return mixture_logdensity(x, modes, sds)

    def draws(k, n):
        return mixture_draws(k, n, modes, sds)

    alg = jg.mcmc.kameleon_darting(
        target, draws(jax.random.key(1), 400), modes, epsilon=1.0, gamma=0.2,
        nu=0.1, sigma=1.0, adapt_steps=ADAPT, target_acceptance=0.3, p_check=0.8,
        symmetry_planes=moves, p_symmetry=0.5, symmetry_scale=jnp.array(scales),
        symmetry_weights=list(weights))
    if kw.get("wrap"):
        alg = retraced(alg)
    x0 = draws(jax.random.key(2), N_CHAINS)
    positions, infos = jg.mcmc.sample(key, alg, x0, N_STEPS)
    tail = np.asarray(positions[ADAPT + 50:], np.float64)
    probs = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    ref = np.quantile(np.asarray(draws(jax.random.key(3), 200_000)), probs, axis=0)
    ind = (tail[..., None] < ref.T[None, None]).mean(axis=0)  # (C, 7, 5): per chain
    z = (ind.mean(axis=0) - probs) / (ind.std(axis=0, ddof=1) / np.sqrt(N_CHAINS))
    return z, infos


def test_turns_pivots_and_slides_together_are_exact():
    z, infos = _grasp_moves_z(jax.random.key(7))
    assert np.all(np.abs(z) < 4.5), z
    assert np.asarray(infos.is_accepted).mean() > 0.1


def test_a_biased_slide_is_detected(monkeypatch):
    """Companion: slides by N(0.3, 0.5²) (not symmetric) with the same acceptance."""
    real_move = symmetry.move

    def biased(x, group, amount):
        return real_move(x, group, amount + 0.3 if isinstance(group, symmetry.Slide) else amount)

    monkeypatch.setattr(kd.symmetry, "move", biased)
    z, _ = _grasp_moves_z(jax.random.key(7), wrap=True)
    assert np.max(np.abs(z)) > 8, z


def _grasp(key, scale=1.0):
    q = so3.random_quaternion(key)
    return jnp.concatenate([jnp.array([0.05, -0.02, 0.1]), scale * q])


def test_a_turn_about_an_offset_axis_is_a_rigid_turn_about_it():
    g = _grasp(jax.random.key(3))
    centre = jnp.array([0.02, -0.01, 0.0])
    out = symmetry.move(g, symmetry.Turn((0.02, -0.01)), 0.9)
    r = so3.from_axis_angle(jnp.array([0.0, 0.0, 1.0]), 0.9)
    np.testing.assert_allclose(out[:3], centre + so3.rotate(r, g[:3] - centre), atol=1e-6)
    np.testing.assert_allclose(out[3:], so3.multiply(r, g[3:]), atol=1e-6)
    # through the origin it is the z-axis planes, bit for bit
    np.testing.assert_array_equal(symmetry.move(g, symmetry.Turn(), 0.9),
                                  symmetry.rotate(g, symmetry.Z_AXIS_PLANES, 0.9))


@pytest.mark.compile_bound
def test_an_n_fold_turn_picks_each_multiple_of_its_angle_equally():
    g = _grasp(jax.random.key(4))
    amounts = jax.random.normal(jax.random.key(5), (30_000,))
    out = jax.vmap(lambda a: symmetry.move(g, symmetry.Turn((0.0, 0.0), 3), a))(amounts)
    angles = np.degrees(np.arctan2(out[:, 1], out[:, 0]) - np.arctan2(g[1], g[0])) % 360
    k = np.round(angles / 120.0).astype(int) % 3
    np.testing.assert_allclose(angles, 120.0 * np.round(angles / 120.0), atol=1e-3)
    counts = np.bincount(k, minlength=3)
    assert counts[0] == 0 and abs(counts[1] - counts[2]) < 4 * np.sqrt(30_000 / 2), counts


def test_a_mirror_reflects_the_grasp_and_is_its_own_inverse():
    g = _grasp(jax.random.key(6), scale=1.7)  # lifted: |q| != 1 is kept
    mirror = symmetry.Mirror((0.01, 0.02), (0.4,))
    out = symmetry.move(g, mirror, 0.3)
    n = np.array([-np.sin(0.4), np.cos(0.4), 0.0])
    m = np.eye(3) - 2 * np.outer(n, n)
    c = np.array([0.01, 0.02, 0.0])
    np.testing.assert_allclose(out[:3], c + m @ (np.asarray(g[:3]) - c), atol=1e-6)
    rot = lambda q: np.asarray(so3.to_matrix(q / jnp.linalg.norm(q)))  # noqa: E731
    np.testing.assert_allclose(rot(out[3:]), m @ rot(g[3:]) @ np.diag([1.0, -1.0, 1.0]),
                               atol=1e-5)
    np.testing.assert_allclose(jnp.linalg.norm(out[3:]), jnp.linalg.norm(g[3:]), rtol=1e-6)
    np.testing.assert_allclose(symmetry.move(out, mirror, -1.2), g, atol=1e-6)


@pytest.mark.compile_bound
@pytest.mark.parametrize("group", [
    symmetry.Turn((0.02, -0.01), 3), symmetry.Turn((0.0, 0.0), 8),
    symmetry.Mirror((0.01, 0.02), (0.4,)),
    symmetry.Mirror((0.01, 0.02), tuple(np.linspace(0.1, 3.0, symmetry.MAX_MIRRORS)))])
def test_a_discrete_move_is_the_static_turn_or_mirror_bit_for_bit(group):
    """Inside the step an n-fold turn or a mirror is a :class:`Discrete` move whose numbers
    are arguments: the same grasps as the static move, for every draw."""
    static, geometry = symmetry.split_groups((group,))
    assert static == (symmetry.Discrete(),)
    g = _grasp(jax.random.key(9), scale=1.3)
    amounts = jax.random.normal(jax.random.key(10), (2000,))
    moved = jax.jit(jax.vmap(lambda geo, a: symmetry.move(
        g, symmetry.join_groups(static, geo)[0], a), in_axes=(None, 0)))
    want = jax.jit(jax.vmap(lambda a: symmetry.move(g, group, a)))(amounts)
    np.testing.assert_array_equal(moved(geometry, amounts), want)
    # another turn order or plane set through the same program moves elsewhere
    other = symmetry.Turn((0.02, -0.01), 5) if isinstance(group, symmetry.Turn) else \
        symmetry.Mirror((0.01, 0.02), (1.0,))
    assert not np.allclose(moved(symmetry.split_groups((other,))[1], amounts), want)
    assert moved._cache_size() == 1


def test_a_mirror_with_more_planes_than_padded_keeps_its_own_program():
    many = symmetry.Mirror((0.0, 0.0), tuple(np.linspace(0.1, 3.0, symmetry.MAX_MIRRORS + 1)))
    static, _ = symmetry.split_groups((many, symmetry.Turn((0.1, 0.0))))
    assert static == (symmetry.Mirror(None, symmetry.MAX_MIRRORS + 1), symmetry.Turn(None, 0))


# Turns about offset axes (continuous and 3-fold) and mirrors: exact on the same 7-d target.
OBJECT_MOVES = (symmetry.Turn((0.3, -0.2)), symmetry.Turn((-0.1, 0.2), 3),
                symmetry.Mirror((0.2, 0.1), (0.3, 1.2)))
OBJECT_SCALES = (0.5, 1.0, 1.0)  # discrete moves draw their pick from N(0, 1)
OBJECT_WEIGHTS = (0.2, 0.2, 0.6)
# Two modes, the second near the first's mirror image (weights 0.6 / 0.4: pi is not
# invariant), so mirror moves are often accepted and a wrong one shows.
_MIRRORED = symmetry.move(MODES7[0], symmetry.Mirror((0.2, 0.1), (0.3,)), -1.0)
MIRROR_MODES = jnp.stack([MODES7[0], _MIRRORED.at[2].add(0.2)])
MIRROR_SDS = jnp.full((2, 7), 0.3)
MIRROR_TARGET = {"moves": OBJECT_MOVES, "scales": OBJECT_SCALES, "weights": OBJECT_WEIGHTS,
                 "modes": MIRROR_MODES, "sds": MIRROR_SDS}


def test_offset_turns_n_fold_turns_and_mirrors_are_exact():
    z, infos = _grasp_moves_z(jax.random.key(8), **MIRROR_TARGET)
    assert np.all(np.abs(z) < 4.5), z
    assert np.asarray(infos.is_accepted).mean() > 0.1


@pytest.mark.slow  # a second companion; the biased slide above carries one in `make test`
def test_a_mirror_that_is_not_its_own_inverse_is_detected(monkeypatch):
    """Companion: a mirror followed by a fixed shift of 0.3 along x (applied twice it does not
    return: the proposal is not symmetric) with the same acceptance is biased."""
    real_move = symmetry.move

    def shifted(x, group, amount):
        out = real_move(x, group, amount)
        return out.at[0].add(0.3) if isinstance(group, symmetry.Mirror) else out

    monkeypatch.setattr(kd.symmetry, "move", shifted)
    z, _ = _grasp_moves_z(jax.random.key(8), wrap=True, **MIRROR_TARGET)
    assert np.max(np.abs(z)) > 8, z
