"""Grasp quality: epsilon of the L1 grasp wrench space (Ferrari & Canny 1992, Miller & Allen 1999).

Convention (see ``docs/design.md``). Contact ``i`` has point ``p_i`` and unit normal ``n_i``
pointing INTO the object (the direction the finger pushes). Its friction cone (coefficient
``mu``) is linearized with ``num_edges`` edges of unit normal component::

    f_ik = n_i + mu (cos θ_k t1_i + sin θ_k t2_i),   θ_k = 2π k / num_edges
    w_ik = (f_ik, (p_i - c) × f_ik / r)                (6,)

with ``c`` the object's center of mass and ``r`` its max radius (torque scale). The grasp
wrench space (GWS) is the convex hull of all ``w_ik`` and

    epsilon = distance from the origin to the boundary of the GWS,

0 when the origin is not strictly inside (origin outside or on the boundary, flat/rank-deficient
wrench sets such as two point contacts). Equivalently, with the support function
``h(u) = max_k u · w_k``, ``epsilon = max(0, min_{|u|=1} h(u))``.

Two implementations with identical arguments:

* :func:`epsilon_qhull` - the reference: numpy (float64) + ``scipy.spatial.ConvexHull``.
* :func:`epsilon` - pure JAX, jittable and vmappable, fixed-size masked contact arrays; the
  method is described in :func:`epsilon_from_wrenches`.

:func:`epsilon_batch` is :func:`epsilon` of a batch where needed (0 elsewhere), the search's
runs of all its trials dealt to a few vmapped lanes: the same values up to round-off (which
can, rarely, pick another best vertex and so another antipode start).

Modules: :mod:`~jaxgrasp.quality.wrenches` (the convention's wrenches),
:mod:`~jaxgrasp.quality.epsilon` (the JAX epsilon), :mod:`~jaxgrasp.quality.simplex` (its
search: LPs and vertex walks), :mod:`~jaxgrasp.quality.qhull` (the reference).
"""

# The names other modules, tests and benchmarks import from ``jaxgrasp.quality``, private
# ones included (``x as x``: a re-export).
from jaxgrasp.quality.epsilon import _EIGH_BATCH as _EIGH_BATCH
from jaxgrasp.quality.epsilon import NUM_EIGEN_STARTS as NUM_EIGEN_STARTS
from jaxgrasp.quality.epsilon import NUM_STARTS as NUM_STARTS
from jaxgrasp.quality.epsilon import ZERO_TOL as ZERO_TOL
from jaxgrasp.quality.epsilon import _eigh as _eigh
from jaxgrasp.quality.epsilon import epsilon, epsilon_batch, epsilon_from_wrenches
from jaxgrasp.quality.qhull import epsilon_qhull, epsilon_qhull_from_wrenches
from jaxgrasp.quality.simplex import _last_lane_per_trial as _last_lane_per_trial
from jaxgrasp.quality.simplex import _lp_step as _lp_step
from jaxgrasp.quality.simplex import _search as _search
from jaxgrasp.quality.simplex import _simplex_directions as _simplex_directions
from jaxgrasp.quality.simplex import _start_basis as _start_basis
from jaxgrasp.quality.simplex import _walk_init as _walk_init
from jaxgrasp.quality.simplex import _walk_step as _walk_step
from jaxgrasp.quality.wrenches import WRENCH_DIM as WRENCH_DIM
from jaxgrasp.quality.wrenches import contact_wrenches, tangent_basis

__all__ = [
    "tangent_basis",
    "contact_wrenches",
    "epsilon",
    "epsilon_from_wrenches",
    "epsilon_batch",
    "epsilon_qhull",
    "epsilon_qhull_from_wrenches",
]
