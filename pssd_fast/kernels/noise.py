"""What the noise probe reads at each sample point: the robust spread of its neighbours about a
local quadratic (docs/ALGORITHM.md, "The noise probe")."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .linalg import cholesky_prefix, cholesky_solve, normal_equations, set_sym3, sym3_eigh
from .mls import PIVOT_TOL, basis

#: Reweighted fits after the first, and the width of their weights in robust spreads.
REFITS = 2
WIDTH = 2.5
#: The spread of a unit Gaussian's median absolute value: ``1 / Phi^-1(3/4)``.
MAD_TO_SIGMA = 1.482602218505602


@helper
def median_abs(values, count, scratch):
    """The median of ``|values[:count]|`` (insertion sort into ``scratch``; the lists are
    short)."""
    for t in range(count):
        v = abs(values[t])
        s = t
        while s > 0 and scratch[s - 1] > v:
            scratch[s] = scratch[s - 1]
            s -= 1
        scratch[s] = v
    half = count // 2
    return scratch[half] if count % 2 == 1 else 0.5 * (scratch[half - 1] + scratch[half])


@helper
def _weighted_quadratic(phi, zs, wts, count, a, b, res):
    """The weighted least-squares quadratic (else plane, else mean height) of the heights
    ``zs`` over the monomials ``1, y, x, xy, y^2, x^2`` of each neighbour (the first rows of
    ``phi``'s columns), its residuals left in ``res``."""
    m = 0
    for top in (6, 3, 1):
        normal_equations(phi, wts, zs, count, top, a, b)
        if cholesky_prefix(a, top, PIVOT_TOL) == top:
            cholesky_solve(a, b, top)
            m = top
            break
    for t in range(count):
        g = 0.0
        for p in range(m):
            g += b[p] * phi[p, t]
        res[t] = zs[t] - g


@parallel_kernel
def local_noise(points, indices, lengths, scale, radius):
    """The robust residual spread of each point's nearest neighbours about their quadratic.

    Parameters
    ----------
    points : (n, 3) float64
    indices : (n, K) int
        Each point's ``K`` nearest points, itself first, nearest first.
    lengths : (c,) int64
        Prefix lengths of the lists to read, each at most ``K`` and at least 7.
    scale : (n, c) float64
        Output: for each prefix, ``MAD_TO_SIGMA`` times the median absolute residual of its
        points about a quadratic fitted in its PCA frame and reweighted ``REFITS`` times with
        ``exp(-(r / (WIDTH s))^2)``, ``s`` the previous fit's spread (0 where the prefix has no
        spread).
    radius : (n, c) float64
        Output: the prefix's radius, the distance from the point to its farthest member.

    Notes
    -----
    The frame: the prefix's centroid and covariance give the normal (smallest eigenvector) and
    the tangent axes; coordinates are relative to the point and divided by the radius. The
    fits take the quadratic where its normal equations pass the pivot test of
    :func:`pssd_fast.kernels.mls.mls_fit`, else the plane, else the mean height. A median
    rather than a mean keeps a neighbour across an edge or a thin wall from counting as noise.
    """
    n, longest = indices.shape
    for c in prange((n + CHUNK - 1) // CHUNK):
        phi = np.empty((10, longest))
        zs = np.empty(longest)
        wts = np.empty(longest)
        res = np.empty(longest)
        scratch = np.empty(longest)
        a = np.empty((6, 6))
        b = np.empty(6)
        cov = np.empty((3, 3))
        w = np.empty(3)
        v = np.empty((3, 3))
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            for col in range(lengths.shape[0]):
                count = lengths[col]
                cx = cy = cz = 0.0
                far = 0.0
                for t in range(count):
                    j = indices[i, t]
                    dx = points[j, 0] - px
                    dy = points[j, 1] - py
                    dz = points[j, 2] - pz
                    cx += dx
                    cy += dy
                    cz += dz
                    far = max(far, dx * dx + dy * dy + dz * dz)
                cx /= count
                cy /= count
                cz /= count
                c00 = c01 = c02 = c11 = c12 = c22 = 0.0
                for t in range(count):
                    j = indices[i, t]
                    dx = points[j, 0] - px - cx
                    dy = points[j, 1] - py - cy
                    dz = points[j, 2] - pz - cz
                    c00 += dx * dx
                    c01 += dx * dy
                    c02 += dx * dz
                    c11 += dy * dy
                    c12 += dy * dz
                    c22 += dz * dz
                set_sym3(cov, c00, c01, c02, c11, c12, c22)
                sym3_eigh(cov, w, v)
                r = math.sqrt(far)
                radius[i, col] = r
                inv_r = 1.0 / r if r > 0.0 else 0.0
                for t in range(count):
                    j = indices[i, t]
                    dx = points[j, 0] - px
                    dy = points[j, 1] - py
                    dz = points[j, 2] - pz
                    x = (dx * v[0, 2] + dy * v[1, 2] + dz * v[2, 2]) * inv_r
                    y = (dx * v[0, 1] + dy * v[1, 1] + dz * v[2, 1]) * inv_r
                    basis(x, y, phi, t)
                    zs[t] = dx * v[0, 0] + dy * v[1, 0] + dz * v[2, 0]
                    wts[t] = 1.0
                _weighted_quadratic(phi, zs, wts, count, a, b, res)
                s = MAD_TO_SIGMA * median_abs(res, count, scratch)
                for _ in range(REFITS):
                    if not s > 0.0:
                        break
                    for t in range(count):
                        u = res[t] / (WIDTH * s)
                        wts[t] = math.exp(-u * u)
                    _weighted_quadratic(phi, zs, wts, count, a, b, res)
                    s = MAD_TO_SIGMA * median_abs(res, count, scratch)
                scale[i, col] = s
