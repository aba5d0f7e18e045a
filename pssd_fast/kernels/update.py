"""Point update along the filtered normal (docs/ALGORITHM.md, step 4; paper Section 4.2)."""
import math

from numba import prange

from .config import CHUNK, parallel_kernel


@parallel_kernel
def move_points(points, proj, filtered, likelihood, feature, lam, out, held):
    """Move each point along its filtered normal: ``p*_i = p_i + m_i |q_i - p_i| n*_i``.

    Parameters
    ----------
    points, proj, filtered : (n, 3) float64
        Positions ``p_i``, MLS projections ``q_i`` and filtered unit normals ``n*_i``.
    likelihood, feature : (n,) float64
        Sampling likelihood ``l_i`` and feature intensity ``s_i``.
    lam : float
        ``lambda`` in [0, 1], the weight of the likelihood term.
    out : (n, 3) float64
        Output positions (may not alias ``points``).
    held : (n,) bool
        Output: True where the step is not finite (a stage upstream failed for the point);
        such a point is left where it was.

    Notes
    -----
    ``m_i = (-1)^tau [lam exp(-l_i) + (1 - lam) exp(-s_i)]`` with ``tau = 0`` when
    ``n*_i . (q_i - p_i) > 0`` and 1 otherwise: the point moves along ``n*_i`` towards the side
    of its projection, by a fraction of the projection distance.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            dx = proj[i, 0] - points[i, 0]
            dy = proj[i, 1] - points[i, 1]
            dz = proj[i, 2] - points[i, 2]
            side = dx * filtered[i, 0] + dy * filtered[i, 1] + dz * filtered[i, 2]
            m = lam * math.exp(-likelihood[i]) + (1.0 - lam) * math.exp(-feature[i])
            if not side > 0.0:
                m = -m
            step = m * math.sqrt(dx * dx + dy * dy + dz * dz)
            sx = step * filtered[i, 0]
            sy = step * filtered[i, 1]
            sz = step * filtered[i, 2]
            held[i] = not (abs(sx) + abs(sy) + abs(sz) < math.inf)
            if held[i]:
                sx = sy = sz = 0.0
            out[i, 0] = points[i, 0] + sx
            out[i, 1] = points[i, 1] + sy
            out[i, 2] = points[i, 2] + sz
