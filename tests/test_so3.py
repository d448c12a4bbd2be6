"""so3: quaternion algebra, poses, uniform rotations and the vMF sampler on S^3."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.special import iv

from jaxgrasp import so3

KAPPAS = (0.0, 0.5, 5.0, 50.0, 1e3, 1e4)
NUM = 20000


def _vmf_draws(num_candidates=16):
    """NUM draws for each kappa in KAPPAS around one mean direction (one compilation)."""
    mu = so3.normalize(jnp.array([0.3, -0.5, 0.2, 0.7]))
    keys = jax.random.split(jax.random.key(0), (len(KAPPAS), NUM))
    sample = partial(so3.sample_vmf, num_candidates=num_candidates)
    draw = jax.jit(jax.vmap(jax.vmap(sample, (0, None, None)), (0, None, 0)))
    return np.asarray(mu), np.asarray(draw(keys, mu, jnp.asarray(KAPPAS)), np.float64)


@pytest.fixture(scope="module")
def vmf_draws():
    return _vmf_draws()


def test_vmf_unit_norm(vmf_draws):
    _, x = vmf_draws
    np.testing.assert_allclose(np.linalg.norm(x, axis=-1), 1.0, atol=1e-6)


@pytest.mark.parametrize("i", range(len(KAPPAS)))
def test_vmf_mean_resultant_length(vmf_draws, i):
    """E[muᵀx] = I_2(κ)/I_1(κ) and E[1 − (muᵀx)²] = 3 A(κ)/κ, within 5 Monte Carlo SEs."""
    _check_resultant(*vmf_draws, i)


def test_companion_the_sampler_without_its_rejection_step_fails():
    # One candidate: Wood's envelope draw is returned whether or not it would be accepted.
    mu, x = _vmf_draws(num_candidates=1)
    failed = []
    for i in range(len(KAPPAS)):
        try:
            _check_resultant(mu, x, i)
        except AssertionError:
            failed.append(KAPPAS[i])
    assert failed, "the moment check passed a sampler that skips its rejection step"


def _check_resultant(mu, x, i):
    kappa = KAPPAS[i]
    w = x[i] @ mu
    a = so3.vmf_mean_resultant_length(kappa)
    # 1 − w computed from the tangent part keeps float32 digits at large kappa
    one_minus_w = 1.0 - w
    se = one_minus_w.std() / np.sqrt(NUM)
    assert abs(one_minus_w.mean() - (1.0 - a)) < 5 * se + 1e-7, (kappa, w.mean(), a)
    if kappa > 0:
        s = 1.0 - w**2
        assert abs(s.mean() - 3 * a / kappa) < 5 * s.std() / np.sqrt(NUM) + 1e-7


def test_vmf_mean_direction(vmf_draws):
    """The sample mean points along mu (every coordinate within 5 SEs of A(κ)·mu)."""
    mu, x = vmf_draws
    for i, kappa in enumerate(KAPPAS):
        mean = x[i].mean(axis=0)
        se = x[i].std(axis=0) / np.sqrt(NUM)
        expected = so3.vmf_mean_resultant_length(kappa) * mu
        assert np.all(np.abs(mean - expected) < 5 * se + 1e-7), (kappa, mean, expected)


def test_vmf_reference_values():
    for kappa in (0.5, 5.0, 50.0):
        assert so3.vmf_mean_resultant_length(kappa) == pytest.approx(iv(2, kappa) / iv(1, kappa))


def test_vmf_kappa_zero_matches_uniform_second_moment(vmf_draws):
    """κ = 0 is uniform on S^3: E[x xᵀ] = I/4."""
    _, x = vmf_draws
    second = x[0].T @ x[0] / NUM
    np.testing.assert_allclose(second, np.eye(4) / 4, atol=5 * 0.5 / np.sqrt(NUM) * 0.5)


def test_random_quaternion_uniform():
    q = np.asarray(jax.vmap(so3.random_quaternion)(jax.random.split(jax.random.key(1), NUM)))
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(q.T @ q / NUM, np.eye(4) / 4, atol=0.015)


def _scipy(q):
    q = np.asarray(q, np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])  # scipy is scalar-last


def test_multiply_rotate_matrix_match_scipy():
    keys = jax.random.split(jax.random.key(2), 3)
    p, q = so3.random_quaternion(keys[0]), so3.random_quaternion(keys[1])
    v = jax.random.normal(keys[2], (5, 3))
    np.testing.assert_allclose(
        so3.to_matrix(so3.multiply(p, q)), (_scipy(p) * _scipy(q)).as_matrix(), atol=1e-5
    )
    np.testing.assert_allclose(so3.rotate(q, v), _scipy(q).apply(np.asarray(v)), atol=1e-5)
    np.testing.assert_allclose(so3.to_matrix(q), _scipy(q).as_matrix(), atol=1e-5)
    np.testing.assert_allclose(
        so3.multiply(q, so3.conjugate(q)), jnp.array([1.0, 0, 0, 0]), atol=1e-6
    )


def test_geodesic_angle():
    axis = jnp.array([0.2, -1.0, 0.5])
    for angle in (0.0, 1e-4, 0.3, 2.0, np.pi - 1e-3):
        p = so3.random_quaternion(jax.random.key(3))
        q = so3.multiply(p, so3.from_axis_angle(axis, jnp.asarray(angle)))
        assert float(so3.geodesic_angle(p, q)) == pytest.approx(angle, abs=2e-5)
        assert float(so3.geodesic_angle(p, -q)) == pytest.approx(angle, abs=2e-5)


def test_pose_compose_inverse():
    k1, k2 = jax.random.split(jax.random.key(4))
    a = jnp.concatenate([jnp.array([0.1, -0.2, 0.3]), so3.random_quaternion(k1)])
    b = jnp.concatenate([jnp.array([-0.5, 0.4, 0.0]), so3.random_quaternion(k2)])
    ident = so3.pose_compose(so3.pose_inverse(a), a)
    np.testing.assert_allclose(ident[:3], 0.0, atol=1e-6)
    np.testing.assert_allclose(so3.canonicalize(ident[3:]), [1.0, 0, 0, 0], atol=1e-6)

    # T_a T_b as homogeneous matrices
    def mat(p):
        m = np.eye(4)
        m[:3, :3] = np.asarray(so3.to_matrix(p[3:]))
        m[:3, 3] = np.asarray(p[:3])
        return m

    np.testing.assert_allclose(mat(so3.pose_compose(a, b)), mat(a) @ mat(b), atol=1e-5)


def test_normalize_and_canonicalize():
    np.testing.assert_allclose(so3.normalize(jnp.array([2.0, 0, 0, 0])), [1.0, 0, 0, 0])
    np.testing.assert_allclose(so3.normalize(jnp.zeros(4)), [1.0, 0, 0, 0])
    np.testing.assert_allclose(
        so3.canonicalize(jnp.array([-0.5, 0.5, 0.5, 0.5])), [0.5] + [-0.5] * 3
    )


def test_numpy_namespace_matches_jax_and_keeps_float64():
    """``xp=numpy`` (host code: the MuJoCo C backend, figures) computes the same rotations in
    float64, batched over leading axes."""
    rng = np.random.default_rng(5)
    q = rng.normal(size=(6, 4))
    q[0] = 0.0  # zero quaternion: identity, as in jax
    mat = so3.to_matrix(q, xp=np)
    assert isinstance(mat, np.ndarray) and mat.dtype == np.float64 and mat.shape == (6, 3, 3)
    np.testing.assert_allclose(mat[1:], _scipy(q[1:]).as_matrix(), atol=1e-12)
    np.testing.assert_array_equal(mat[0], np.eye(3))
    np.testing.assert_allclose(mat, so3.to_matrix(jnp.asarray(q, jnp.float32)), atol=1e-6)
    unit = so3.normalize(q, xp=np)
    np.testing.assert_array_equal(so3.unit_to_matrix(unit, xp=np), mat)
    np.testing.assert_array_equal(so3.conjugate(unit, xp=np), unit * [1, -1, -1, -1])
