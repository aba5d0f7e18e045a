"""A scale per point: fits over nested prefixes of each list, and the walk that picks one
(docs/ALGORITHM.md, "A scale per point")."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .linalg import cholesky_prefix, cholesky_solve, orthonormal_basis

#: Monomials of the nested fits: the plane's 3, the quadratic's 6, the cubic's 10.
PLANE, QUADRATIC, CUBIC = 3, 6, 10
#: The lower quartile of ``|r|`` for a unit normal ``r``: a thin wall's spread is the lower
#: quartile of its residuals over this (the own side holds at least half of a list).
QUARTILE_OF_UNIT = 0.3186


@helper
def _nested(factor, rhs, b, szz, sw, m, rank):
    """Height at the origin and residual sum of squares of the fit of the first ``m``
    monomials, from the Cholesky ``factor`` of ``rank`` pivots; NaN where they are too few,
    or where the weights ``sw`` sum to less than ``m`` (fewer points than monomials in
    effect: the few neighbours whose normals agree would be fitted exactly)."""
    if rank < m or sw < m:
        return np.nan, np.nan
    for p in range(m):
        b[p] = rhs[p]
    cholesky_solve(factor, b, m)
    r = szz
    for p in range(m):
        r -= b[p] * rhs[p]
    return b[0], max(r, 0.0)


@helper
def _height_above(c, x, y, z):
    """``z`` less the quadratic ``c`` (monomials ``1, y, x, xy, y^2, x^2``) at ``(x, y)``."""
    return z - (c[0] + c[1] * y + c[2] * x + c[3] * x * y + c[4] * y * y + c[5] * x * x)


@parallel_kernel
def scale_fits(points, normals, indptr, indices, scales, sigma_n, k, coef, across, quad, plane,
               rss, rss_plane, rss_cubic, weight, radius, tapered):
    """Nested fits of each point's list at each scale (a prefix of its list).

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64
        Unit normals (the filtered ``n*_j``); only ``|n_i . n_j|`` is used.
    indptr, indices : CSR lists, nearest first, each starting with the point itself.
    scales : (S,) int64
        Increasing prefix lengths; a list shorter than a scale ends it.
    sigma_n : float
        Width of the normal-agreement weight ``exp(-((1 - |n_i . n_j|) / sigma_n)^2)``; each
        neighbour weighs that alone (flat in distance), so one pass over the longest list
        accumulates the normal equations of every scale.
    k : int
        The lists' length in the pipeline: a thin wall's spread is measured over this prefix.
    coef : (n, 7) float64
        The fit of :func:`pssd_fast.kernels.mls.aware_fit` at ``k`` (its ``coef``).
    across : (n,) bool
        Where that fit took its robust alternative (a list reaching across a thin wall): there
        each neighbour also weighs ``exp(-(r / s)^2)``, ``r`` its height above ``coef`` and
        ``s`` the lower quartile of ``|r|`` over the first ``k`` over ``QUARTILE_OF_UNIT``.
    quad, plane, rss, rss_plane, rss_cubic, weight, radius, tapered : (n, S) float64
        Output per scale: the heights at the origin of the quadratic and of the plane (NaN
        where the normal equations have too few pivots), the residual sums of squares of the
        quadratic, the plane and the cubic (10 monomials), the summed weight, the distance
        ``R`` to the last neighbour of the prefix, and the height of the quadratic whose
        weights also taper as ``1 - d^2 / R^2`` over the prefix (``d`` a neighbour's
        distance). A fit whose weights sum to less than its number of monomials is NaN too.

    Notes
    -----
    Frame: origin ``p_i``, axis the normal of its first listed point, tangent coordinates
    scaled by the whole list's radius. The three fits share one Cholesky factor of the cubic's
    normal equations (monomials ordered so that each fit is a leading block). The tapered
    fit's sums are the flat ones less sums weighted by ``d^2`` over ``R^2``, so it too needs
    one pass over the list.
    """
    inv_sn = 1.0 / sigma_n
    n_scales = scales.shape[0]
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        a = np.zeros((CUBIC, CUBIC))
        acc = np.zeros((CUBIC, CUBIC))
        bacc = np.zeros(CUBIC)
        b = np.zeros(CUBIC)
        phi = np.zeros(CUBIC)
        residual = np.zeros(max(k, 1))
        # Sums weighted by d^2 as well, for the tapered quadratic.
        a2 = np.zeros((QUADRATIC, QUADRATIC))
        acc2 = np.zeros((QUADRATIC, QUADRATIC))
        bacc2 = np.zeros(QUADRATIC)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            acc[:, :] = 0.0
            bacc[:] = 0.0
            acc2[:, :] = 0.0
            bacc2[:] = 0.0
            sw2 = 0.0
            start = indptr[i]
            count = indptr[i + 1] - start
            for s in range(n_scales):
                quad[i, s] = plane[i, s] = np.nan
                rss[i, s] = rss_plane[i, s] = rss_cubic[i, s] = np.nan
                weight[i, s] = radius[i, s] = 0.0
                tapered[i, s] = np.nan
            if count == 0:
                continue
            first = indices[start]
            nx, ny, nz = normals[first, 0], normals[first, 1], normals[first, 2]
            ux, uy, uz, vx, vy, vz = orthonormal_basis(nx, ny, nz)
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            r2 = 0.0
            for t in range(count):
                j = indices[start + t]
                r2 = max(r2, (points[j, 0] - px) ** 2 + (points[j, 1] - py) ** 2
                         + (points[j, 2] - pz) ** 2)
            inv_r = 1.0 / math.sqrt(r2) if r2 > 0.0 else 1.0
            inv_spread = 0.0
            if across[i]:
                m = min(k, count)
                cr = coef[i]
                for t in range(m):
                    j = indices[start + t]
                    dx, dy, dz = points[j, 0] - px, points[j, 1] - py, points[j, 2] - pz
                    residual[t] = abs(_height_above(cr, (dx * ux + dy * uy + dz * uz) * cr[6],
                                                    (dx * vx + dy * vy + dz * vz) * cr[6],
                                                    dx * nx + dy * ny + dz * nz))
                quartile = np.sort(residual[:m])[(m - 1) // 4]
                inv_spread = QUARTILE_OF_UNIT / quartile if quartile > 0.0 else 0.0
            szz = 0.0
            sw = 0.0
            s = 0
            for t in range(count):
                j = indices[start + t]
                dx, dy, dz = points[j, 0] - px, points[j, 1] - py, points[j, 2] - pz
                x = (dx * ux + dy * uy + dz * uz) * inv_r
                y = (dx * vx + dy * vy + dz * vz) * inv_r
                z = dx * nx + dy * ny + dz * nz
                u = (1.0 - min(abs(nx * normals[j, 0] + ny * normals[j, 1] + nz * normals[j, 2]),
                               1.0)) * inv_sn
                w = math.exp(-u * u)
                if inv_spread > 0.0:
                    cr = coef[i]
                    h = _height_above(cr, (dx * ux + dy * uy + dz * uz) * cr[6],
                                      (dx * vx + dy * vy + dz * vz) * cr[6], z) * inv_spread
                    w *= math.exp(-h * h)
                phi[0], phi[1], phi[2], phi[3], phi[4], phi[5] = 1.0, y, x, x * y, y * y, x * x
                phi[6], phi[7], phi[8], phi[9] = x * x * x, x * x * y, x * y * y, y * y * y
                for p in range(CUBIC):
                    bacc[p] += w * phi[p] * z
                    for q in range(p + 1):
                        acc[p, q] += w * phi[p] * phi[q]
                szz += w * z * z
                sw += w
                d2 = dx * dx + dy * dy + dz * dz
                wd2 = w * d2
                for p in range(QUADRATIC):
                    bacc2[p] += wd2 * phi[p] * z
                    for q in range(p + 1):
                        acc2[p, q] += wd2 * phi[p] * phi[q]
                sw2 += wd2
                while s < n_scales and (t + 1 == scales[s] or t + 1 == count):
                    a[:, :] = acc
                    rank = cholesky_prefix(a, CUBIC, 1e-9)
                    quad[i, s], rss[i, s] = _nested(a, bacc, b, szz, sw, QUADRATIC, rank)
                    rss_cubic[i, s] = _nested(a, bacc, b, szz, sw, CUBIC, rank)[1]
                    plane[i, s], rss_plane[i, s] = _nested(a, bacc, b, szz, sw, PLANE, rank)
                    weight[i, s] = sw
                    radius[i, s] = math.sqrt(d2)
                    inv_r2 = 1.0 / d2 if d2 > 0.0 else 0.0
                    for p in range(QUADRATIC):
                        b[p] = bacc[p] - bacc2[p] * inv_r2
                        for q in range(p + 1):
                            a2[p, q] = acc[p, q] - acc2[p, q] * inv_r2
                    if (cholesky_prefix(a2, QUADRATIC, 1e-9) == QUADRATIC
                            and sw - sw2 * inv_r2 >= QUADRATIC):
                        cholesky_solve(a2, b, QUADRATIC)
                        tapered[i, s] = b[0]
                    s += 1


@parallel_kernel
def walk_scales(quad, plane, rss, rss_plane, rss_cubic, weight, tapered, first, noise2, tau,
                tau_cubic, tau_plane, fallback, fallback_rms, height, rms, pick, flat):
    """Each point's scale, walking up from ``first``, and its height there.

    Parameters
    ----------
    quad, plane, rss, rss_plane, rss_cubic, weight, tapered : (n, S) float64
        The fits of :func:`scale_fits`.
    first : int
        The column the walks start from.
    noise2 : float
        The noise variance the tests compare with.
    tau, tau_cubic, tau_plane : float
        The tests' margins, in standard deviations of a chi-square mean.
    fallback, fallback_rms : (n,) float64
        The height and RMS residual of a point whose fit at its scale is not finite.
    height, rms : (n,) float64
        Output: the height above the point (the plane's, else the tapered quadratic's where
        it and the flat one are finite, else the flat one's), and the RMS residual of the
        (flat) quadratic there.
    pick : (n,) int64
        Output: the column kept. A scale is kept while the residual its ring adds per unit
        weight stays below ``noise2 (1 + tau sqrt(2 / added weight))`` and its four cubic
        terms explain no more than ``noise2 (1 + tau_cubic sqrt(2 / 4))`` each (NaN passes);
        the first scale that fails ends the walk.
    flat : (n,) bool
        Output: the plane replaced the quadratic, as its three curvature terms explain no more
        than ``noise2 (1 + tau_plane sqrt(2 / 3))`` each.
    """
    n, n_scales = quad.shape
    cubic_limit = 1.0 + tau_cubic * math.sqrt(2.0 / 4.0)
    plane_limit = 1.0 + tau_plane * math.sqrt(2.0 / 3.0)
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            kept = first
            if math.isfinite(quad[i, first]):
                for s in range(first + 1, n_scales):
                    added = max(weight[i, s] - weight[i, s - 1], 1e-9)
                    rate = (rss[i, s] - rss[i, s - 1]) / added / noise2
                    gain = (rss[i, s] - rss_cubic[i, s]) / 4.0 / noise2
                    if not (math.isfinite(quad[i, s]) and rate <= 1.0 + tau * math.sqrt(
                            2.0 / added)) or gain > cubic_limit:
                        break
                    kept = s
            pick[i] = kept
            curvature = (rss_plane[i, kept] - rss[i, kept]) / 3.0 / noise2
            flat[i] = math.isfinite(plane[i, kept]) and curvature <= plane_limit
            h = plane[i, kept] if flat[i] else quad[i, kept]
            if not flat[i] and math.isfinite(h) and math.isfinite(tapered[i, kept]):
                # The walk tested flat fits; the taper lowers the bias of the one kept.
                h = tapered[i, kept]
            if math.isfinite(h):
                height[i] = h
                rms[i] = math.sqrt(rss[i, kept] / max(weight[i, kept], 1.0))
            else:
                height[i], rms[i] = fallback[i], fallback_rms[i]
