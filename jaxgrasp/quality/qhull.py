"""The reference epsilon: numpy (float64) and ``scipy.spatial.ConvexHull`` (Qhull)."""

import numpy as np

from jaxgrasp.quality.wrenches import WRENCH_DIM, _check_contacts, contact_wrenches


def epsilon_qhull_from_wrenches(wrenches) -> float:
    """Reference epsilon of a wrench set (rows of ``wrenches``) with scipy's Qhull, float64.

    Flat sets (affine rank < 6, detected by SVD) give 0. Full-rank sets on which Qhull's
    default options hit a topology error (dupridge on very symmetric sets) are retried with
    ``"Qt Q12"`` and then ``"QJ"`` (joggle ~1e-11 relative). Then
    ``epsilon = max(0, min_F -offset_F)`` over the hull facets (``hull.equations`` rows
    ``[n_F, offset_F]`` with unit outward ``n_F``, interior ``n_F·x + offset_F <= 0``), which
    is 0 when the origin is outside or on the boundary.
    """
    # why: scipy.spatial is a heavy import that only this reference path needs.
    from scipy.spatial import ConvexHull, QhullError

    W = np.asarray(wrenches, np.float64).reshape(-1, WRENCH_DIM)
    if W.shape[0] <= WRENCH_DIM:
        return 0.0
    sv = np.linalg.svd(W - W.mean(axis=0), compute_uv=False)
    if sv[-1] <= 1e-10 * max(sv[0], 1e-300):
        return 0.0
    # Full rank: a Qhull failure is a precision/topology problem of a symmetric set (e.g.
    # many coplanar patch contacts), not flatness. Retry allowing wide merges, then joggled.
    for options in (None, "Qt Q12", "QJ"):
        try:
            hull = ConvexHull(W, qhull_options=options)
        except QhullError:
            continue
        return float(max(0.0, np.min(-hull.equations[:, -1])))
    return 0.0


def epsilon_qhull(points, normals, mask, mu, center, radius, num_edges=8) -> float:
    """Reference epsilon (numpy + ``scipy.spatial.ConvexHull``), same arguments as :func:`epsilon`.

    Returns
    -------
    float
        Distance from the origin to the GWS boundary, 0 when not strictly inside or flat.
    """
    points, normals, mask = np.asarray(points), np.asarray(normals), np.asarray(mask)
    _check_contacts(points.shape, normals.shape, mask.shape, np.shape(center), num_edges)
    f64 = lambda x: np.asarray(x, np.float64)  # noqa: E731
    W = contact_wrenches(f64(points).reshape(-1, 3), f64(normals).reshape(-1, 3), mu, f64(center),
                         float(radius), num_edges, xp=np)
    keep = np.repeat(mask.astype(bool), num_edges)
    return epsilon_qhull_from_wrenches(W[keep])
