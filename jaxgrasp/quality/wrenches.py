"""Primitive wrenches of linearized friction cones (the convention in :mod:`jaxgrasp.quality`).

The tangent basis ``(t1, t2)`` of a normal is a fixed function of the normal
(:func:`tangent_basis`), so the linearized cone is equivariant under rotations about ``z`` for
normals with ``|n_z| < 0.9`` and epsilon is exactly invariant under translating the whole grasp;
under other rotations the edges turn about the normal and epsilon changes by the polygonal
approximation error of the cone (small for many edges).
"""

import jax.numpy as jnp
import numpy as np

WRENCH_DIM = 6
#: Tangent helper axis switches from z to x when |n_z| >= this (keeps t1 well defined).
_HELPER_SWITCH = 0.9


def tangent_basis(normals, xp=jnp):
    """Unit tangents ``t1, t2`` with ``(t1, t2, n)`` right-handed; a fixed function of ``n``.

    ``t1 = normalize(a × n)`` with helper ``a = e_z`` (or ``e_x`` when ``|n_z| >= 0.9``),
    ``t2 = n × t1``. For side contacts (normal horizontal) the edges are aligned with the
    vertical, which keeps symmetric grasps symmetric.

    Parameters
    ----------
    normals : (..., 3) array
        Unit normals.
    xp : array namespace
        ``jax.numpy`` (default) or ``numpy`` (the Qhull reference).

    Returns
    -------
    t1, t2 : (..., 3) arrays
    """
    n = xp.asarray(normals)
    ez = xp.asarray([0.0, 0.0, 1.0], n.dtype)
    ex = xp.asarray([1.0, 0.0, 0.0], n.dtype)
    helper = xp.where(xp.abs(n[..., 2:3]) < _HELPER_SWITCH, ez, ex)
    t1 = xp.cross(helper, n)
    t1 = t1 / xp.maximum(xp.linalg.norm(t1, axis=-1, keepdims=True), 1e-12)
    t2 = xp.cross(n, t1)
    return t1, t2


def contact_wrenches(points, normals, mu, center, radius, num_edges=8, xp=jnp):
    """Primitive wrenches of linearized friction cones (the convention above).

    Parameters
    ----------
    points : (K, 3) array
        Contact points.
    normals : (K, 3) array
        Unit normals pointing into the object (renormalized here; zero rows are allowed and
        give finite wrenches, for masked-out buffer slots).
    mu : float
        Friction coefficient.
    center : (3,) array
        Torque origin (object center of mass).
    radius : float
        Torque scale (object max radius).
    num_edges : int, static
        Cone edges per contact.
    xp : array namespace
        ``jax.numpy`` (default) or ``numpy`` (the Qhull reference, float64).

    Returns
    -------
    (K * num_edges, 6) array
        Row ``i * num_edges + k`` is ``w_ik = (f_ik, (p_i - c) × f_ik / r)``.
    """
    points = xp.asarray(points)
    normals = xp.asarray(normals, points.dtype)
    n = normals / xp.maximum(xp.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    t1, t2 = tangent_basis(n, xp)
    theta = 2.0 * xp.pi * xp.arange(num_edges, dtype=points.dtype) / num_edges
    tangential = (
        xp.cos(theta)[None, :, None] * t1[:, None, :]
        + xp.sin(theta)[None, :, None] * t2[:, None, :]
    )
    forces = n[:, None, :] + mu * tangential  # (K, E, 3)
    arms = (points - xp.asarray(center, points.dtype))[:, None, :]
    torques = xp.cross(xp.broadcast_to(arms, forces.shape), forces) / radius
    return xp.concatenate([forces, torques], axis=-1).reshape(-1, WRENCH_DIM)


def _check_contacts(points, normals, mask, center, num_edges):
    """Static shape checks shared by :func:`epsilon` and :func:`epsilon_qhull`."""
    if len(points) != 2 or points[-1] != 3:
        raise ValueError(f"points must have shape (K, 3), got {points}")
    if tuple(normals) != tuple(points):
        raise ValueError(f"normals must have the shape of points {points}, got {normals}")
    if tuple(mask) != (points[0],):
        raise ValueError(f"mask must have shape ({points[0]},), got {mask}")
    if tuple(center) != (3,):
        raise ValueError(f"center must have shape (3,), got {center}")
    if not (isinstance(num_edges, int | np.integer) and num_edges >= 1):
        raise ValueError(f"num_edges must be a positive int, got {num_edges!r}")
