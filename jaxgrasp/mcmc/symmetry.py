"""Symmetry moves: turn the state in fixed coordinate planes by one random angle.

``x' = R(δ) x`` where ``R(δ)`` turns each plane ``(i, j)`` of ``planes`` by ``rate · δ`` and
``δ ~ N(0, scale²)``. ``R(δ)`` is orthogonal (it keeps volume) and ``R(−δ) = R(δ)⁻¹``, and ``δ``
and ``−δ`` are equally likely, so ``q(x' | x) = q(x | x')``: the MH acceptance is
``min(1, π(x') / π(x))``.

A grasp ``(x, y, z, qw, qx, qy, qz)`` turned about the object frame's z axis by δ is the plane
``(x, y)`` at rate 1 and the quaternion planes ``(qw, qz)`` and ``(qx, qy)`` at rate 1/2 (left
multiplication by ``(cos δ/2, 0, 0, sin δ/2)``): :data:`Z_AXIS_PLANES`. On an object with a
revolution axis, a grasp that holds turned about that axis holds again, wherever the handle
is not in the way, and is a new grasp once the turn exceeds the 1 cm / 10° cell.

A grasp pivoted about the gripper's own closing axis (the grasp frame's y axis, through the
grasp centre between the pads) is right multiplication by ``(cos δ/2, 0, sin δ/2, 0)``: the
quaternion planes ``(qw, qy)`` and ``(qx, qz)`` at rate 1/2, position unchanged
(:data:`PIVOT_PLANES`). The pads stay on the same contact points while the approach direction
tilts, so a pinch that holds often holds pivoted.

A slide moves the position along a fixed axis of the grasp frame, ``p' = p + δ R(q) a``
(:class:`Slide`; e.g. the approach axis: a deeper or shallower grasp). The shift depends only
on the quaternion, which it leaves unchanged, so the map has unit Jacobian and ``−δ`` undoes
it: symmetric as well.

A turn about a vertical axis through ``centre`` (:class:`Turn`) shifts the position by
``-centre``, turns it like :data:`Z_AXIS_PLANES` and shifts it back: continuous (``order`` 0,
an object of revolution) or by ``2πk/order`` with ``k`` uniform in ``1 .. order-1`` (an
n-fold symmetric object; ``k`` and ``order - k`` are equally likely, so the move is symmetric).
A mirror (:class:`Mirror`) reflects the grasp through a vertical plane through ``centre``,
``p' = c + M (p - c)``, ``R' = M R S`` with ``S`` the gripper's own mirror (its closing axis
reversed: the pads swap): ``q' = (0, n) ⊗ q ⊗ (0, e_y)``. Both parts are linear isometries and
the map is its own inverse, so the proposal is symmetric; with several planes one is picked
independently of the state.

Several groups of planes (or slides, turns, mirrors) make a mixture: pick group ``g`` with
probability ``w_g`` (state independent), then turn by ``δ ~ N(0, scale_g²)``; each component
is symmetric, so the mixture is (:func:`mixture_proposal`).
"""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp import so3
from jaxgrasp.types import Array, PRNGKey

__all__ = ["Z_AXIS_PLANES", "PIVOT_PLANES", "APPROACH_SLIDE", "MAX_MIRRORS", "Slide", "Turn",
           "Mirror", "Discrete", "check_planes", "split_groups", "join_groups",
           "check_groups", "rotate", "move", "symmetry_proposal", "mixture_proposal"]

#: A 7-d grasp (position first, then a w-first quaternion) turned about z.
Z_AXIS_PLANES = ((0, 1, 1.0), (3, 6, 0.5), (4, 5, 0.5))
#: A 7-d grasp pivoted about its own closing axis (grasp frame y) through the grasp centre.
PIVOT_PLANES = ((3, 5, 0.5), (4, 6, 0.5))


class Slide(NamedTuple):
    """Shift ``x[0:3]`` along ``axis`` turned by the (normalized) quaternion ``x[3:7]``."""

    axis: tuple = (0.0, 0.0, 1.0)


class Turn(NamedTuple):
    """Turn a 7-d grasp about the vertical axis through ``centre`` (sampler units): by the
    move's angle (``order`` 0) or by ``2πk/order``, ``k`` uniform in ``1 .. order-1``."""

    centre: tuple = (0.0, 0.0)
    order: int = 0


class Mirror(NamedTuple):
    """Reflect a 7-d grasp through one of the vertical planes through ``centre`` (sampler
    units) at ``angles`` (radians to the x axis), picked uniformly (among the first ``count``
    when ``angles`` is padded: inside the traced step)."""

    centre: tuple = (0.0, 0.0)
    angles: tuple = (0.0,)
    count: object = None


class Discrete(NamedTuple):
    """Inside the traced step: an n-fold :class:`Turn` or a :class:`Mirror` whose kind and
    numbers are arrays (``count``: the turn's ``order - 1`` or the mirror's planes; ``step``:
    the turn's ``2π/order``; ``angles``: the planes padded to :data:`MAX_MIRRORS`), so objects
    with other orders, mirrors or kinds share one compiled sampler."""

    centre: object = None
    is_mirror: object = None
    count: object = None
    step: object = None
    angles: object = None


MOVES = (Slide, Turn, Mirror)
#: Mirror planes a :class:`Discrete` move carries (padded); a mirror with more is its own program.
MAX_MIRRORS = 8

#: A 7-d grasp moved along its own approach axis (grasp frame z): deeper or shallower.
APPROACH_SLIDE = Slide((0.0, 0.0, 1.0))


def check_planes(planes, d: int) -> tuple:
    """``planes`` as a static tuple of ``(i, j, rate)`` with distinct coordinates ``< d``."""
    out = tuple((int(i), int(j), float(rate)) for i, j, rate in planes)
    used = [c for i, j, _ in out for c in (i, j)]
    if len(set(used)) != len(used) or any(not 0 <= c < d for c in used):
        raise ValueError(f"symmetry planes must use distinct coordinates in [0, {d}), got {out}")
    return out


def check_groups(planes, d: int) -> tuple:
    """``planes`` as a static tuple of groups of planes: one group ``((i, j, rate), ...)`` or
    several ``(group, group, ...)``; empty for none."""
    if isinstance(planes, MOVES):
        return (_check_move(planes, d),)
    planes = tuple(planes)
    if not planes:
        return ()
    if isinstance(planes[0], MOVES) or isinstance(planes[0][0], tuple | list):
        return tuple(_check_move(g, d) if isinstance(g, MOVES) else check_planes(g, d)
                     for g in planes)
    return (check_planes(planes, d),)


def _check_move(move, d: int):
    if isinstance(move, Slide):
        return _check_slide(move, d)
    if d < 7:
        raise ValueError(f"a turn or a mirror needs a 7-d state (position, quaternion), got "
                         f"d = {d}")
    centre = tuple(float(c) for c in move.centre)
    if len(centre) != 2:
        raise ValueError(f"a vertical axis needs a 2-d centre (x, y), got {move.centre}")
    if isinstance(move, Turn):
        if not (isinstance(move.order, int) and (move.order == 0 or move.order >= 2)):
            raise ValueError(f"a turn's order is 0 (any angle) or >= 2, got {move.order!r}")
        return Turn(centre, move.order)
    angles = tuple(float(a) for a in move.angles)
    if not angles:
        raise ValueError("a mirror needs at least one plane angle")
    return Mirror(centre, angles)


def _check_slide(slide: Slide, d: int) -> Slide:
    axis = tuple(float(a) for a in slide.axis)
    if d < 7 or len(axis) != 3 or abs(sum(a * a for a in axis) - 1.0) > 1e-6:
        raise ValueError(f"a slide needs a 7-d state (position, quaternion) and a unit 3-d "
                         f"axis, got d = {d}, axis {axis}")
    return Slide(axis)


def split_groups(groups: tuple) -> tuple:
    """``(static, geometry)``: the groups with each turn's and mirror's numbers taken out
    (``static`` keeps whether a turn is continuous: the program; n-fold turns and mirrors
    become :class:`Discrete`) and those numbers as arrays (``geometry``, per group), so objects
    with other axes, orders and mirrors share one compiled sampler."""
    static, geometry = [], []
    for g in groups:
        if isinstance(g, Turn) and g.order == 0:
            static.append(Turn(None, 0))
            geometry.append((jnp.asarray(g.centre, jnp.float32),))
        elif isinstance(g, Turn | Mirror) and len(getattr(g, "angles", ())) <= MAX_MIRRORS:
            static.append(Discrete())
            geometry.append(_discrete(g))
        elif isinstance(g, Mirror):
            static.append(Mirror(None, len(g.angles)))
            geometry.append((jnp.asarray(g.centre, jnp.float32),
                             jnp.asarray(g.angles, jnp.float32)))
        else:
            static.append(g)
            geometry.append(())
    return tuple(static), tuple(geometry)


def _discrete(g) -> tuple:
    """A :class:`Discrete`'s arrays for an n-fold turn or a mirror (the turn's step rounded
    from float64, as a Python constant would be: the same draws as the static move)."""
    is_mirror = isinstance(g, Mirror)
    count = len(g.angles) if is_mirror else g.order - 1
    step = 0.0 if is_mirror else 2.0 * math.pi / g.order
    angles = np.zeros(MAX_MIRRORS, np.float32)
    if is_mirror:
        angles[:count] = g.angles
    return (jnp.asarray(g.centre, jnp.float32), jnp.asarray(is_mirror),
            jnp.asarray(count, jnp.float32), jnp.asarray(step, jnp.float32),
            jnp.asarray(angles))


def join_groups(static: tuple, geometry: tuple) -> tuple:
    """Inverse of :func:`split_groups` (inside the traced step)."""
    return tuple(Discrete(*geo) if isinstance(g, Discrete)
                 else g._replace(centre=geo[0]) if isinstance(g, Turn)
                 else g._replace(centre=geo[0], angles=geo[1]) if isinstance(g, Mirror)
                 else g for g, geo in zip(static, geometry, strict=True))


def rotate(x: Array, planes: tuple, angle: Array) -> Array:
    """``R(angle) x``: each plane ``(i, j, rate)`` turned by ``rate · angle``."""
    for i, j, rate in planes:
        c, s = jnp.cos(rate * angle), jnp.sin(rate * angle)
        xi, xj = x[i], x[j]
        x = x.at[i].set(c * xi - s * xj).at[j].set(s * xi + c * xj)
    return x


def move(x: Array, group, amount: Array) -> Array:
    """``x`` turned in a group of planes, or slid (:class:`Slide`), by ``amount``."""
    if isinstance(group, Slide):
        q = x[3:7] / jnp.linalg.norm(x[3:7])
        return x.at[:3].add(amount * so3.rotate(q, jnp.asarray(group.axis, x.dtype)))
    if isinstance(group, Turn):
        angle = amount if group.order == 0 else (
            2.0 * jnp.pi / group.order * (1 + _pick(amount, group.order - 1)))
        return _turn(x, group.centre, angle)
    if isinstance(group, Mirror):
        count = len(group.angles) if group.count is None else group.count
        return _mirror(x, group, _pick(amount, count))
    if isinstance(group, Discrete):  # both computed, one kept: the kind is data
        turned = _turn(x, group.centre, group.step * (1 + _pick(amount, group.count)))
        mirrored = move(x, Mirror(group.centre, group.angles, group.count), amount)
        return jnp.where(group.is_mirror, mirrored, turned)
    return rotate(x, group, amount)


def _turn(x: Array, centre, angle: Array) -> Array:
    c = jnp.asarray(centre, x.dtype)
    return rotate(x.at[:2].add(-c), Z_AXIS_PLANES, angle).at[:2].add(c)


def _pick(amount: Array, n: int) -> Array:
    """An index uniform in ``0 .. n-1`` from a standard normal ``amount`` (independent of the
    state; a discrete move takes scale 1)."""
    u = jax.scipy.special.ndtr(amount)
    return jnp.clip(jnp.floor(u * n), 0, n - 1)


def _mirror(x: Array, mirror: Mirror, j: Array) -> Array:
    theta = jnp.asarray(mirror.angles, x.dtype)[j.astype(jnp.int32)]
    n = jnp.stack([-jnp.sin(theta), jnp.cos(theta), jnp.zeros_like(theta)])
    c = jnp.concatenate([jnp.asarray(mirror.centre, x.dtype), jnp.zeros(1, x.dtype)])
    p = x[:3] - c
    p = c + p - 2.0 * jnp.dot(p, n) * n
    # (0, n) ⊗ q ⊗ (0, e_y): R' = Rot_π(n) R Rot_π(e_y) = M R S (no normalisation: lifted q)
    q = so3.multiply(so3.multiply(jnp.concatenate([jnp.zeros(1, x.dtype), n]), x[3:7]),
                     jnp.asarray([0.0, 0.0, 1.0, 0.0], x.dtype))
    return jnp.concatenate([p, q, x[7:]])


def symmetry_proposal(key: PRNGKey, x: Array, planes: tuple, scale: Array) -> Array:
    """``R(δ) x`` with ``δ ~ N(0, scale²)`` (a symmetric proposal: no Hastings term)."""
    angle = scale * jax.random.normal(key, (), x.dtype)
    return move(x, planes, angle)


def mixture_proposal(key: PRNGKey, x: Array, groups: tuple, scales: Array,
                     weights: Array) -> Array:
    """Group ``g ~ weights`` (state independent), then ``R_g(δ) x`` with ``δ ~ N(0, scales_g²)``:
    a mixture of symmetric proposals, itself symmetric."""
    k_pick, k_angle = jax.random.split(key)
    pick = jax.random.categorical(k_pick, jnp.log(weights))
    angle = scales[pick] * jax.random.normal(k_angle, (), x.dtype)
    out = move(x, groups[0], angle)
    for g, group in enumerate(groups[1:], start=1):
        out = jnp.where(pick == g, move(x, group, angle), out)
    return out
