"""Static support: where the body's centre must be for the feet on the ground to hold it. Pure numpy.

A walking robot without a dynamic balance controller stands as long as its centre of mass lies inside
the polygon of the feet on the ground (the support polygon). The body frame's origin stands in for the
centre of mass (the trunk carries most of the mass and the legs spread around it).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError


def support_shift(feet_xy: np.ndarray, margin_m: float) -> np.ndarray | None:
    """The smallest horizontal move of the body's centre (the origin) that puts it ``margin_m`` inside
    the convex polygon of ``feet_xy`` (n x 2): zero when it already is; None when no point of the
    polygon is that far inside (fewer than three feet, feet on one line, a polygon too narrow)."""
    try:
        hull = ConvexHull(np.asarray(feet_xy, dtype=float))
    except (QhullError, ValueError):
        return None
    n, c = hull.equations[:, :2], -hull.equations[:, 2] - margin_m      # inside by the margin: n . x <= c
    cands = [np.zeros(2)] + [ni * ci for ni, ci in zip(n, c)]           # the origin, its projections ...
    for i in range(len(n)):                                             # ... and the corners of the shrunk polygon
        for j in range(i + 1, len(n)):
            if abs(np.linalg.det(n[[i, j]])) > 1e-9:
                cands.append(np.linalg.solve(n[[i, j]], c[[i, j]]))
    ok = [x for x in cands if np.all(n @ x <= c + 1e-9)]
    return min(ok, key=lambda x: float(x @ x)) if ok else None
