"""MLS reference plane, weighted cubic fit, projection and residual (docs/ALGORITHM.md,
step 1)."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .graph import max_degree
from .linalg import (
    DEGENERATE_RATIO, cholesky_prefix, cholesky_solve, normal_equations, orthonormal_basis,
    set_sym3, sym3_eigh,
)

# A Cholesky pivot fails when less than this fraction of its column's weighted energy is left
# once the earlier basis functions are removed (the column is numerically dependent on them).
# This threshold is the only regularisation: a diagonal ridge, the first plan for this solve,
# lifts the pivot of a rank-deficient system above it whenever the null vector has little weight
# on the last column (seen with 9 distinct locations in a list of duplicates), so the singular
# cubic was accepted. See docs/DECISIONS.md ("Numerics") and docs/ALGORITHM.md step 1.
PIVOT_TOL = 1e-9

# Fit degree codes written to ``degree``.
CUBIC, QUADRATIC, PLANE = 3, 2, 0
# Thin walls (docs/DECISIONS.md, "Thin walls"): a list may reach across to the other side of a
# thin part, and its plain fit then lies between the two. A robust fit is tried beside it, with
# Welsch weights ``exp(-(r / s)^2)`` on the residuals ``r``, ``s`` this fraction of the plain
# fit's weighted RMS residual (the spread of the list as the plain fit sees it) ...
ROBUST_SPREAD = 0.5
# ... and kept where its Welsch score (the weights' sum) beats the plain fit's by this fraction:
# on one surface the plain fit already sits at the densest height, and a robust fit that merely
# follows the noise gains less.
ROBUST_MARGIN = 0.3
# Refits of the robust fit to its own residuals after the fit anchored at the point's height.
REFITS = 4
# Effective sample sizes a reweighted fit needs for the quadratic and the plane.
ROBUST_SAMPLES = (18.0, 6.0)


@helper
def basis(x, y, phi, t):
    """Monomials of eq. (1) at ``(x, y)`` in coefficient order a0..a9 into column ``t`` of
    ``phi`` (10, m); the first six span the quadratic."""
    phi[0, t] = 1.0
    phi[1, t] = y
    phi[2, t] = x
    phi[3, t] = x * y
    phi[4, t] = y * y
    phi[5, t] = x * x
    phi[6, t] = x * y * y
    phi[7, t] = x * x * y
    phi[8, t] = y * y * y
    phi[9, t] = x * x * x


@helper
def _residuals(phi, b, m, zs, count, out):
    """``out[t] = z_t - g(x_t, y_t)`` for the fit of the first ``m`` coefficients ``b``."""
    for t in range(count):
        out[t] = zs[t]
    for p in range(m):
        for t in range(count):
            out[t] -= b[p] * phi[p, t]


@helper
def _mean_curvature(b, inv_r):
    """Mean curvature of the graph z = g(x / r, y / r) of coefficients ``b`` at the origin,
    from its derivatives (world units), signed positive where the surface bends away from n
    (convex for outward n)."""
    gx = b[2] * inv_r
    gy = b[1] * inv_r
    gxx = 2.0 * b[5] * inv_r * inv_r
    gyy = 2.0 * b[4] * inv_r * inv_r
    gxy = b[3] * inv_r * inv_r
    slope2 = 1.0 + gx * gx + gy * gy
    return -((1.0 + gy * gy) * gxx - 2.0 * gx * gy * gxy + (1.0 + gx * gx) * gyy) / (
        2.0 * slope2 * math.sqrt(slope2))


@helper
def _fit_point(i, points, normals, indptr, indices, inv_h2, wts, xs, ys, zs, cov, w, v,
               a, b, phi, proj, resid, degree, curvature):
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    start = indptr[i]
    count = indptr[i + 1] - start

    # Gaussian weights and weighted centroid, relative to p_i.
    sw = cx = cy = cz = 0.0
    radius2 = 0.0
    for t in range(count):
        j = indices[start + t]
        dx = points[j, 0] - px
        dy = points[j, 1] - py
        dz = points[j, 2] - pz
        d2 = dx * dx + dy * dy + dz * dz
        radius2 = max(radius2, d2)
        th = math.exp(-d2 * inv_h2)
        wts[t] = th
        xs[t] = dx
        ys[t] = dy
        zs[t] = dz
        sw += th
        cx += th * dx
        cy += th * dy
        cz += th * dz
    cx /= sw
    cy /= sw
    cz /= sw

    # Reference plane H_i: smallest eigenvector of the weighted covariance about the centroid.
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0
    for t in range(count):
        dx = xs[t] - cx
        dy = ys[t] - cy
        dz = zs[t] - cz
        th = wts[t]
        c00 += th * dx * dx
        c01 += th * dx * dy
        c02 += th * dx * dz
        c11 += th * dy * dy
        c12 += th * dy * dz
        c22 += th * dz * dz
    set_sym3(cov, c00, c01, c02, c11, c12, c22)
    sym3_eigh(cov, w, v)
    if w[1] > DEGENERATE_RATIO * w[2]:
        nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
    else:  # collinear or coincident weights: no plane of its own, use the point's normal
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
    if nx * normals[i, 0] + ny * normals[i, 1] + nz * normals[i, 2] < 0.0:
        nx, ny, nz = -nx, -ny, -nz
    ux, uy, uz, vx, vy, vz = orthonormal_basis(nx, ny, nz)

    # Local frame: origin o_i = projection of p_i onto H_i; x, y scaled by the radius r_i.
    off = cx * nx + cy * ny + cz * nz
    ox, oy, oz = off * nx, off * ny, off * nz
    radius = math.sqrt(radius2)
    inv_r = 1.0 / radius if radius > 0.0 else 1.0
    for t in range(count):
        dx = xs[t] - ox
        dy = ys[t] - oy
        dz = zs[t] - oz
        x = (dx * ux + dy * uy + dz * uz) * inv_r
        y = (dx * vx + dy * vy + dz * vz) * inv_r
        zs[t] = dx * nx + dy * ny + dz * nz
        basis(x, y, phi, t)
    normal_equations(phi, wts, zs, count, 10, a, b)

    # Cubic if the whole system is well posed, else the quadratic, else the plane g = 0.
    rank = cholesky_prefix(a, 10, PIVOT_TOL)
    if rank == 10:
        m = 10
        degree[i] = CUBIC
    elif rank >= 6:
        m = 6
        degree[i] = QUADRATIC
    else:
        m = 0
        degree[i] = PLANE
    cholesky_solve(a, b, m)
    for p in range(m, 10):
        b[p] = 0.0

    curvature[i] = _mean_curvature(b, inv_r)

    # Projection q_i = o_i + g(0, 0) n and the weighted mean residual d_i.
    proj[i, 0] = px + ox + b[0] * nx
    proj[i, 1] = py + oy + b[0] * ny
    proj[i, 2] = pz + oz + b[0] * nz
    _residuals(phi, b, m, zs, count, xs)
    se = 0.0
    for t in range(count):
        se += wts[t] * abs(xs[t])
    resid[i] = se / sw


@parallel_kernel
def mls_fit(points, normals, indptr, indices, h, proj, resid, degree, curvature):
    """Project every point onto its local MLS cubic and measure the fit's residual.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64
        Unit normals; orient the reference planes and stand in for them when the weighted
        neighbourhood is collinear or coincident.
    indptr, indices : CSR neighbour graph (each list contains the point itself)
    h : float
        Gaussian kernel width, ``theta(d) = exp(-d^2 / h^2)``; must be positive.
    proj : (n, 3) float64
        Output: projection ``q_i = o_i + g(0, 0) n`` of each point onto its fitted surface.
    resid : (n,) float64
        Output: ``d_i``, the theta-weighted mean of ``|z_j - g(x_j, y_j)|`` over the list.
    degree : (n,) int8
        Output: 3 (cubic), 2 (quadratic fallback) or 0 (plane fallback, ``g = 0``).
    curvature : (n,) float64
        Output: mean curvature of the fitted surface at ``o_i``, from the derivatives of ``g``
        at the origin; positive where the surface bends away from the normal (a sphere with
        outward normals has ``1 / radius``); 0 for the plane fallback.

    Notes
    -----
    The reference plane is a one-step simplification of Alexa et al.'s non-linear search: the
    weighted centroid and the smallest eigenvector of the weighted covariance about it. The
    10x10 normal equations are factored once; since the first six monomials span the quadratic,
    the quadratic fallback reuses the leading 6x6 block of the same factor.
    """
    n = points.shape[0]
    longest = max_degree(indptr)
    inv_h2 = 1.0 / (h * h)
    for c in prange((n + CHUNK - 1) // CHUNK):
        wts = np.empty(longest)
        xs = np.empty(longest)
        ys = np.empty(longest)
        zs = np.empty(longest)
        cov = np.empty((3, 3))
        w = np.empty(3)
        v = np.empty((3, 3))
        a = np.empty((10, 10))
        b = np.empty(10)
        phi = np.empty((10, longest))
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            _fit_point(i, points, normals, indptr, indices, inv_h2, wts, xs, ys, zs, cov, w, v,
                       a, b, phi, proj, resid, degree, curvature)


@helper
def _solve(phi, wts, zs, count, top, a, b):
    """Weighted least-squares fit of the first ``top`` (6, 3 or 1) monomials into ``b``: the
    quadratic if well posed, else the plane, else the weighted mean height, else nothing;
    returns the number of coefficients fitted (``b`` is zero beyond them)."""
    normal_equations(phi, wts, zs, count, top, a, b)
    rank = cholesky_prefix(a, top, PIVOT_TOL)
    if rank == 6:
        m = 6
    elif rank >= 3:
        m = 3
    else:
        m = min(rank, 1)
    cholesky_solve(a, b, m)
    for p in range(m, 6):
        b[p] = 0.0
    return m


@helper
def _robust_top(wts, count):
    """The most monomials a reweighted fit may take: the quadratic where its weights amount to
    at least ``ROBUST_SAMPLES[0]`` equal ones (Kish's effective sample size), the plane from
    ``ROBUST_SAMPLES[1]``, else the mean height (a few lopsided neighbours would let a
    quadratic swing far off)."""
    s1 = 0.0
    s2 = 0.0
    for t in range(count):
        s1 += wts[t]
        s2 += wts[t] * wts[t]
    size = s1 * s1 / s2 if s2 > 0.0 else 0.0
    if size >= ROBUST_SAMPLES[0]:
        return 6
    return 3 if size >= ROBUST_SAMPLES[1] else 1


@helper
def _robust_fit(phi, base, zs, count, inv_spread, wts, xs, a, b):
    """The quadratic of a list that may hold another sheet: anchored at the origin's height (a
    plane; the origin itself left out, so that an outlier meets the neighbours nearest its
    height), then refitted ``REFITS`` times to its own residuals, each neighbour's weight
    ``base`` times ``exp(-(r * inv_spread)^2)`` (``wts`` is scratch). Leaves the coefficients
    in ``b``; returns their number."""
    for t in range(count):
        u = zs[t] * inv_spread
        origin = phi[1, t] == 0.0 and phi[2, t] == 0.0 and zs[t] == 0.0
        wts[t] = 0.0 if origin else base[t] * math.exp(-u * u)
    m = _solve(phi, wts, zs, count, min(3, _robust_top(wts, count)), a, b)
    if m == 0:
        m = _solve(phi, base, zs, count, 3, a, b)
    for _ in range(REFITS):
        _residuals(phi, b, m, zs, count, xs)
        for t in range(count):
            u = xs[t] * inv_spread
            wts[t] = base[t] * math.exp(-u * u)
        m = _solve(phi, wts, zs, count, _robust_top(wts, count), a, b)
    return m


@helper
def _frame_fit(px, py, pz, nx, ny, nz, points, normals, mass, indices, start, count,
               inv_sigma_n, robust, wts, base, xs, zs, a, b, other, phi):
    """Weighted quadratic over the listed ``points`` in the frame of origin ``(px, py, pz)`` and
    unit axis ``(nx, ny, nz)``: the height ``g(0, 0)``, the weighted RMS residual, the number
    of coefficients fitted (see :func:`aware_fit`), the inverse of the list radius that scales
    the tangent coordinates, and the plain fit's leverage on the origin where the list holds it
    first (:func:`_leverage`); ``b`` holds the coefficients. With ``robust``, the fit of
    :func:`_robust_fit` replaces the plain one where it explains the list better."""
    ux, uy, uz, vx, vy, vz = orthonormal_basis(nx, ny, nz)
    radius2 = 0.0
    for t in range(count):
        j = indices[start + t]
        dx = points[j, 0] - px
        dy = points[j, 1] - py
        dz = points[j, 2] - pz
        radius2 = max(radius2, dx * dx + dy * dy + dz * dz)
    inv_r = 1.0 / math.sqrt(radius2) if radius2 > 0.0 else 1.0
    inv_r2 = 1.0 / radius2 if radius2 > 0.0 else 0.0
    for t in range(count):
        j = indices[start + t]
        dx = points[j, 0] - px
        dy = points[j, 1] - py
        dz = points[j, 2] - pz
        x = (dx * ux + dy * uy + dz * uz) * inv_r
        y = (dx * vx + dy * vy + dz * vz) * inv_r
        z = dx * nx + dy * ny + dz * nz
        wgt = math.exp(-(dx * dx + dy * dy + dz * dz) * inv_r2)
        if inv_sigma_n > 0.0:
            u = (1.0 - min(abs(nx * normals[j, 0] + ny * normals[j, 1] + nz * normals[j, 2]),
                           1.0)) * inv_sigma_n
            wgt *= math.exp(-u * u)
        if mass.shape[0] > 0:
            wgt *= mass[j]
        zs[t] = z
        base[t] = wgt
        basis(x, y, phi, t)
    m = _solve(phi, base, zs, count, 6, a, b)
    leverage = _leverage(a, m, base, phi, zs, count, other)
    _residuals(phi, b, m, zs, count, xs)
    rms = _weighted_rms(base, xs, count)
    if robust and rms > 0.0:
        inv_spread = 1.0 / (ROBUST_SPREAD * rms)
        m_other = _robust_fit(phi, base, zs, count, inv_spread, wts, xs, a, other)
        plain = _welsch_score(phi, b, m, zs, count, base, inv_spread, xs)
        if _welsch_score(phi, other, m_other, zs, count, base, inv_spread, xs) > (
                1.0 + ROBUST_MARGIN) * plain:
            m = m_other
            for p in range(6):
                b[p] = other[p]
            rms = _weighted_rms(base, xs, count)  # xs: the residuals about ``other``
    return b[0], rms, m, inv_r, leverage


@helper
def _leverage(lower, m, base, phi, zs, count, y):
    """The weight of the list's first entry in its own fitted height, ``H_00 = w_0 (A^-1)_00``
    (``lower``: the factor of the fit's ``m`` coefficients), where that entry is the origin
    itself; else 0. The residual of the origin about the fit has ``1 - H_00`` of its noise's
    variance. ``y`` is scratch (6)."""
    if m == 0 or count == 0 or phi[1, 0] != 0.0 or phi[2, 0] != 0.0 or zs[0] != 0.0:
        return 0.0
    # (A^-1)_00 = |L^-1 e0|^2: forward substitution of e0.
    total = 0.0
    for k in range(m):
        s = 1.0 if k == 0 else 0.0
        for j in range(k):
            s -= lower[k, j] * y[j]
        y[k] = s / lower[k, k]
        total += y[k] * y[k]
    return base[0] * total


@helper
def _welsch_score(phi, b, m, zs, count, base, inv_spread, xs):
    """``sum(base * exp(-(r * inv_spread)^2))`` over the residuals ``r`` about the fit ``b`` (left
    in ``xs``): the weight a fit gathers from the neighbours close to it."""
    _residuals(phi, b, m, zs, count, xs)
    s = 0.0
    for t in range(count):
        u = xs[t] * inv_spread
        s += base[t] * math.exp(-u * u)
    return s


@helper
def _weighted_rms(wts, xs, count):
    """Weighted RMS of the residuals ``xs``."""
    se = 0.0
    sw = 0.0
    for t in range(count):
        se += wts[t] * xs[t] * xs[t]
        sw += wts[t]
    return math.sqrt(se / sw) if sw > 0.0 else 0.0


@parallel_kernel
def aware_fit(points, surface, normals, mass, indptr, indices, sigma_n, robust, height, rms,
              degree, coef, leverage):
    """Feature-aware local quadratic of each point's listed ``surface`` points, in the frame of
    the point and the normal of its first (nearest) listed one: the iterations of the default
    method on its cell means and on the points it refines (``surface`` is ``points``, each list
    starting with the point itself, so the frame is ``p_i`` and ``n_i``; docs/ALGORITHM.md,
    "One iteration").

    Parameters
    ----------
    points : (n, 3) float64
        Where to fit: the origin of each frame.
    surface : (m, 3) float64
        The points fitted.
    normals : (m, 3) float64
        Unit normals of ``surface`` (the filtered normals ``n*_j``); only ``|n_i . n_j|`` is
        used, so signs need not agree.
    mass : (m,) float64 or (0,)
        A factor on each surface point's weight (the number of input points a cell mean stands
        for); no entries: every factor is 1.
    indptr, indices : CSR lists of ``surface`` rows for each of ``points``, nearest first
    sigma_n : float
        Width of the normal-agreement weight ``exp(-((1 - |n_i . n_j|) / sigma_n)^2)``; 0 or
        less turns it off (weights by distance only).
    robust : bool
        Also try the robust fit of :func:`_robust_fit` at each point and keep it where its
        Welsch score beats the plain fit's by ``ROBUST_MARGIN`` (thin walls).
    height : (n,) float64
        Output: ``g(0, 0)``, the height of the fitted surface above ``p_i`` along the frame's
        axis ``n``, so that ``p_i + height_i n`` is the projection of ``p_i`` along it (0 for an
        empty list).
    rms : (n,) float64
        Output: weighted root-mean-square residual of the list about the fit.
    degree : (n,) int8
        Output: number of coefficients fitted: 6 (quadratic), 3 (plane fallback), 1 (weighted
        mean height) or 0 (no fit, ``height = 0``).
    coef : (n, 7) float64 or (0, 7)
        Output, if it has rows: the six coefficients of ``g`` (monomials ``1, y, x, xy, y^2,
        x^2``; those not fitted are 0) and ``1 / r_i``, for :func:`evaluate_fits`.
    leverage : (n,) float64 or (0,)
        Output, if it has entries: the plain fit's leverage on the point, where its list holds
        it first (:func:`_leverage`), else 0.

    Notes
    -----
    Frame: origin ``p_i``, axis ``n``, tangent coordinates scaled by the list radius ``r_i``.
    Weights: ``exp(-|p_j - p_i|^2 / r_i^2)`` times the normal-agreement weight (times
    ``mass[j]``); a point listed in its own list counts with weight 1 (``mass[i]``). Neighbours
    whose normal disagrees with ``n`` (the other side of a crease) hardly count, so points near
    a sharp edge are fitted to their own face. The quadratic's normal equations are factored
    with the same pivot test as :func:`mls_fit`; a leading block that fails falls back to the
    plane (first three monomials), then to the weighted mean height.
    """
    n = points.shape[0]
    longest = max_degree(indptr)
    inv_sigma_n = 1.0 / sigma_n if sigma_n > 0.0 else 0.0
    for c in prange((n + CHUNK - 1) // CHUNK):
        wts = np.empty(longest)
        base = np.empty(longest)
        other = np.empty(6)
        xs = np.empty(longest)
        zs = np.empty(longest)
        a = np.empty((6, 6))
        b = np.empty(6)
        phi = np.empty((10, longest))
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            start = indptr[i]
            count = indptr[i + 1] - start
            if count == 0:
                height[i], rms[i], degree[i] = 0.0, 0.0, 0
                if coef.shape[0] > 0:
                    coef[i, :] = 0.0
                if leverage.shape[0] > 0:
                    leverage[i] = 0.0
                continue
            first = indices[start]
            height[i], rms[i], degree[i], inv_r, own = _frame_fit(
                points[i, 0], points[i, 1], points[i, 2], normals[first, 0],
                normals[first, 1], normals[first, 2], surface, normals, mass, indices, start,
                count, inv_sigma_n, robust, wts, base, xs, zs, a, b, other, phi)
            if coef.shape[0] > 0:
                coef[i, :6] = b
                coef[i, 6] = inv_r
            if leverage.shape[0] > 0:
                leverage[i] = own


@parallel_kernel
def evaluate_fits(points, origins, normals, coef, nearest, distance, moved, held):
    """Move each point onto the fitted surfaces of its nearest origins, along their axes, by the
    inverse-distance-weighted mean of those steps.

    Parameters
    ----------
    points : (n, 3) float64
    origins : (m, 3) float64
        Frame origins of the fits of :func:`aware_fit` (its ``points``).
    normals : (m, 3) float64
        Unit axes of those frames.
    coef : (m, 7) float64
        The fits' coefficients and inverse list radii (``coef`` of :func:`aware_fit`); a fit of
        no coefficients is the plane through its origin.
    nearest : (n, b) int64
        Rows of ``origins`` whose fits each point moves onto; a row past ``origins``' is
        none.
    distance : (n, b) float64
        Distance from the point to each of those origins; the weight of a fit is its inverse.
    moved : (n, 3) float64
        Output: ``p_i`` plus the weighted mean of the steps ``(g_j(x, y) - z) n_j``, with
        ``(x, y, z)`` the point in the frame of origin ``j``. A fit is used only within its
        support: steps that are not finite, or that land the point farther than the fit's
        list radius ``r_j`` from its origin (outside the ball its list covers), are left out.
    held : (n,) bool
        Output: whether no step was left, so that the point stayed where it was.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            sx = 0.0
            sy = 0.0
            sz = 0.0
            sw = 0.0
            for t in range(nearest.shape[1]):
                j = nearest[i, t]
                if j >= origins.shape[0]:
                    continue  # none found there (beyond the query's bound)
                nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
                ux, uy, uz, vx, vy, vz = orthonormal_basis(nx, ny, nz)
                dx = points[i, 0] - origins[j, 0]
                dy = points[i, 1] - origins[j, 1]
                dz = points[i, 2] - origins[j, 2]
                x = (dx * ux + dy * uy + dz * uz) * coef[j, 6]
                y = (dx * vx + dy * vy + dz * vz) * coef[j, 6]
                z = dx * nx + dy * ny + dz * nz
                step = (coef[j, 0] + coef[j, 1] * y + coef[j, 2] * x + coef[j, 3] * x * y
                        + coef[j, 4] * y * y + coef[j, 5] * x * x - z)
                # A fit describes the ball of its own list: a step that lands outside it
                # (read past the list, or swinging out of it) has no support.
                height = (step + z) * coef[j, 6]
                if not x * x + y * y + height * height <= 1.0:
                    continue
                if not (math.isfinite(step * nx) and math.isfinite(step * ny)
                        and math.isfinite(step * nz)):
                    continue
                w = 1.0 / max(distance[i, t], 1e-300)
                sx += w * step * nx
                sy += w * step * ny
                sz += w * step * nz
                sw += w
            held[i] = not sw > 0.0
            if held[i]:
                sw = 1.0
            moved[i, 0] = points[i, 0] + sx / sw
            moved[i, 1] = points[i, 1] + sy / sw
            moved[i, 2] = points[i, 2] + sz / sw
