"""Unit quaternions, poses and the von Mises-Fisher distribution on S^3.

Conventions: quaternions are ``(w, x, y, z)`` (scalar first), Hamilton product, active
rotations (``rotate(q, v) = q v q*``). A pose is ``(x, y, z, qw, qx, qy, qz)``: ``(7,)``, the
same layout as a grasp. ``q`` and ``-q`` are the same rotation; :func:`canonicalize` picks
``qw >= 0`` and is meant for reporting only (samplers never canonicalize).

Every function works on one quaternion/pose (trailing axis 4 or 7, leading axes broadcast where
noted); ``jax.vmap`` them for many. :func:`normalize`, :func:`conjugate`, :func:`to_matrix` and
:func:`unit_to_matrix` also take ``xp=numpy`` (host code, float64: the MuJoCo C backend, figures).
Nothing here imports MuJoCo.
"""

import jax
import jax.numpy as jnp

from jaxgrasp.types import Array, PRNGKey

__all__ = [
    "normalize",
    "perturbed_poses",
    "multiply",
    "conjugate",
    "rotate",
    "canonicalize",
    "to_matrix",
    "unit_to_matrix",
    "from_axis_angle",
    "geodesic_angle",
    "pose_compose",
    "pose_inverse",
    "random_quaternion",
    "sample_vmf",
    "vmf_mean_resultant_length",
]

_TINY = 1e-30


def normalize(q: Array, xp=jnp) -> Array:
    """``q / |q|`` along the last axis (the zero quaternion maps to the identity).

    ``xp``: the array namespace, ``jax.numpy`` (default) or ``numpy``.
    """
    q = xp.asarray(q)
    norm = xp.linalg.norm(q, axis=-1, keepdims=True)
    identity = xp.asarray([1, 0, 0, 0], q.dtype)
    # why: avoid 0/0 -> NaN (and NaN gradients) for a degenerate input.
    safe = xp.where(norm > _TINY, norm, 1.0)
    return xp.where(norm > _TINY, q / safe, identity)


def multiply(p: Array, q: Array) -> Array:
    """Hamilton product ``p ⊗ q`` (broadcasts over leading axes): rotate by q, then by p."""
    pw, px, py, pz = jnp.moveaxis(jnp.asarray(p), -1, 0)
    qw, qx, qy, qz = jnp.moveaxis(jnp.asarray(q), -1, 0)
    return jnp.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q: Array, xp=jnp) -> Array:
    """``(w, -x, -y, -z)``: the inverse rotation of a unit quaternion (``xp`` as in
    :func:`normalize`)."""
    q = xp.asarray(q)
    return q * xp.asarray([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def rotate(q: Array, v: Array) -> Array:
    """Rotate the 3-vector(s) ``v`` by the unit quaternion ``q`` (``q v q*``)."""
    q = jnp.asarray(q)
    v = jnp.asarray(v)
    w = q[..., :1]
    u = q[..., 1:]
    # why: the two-cross-product form is cheaper and exact for unit q.
    t = 2.0 * jnp.cross(u, v)
    return v + w * t + jnp.cross(u, t)


def canonicalize(q: Array) -> Array:
    """The representative with ``w >= 0`` (``q`` and ``-q`` are one rotation). Reporting only."""
    q = jnp.asarray(q)
    return jnp.where(q[..., :1] < 0, -q, q)


def unit_to_matrix(q: Array, xp=jnp) -> Array:
    """Rotation matrix ``(..., 3, 3)`` of a quaternion taken as unit (not renormalized:
    physics states and normalized grasps are used as they are). ``xp`` as in :func:`normalize`."""
    w, x, y, z = (q[..., i] for i in range(4))
    return xp.stack(
        [
            xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            xp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            xp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def to_matrix(q: Array, xp=jnp) -> Array:
    """Rotation matrix ``(..., 3, 3)`` of a quaternion of any norm (normalized first).

    ``xp``: ``jax.numpy`` (default) or ``numpy`` (host code; keeps float64).
    """
    return unit_to_matrix(normalize(q, xp), xp)


def from_axis_angle(axis: Array, angle: Array) -> Array:
    """Unit quaternion of a rotation by ``angle`` (radians) about ``axis`` (need not be unit)."""
    axis = jnp.asarray(axis)
    angle = jnp.asarray(angle)
    n = jnp.linalg.norm(axis, axis=-1, keepdims=True)
    axis = axis / jnp.where(n > _TINY, n, 1.0)
    half = 0.5 * angle[..., None]
    return jnp.concatenate([jnp.cos(half), jnp.sin(half) * axis], axis=-1)


def geodesic_angle(p: Array, q: Array) -> Array:
    """Rotation angle in ``[0, π]`` between the rotations ``p`` and ``q`` (sign-invariant).

    Uses ``2·atan2(|vec(p* ⊗ q)|, |w(p* ⊗ q)|)``, accurate for tiny and near-π angles, unlike
    ``2·acos(|p·q|)`` which loses all digits near 0 in float32.
    """
    r = multiply(conjugate(normalize(p)), normalize(q))
    return 2.0 * jnp.arctan2(jnp.linalg.norm(r[..., 1:], axis=-1), jnp.abs(r[..., 0]))


def pose_compose(a: Array, b: Array) -> Array:
    """``a ∘ b`` for poses ``(x, y, z, qw, qx, qy, qz)``: first b, then a (``T_a T_b``)."""
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    qa = normalize(a[..., 3:])
    pos = a[..., :3] + rotate(qa, b[..., :3])
    return jnp.concatenate([pos, multiply(qa, normalize(b[..., 3:]))], axis=-1)


def pose_inverse(a: Array) -> Array:
    """Inverse pose: ``pose_compose(pose_inverse(a), a)`` is the identity."""
    a = jnp.asarray(a)
    qi = conjugate(normalize(a[..., 3:]))
    return jnp.concatenate([-rotate(qi, a[..., :3]), qi], axis=-1)


def perturbed_poses(key: PRNGKey, pose: Array, num: int, position_sd, angle_sd) -> Array:
    """(num, 7) ``pose`` under a robot's pose error: position ``+ N(0, position_sd)`` per axis,
    orientation turned about a uniformly random axis by ``|N(0, angle_sd)|`` (radians), the
    turn applied in the pose's own frame (for a uniform axis the law is the same in any frame).
    """
    pose = jnp.asarray(pose)
    k_pos, k_axis, k_angle = jax.random.split(key, 3)
    pos = pose[:3] + position_sd * jax.random.normal(k_pos, (num, 3), pose.dtype)
    axis = jax.random.normal(k_axis, (num, 3), pose.dtype)
    angle = jnp.abs(angle_sd * jax.random.normal(k_angle, (num,), pose.dtype))
    turn = from_axis_angle(axis, angle)
    return jnp.concatenate([pos, multiply(normalize(pose[3:]), turn)], axis=-1)


def random_quaternion(key: PRNGKey, dtype=jnp.float32) -> Array:
    """One unit quaternion, uniform on S^3 (so the rotation is Haar-uniform on SO(3))."""
    return normalize(jax.random.normal(key, (4,), dtype))


def _chi2_3(key: PRNGKey, shape, dtype) -> Array:
    """χ²(3) draws as sums of three squared normals: loop-free, unlike ``jax.random.gamma``."""
    return jnp.sum(jnp.square(jax.random.normal(key, (*shape, 3), dtype)), axis=-1)


def sample_vmf(key: PRNGKey, mu: Array, kappa: Array, *, num_candidates: int = 16) -> Array:
    """One unit quaternion ``x ~ vMF(mu, kappa)`` on S^3, density ∝ ``exp(kappa · muᵀx)``.

    Wood's (1994) rejection sampler for the component ``w = muᵀx``, written with a fixed number
    of candidates so it is branch-free (``jit``/``vmap``-able, differentiable in nothing but
    cheap). The first accepted candidate is returned; Wood's acceptance probability on S^3 is
    above 0.6 for every kappa, so all 16 rejecting has probability below 1e-6 (the last
    candidate is then used, a negligible bias).

    float32-safe for ``kappa`` from 0 to 1e4 and beyond: ``b``, ``1 - w`` and ``1 - x0·w`` are
    computed in cancellation-free forms instead of ``1 - w**2`` etc. The tangent part is a
    uniform direction on S^2, and the sample is carried from the identity ``e1 = (1,0,0,0)`` to
    ``mu`` by the left multiplication ``mu ⊗ x`` (an isometry of S^3 with ``mu ⊗ e1 = mu``).

    Parameters
    ----------
    key : PRNGKey
    mu : (4,) mean direction (normalized here).
    kappa : scalar >= 0, concentration (0 gives the uniform distribution).
    num_candidates : static number of rejection candidates.

    Returns
    -------
    (4,) unit quaternion.
    """
    mu = normalize(jnp.asarray(mu))
    dtype = mu.dtype
    kappa = jnp.asarray(kappa, dtype)
    k_z1, k_z2, k_u, k_v = jax.random.split(key, 4)
    m1 = 3.0  # (dimension of S^3's ambient space) - 1
    # b = (-2κ + sqrt(4κ² + 9)) / 3, rationalized: no cancellation for large κ.
    b = m1 / (2.0 * kappa + jnp.sqrt(4.0 * kappa**2 + m1**2))
    one_minus_x0 = 2.0 * b / (1.0 + b)
    log_one_minus_x0sq = jnp.log(4.0 * b) - 2.0 * jnp.log1p(b)
    shape = (num_candidates,)
    # Beta(3/2, 3/2) = χ²₃ / (χ²₃ + χ²₃).
    c1 = _chi2_3(k_z1, shape, dtype)
    c2 = _chi2_3(k_z2, shape, dtype)
    z = c1 / (c1 + c2)
    denom = 1.0 - (1.0 - b) * z
    one_minus_w = 2.0 * b * z / denom
    one_plus_w = 2.0 * (1.0 - z) / denom
    w = 1.0 - one_minus_w
    one_minus_x0w = one_minus_w + w * one_minus_x0
    # log acceptance: κ(w − x0) + 3 log(1 − x0 w) − 3 log(1 − x0²).
    log_accept = kappa * (one_minus_x0 - one_minus_w) + m1 * (
        jnp.log(one_minus_x0w) - log_one_minus_x0sq
    )
    log_u = jnp.log(jax.random.uniform(k_u, shape, dtype, minval=jnp.finfo(dtype).tiny))
    accepted = log_u <= log_accept
    # why: first accepted candidate, else the last one (probability < 1e-6).
    idx = jnp.where(jnp.any(accepted), jnp.argmax(accepted), num_candidates - 1)
    w_s = w[idx]
    sin_s = jnp.sqrt(jnp.clip(one_minus_w[idx] * one_plus_w[idx], 0.0, None))
    v = jax.random.normal(k_v, (3,), dtype)
    v = v / jnp.maximum(jnp.linalg.norm(v), _TINY)
    x = jnp.concatenate([w_s[None], sin_s * v])
    return multiply(mu, x)


def vmf_mean_resultant_length(kappa) -> float:
    """``E[muᵀx] = I_2(κ)/I_1(κ)`` for vMF on S^3 (host-side, float64, via scipy).

    Reference value for checks; not used inside the samplers.
    """
    # why: scipy.special is a heavy import that only this reference value needs.
    from scipy.special import ive

    kappa = float(kappa)
    if kappa == 0.0:
        return 0.0
    return float(ive(2, kappa) / ive(1, kappa))
