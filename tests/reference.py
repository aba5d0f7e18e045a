"""Slow, obvious implementations of every stage, written from docs/ALGORITHM.md.

Python loops over points, ``np.linalg.eigh`` and ``np.linalg.lstsq``, sets and deques: no attempt
at speed, so that each line can be checked against the text. The kernels must agree with these.
Neighbour lists are passed as a list of integer arrays (``lists[i]`` = ``N_k(i)``, self first).
"""
import math
from collections import deque

import numpy as np

# Decisions shared with the kernels (docs/ALGORITHM.md and docs/DECISIONS.md).
DEGENERATE_RATIO = 1e-12  # second covariance eigenvalue / largest below this: no plane
FIT_TOL = 1e-9  # smallest eigenvalue of the column-normalised Gram matrix below this: singular
# The robust fit of the feature-aware quadratic (docs/ALGORITHM.md, "One iteration", 4b).
ROBUST_SPREAD = 0.5  # Welsch spread, as a fraction of the plain fit's weighted RMS residual
ROBUST_MARGIN = 0.3  # the robust fit's Welsch score must beat the plain fit's by this fraction
REFITS = 4  # refits to the own residuals after the fit anchored at the point's height
ROBUST_SAMPLES = (18.0, 6.0)  # effective sample sizes for the quadratic and the plane
# The shifted normals of the first feature-aware iteration (docs/ALGORITHM.md, "Shifted normals").
SHIFT = {"candidates": 0.25, "tolerance": 2.0}  # candidates as a fraction of k; spreads


def morton_order(points):
    """Stable sort by interleaved 21-bit cell coordinates (x in bit 0 of each triple)."""
    low = points.min(axis=0)
    extent = float((points.max(axis=0) - low).max())
    scale = (2**21 - 1) / extent if extent > 0.0 else 0.0
    cells = ((points - low) * scale).astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for i in range(len(points)):
        for bit in range(21):
            for axis in range(3):
                if (int(cells[i, axis]) >> bit) & 1:
                    code[i] |= np.uint64(1) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def morton_code(cell):
    """Interleaved bits of integer cell coordinates ``(x, y, z)`` (x in bit 0 of each triple)."""
    code = 0
    for bit in range(21):
        for axis in range(3):
            code |= ((int(cell[axis]) >> bit) & 1) << (3 * bit + axis)
    return code


def knn_lists(points, k):
    """Brute-force k nearest neighbours (self included), sorted by distance, self first."""
    lists, dists = [], []
    for i in range(len(points)):
        d = np.sqrt(((points - points[i]) ** 2).sum(axis=1))
        # Sort by distance; among ties at distance 0 the point itself comes first.
        order = np.lexsort((np.arange(len(points)) != i, d))[:k]
        lists.append(order)
        dists.append(d[order])
    return lists, dists


def graph_lists(graph):
    """Split a CSR graph into per-point lists."""
    indptr, indices = graph[0], graph[1]
    return [indices[indptr[i]:indptr[i + 1]].astype(np.int64) for i in range(len(indptr) - 1)]


def pca_normal(points, members):
    """Smallest eigenvector of the covariance of ``points[members]`` about their centroid."""
    x = points[members]
    c = x - x.mean(axis=0)
    w, v = np.linalg.eigh(c.T @ c)
    return v[:, 0], w


def pca_normals(points, lists):
    return np.array([pca_normal(points, m)[0] for m in lists])


def _basis(n):
    """Any orthonormal pair perpendicular to n (the cubic fit does not depend on the choice)."""
    helper = np.eye(3)[np.argmin(np.abs(n))]
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _monomials(x, y):
    """Columns of eq. (1) in coefficient order a0..a9."""
    return np.stack([np.ones_like(x), y, x, x * y, y * y, x * x, x * y * y, x * x * y, y ** 3,
                     x ** 3], axis=1)


def _well_posed(design, weights):
    """Whether the weighted least-squares problem on ``design`` has a numerically full rank."""
    gram = design.T @ (weights[:, None] * design)
    diag = np.diag(gram)
    if (diag <= 0).any():
        return False
    scaled = gram / np.sqrt(np.outer(diag, diag))
    return np.linalg.eigvalsh(scaled).min() > FIT_TOL


def mls_point(points, normals, members, i, h):
    """MLS projection q_i, residual d_i and fitted degree of point i (docs/ALGORITHM.md step 1)."""
    rel = points[members] - points[i]
    theta = np.exp(-(rel ** 2).sum(axis=1) / h ** 2)
    centroid = (theta[:, None] * rel).sum(axis=0) / theta.sum()
    dev = rel - centroid
    w, v = np.linalg.eigh((theta[:, None] * dev).T @ dev)
    plane_normal = v[:, 0] if w[1] > DEGENERATE_RATIO * w[2] else normals[i].copy()
    if plane_normal @ normals[i] < 0:
        plane_normal = -plane_normal
    origin = (centroid @ plane_normal) * plane_normal
    u, v2 = _basis(plane_normal)
    radius = np.sqrt((rel ** 2).sum(axis=1)).max()
    scale = radius if radius > 0 else 1.0
    local = rel - origin
    x, y, z = local @ u / scale, local @ v2 / scale, local @ plane_normal
    design = _monomials(x, y)
    coef = np.zeros(10)
    degree = 0
    for m, deg in ((10, 3), (6, 2)):
        if _well_posed(design[:, :m], theta):
            sw = np.sqrt(theta)
            coef[:m] = np.linalg.lstsq(sw[:, None] * design[:, :m], sw * z, rcond=None)[0]
            degree = deg
            break
    q = points[i] + origin + coef[0] * plane_normal
    resid = (theta * np.abs(z - design @ coef)).sum() / theta.sum()
    # Mean curvature of z = g(x / s, y / s), sign flipped: positive bending away from the normal.
    gx, gy = coef[2] / scale, coef[1] / scale
    gxx, gyy, gxy = 2 * coef[5] / scale ** 2, 2 * coef[4] / scale ** 2, coef[3] / scale ** 2
    curvature = -((1 + gy ** 2) * gxx - 2 * gx * gy * gxy + (1 + gx ** 2) * gyy) / (
        2 * (1 + gx ** 2 + gy ** 2) ** 1.5)
    return q, resid, degree, curvature


def mls_fit(points, normals, lists, h):
    out = [mls_point(points, normals, m, i, h) for i, m in enumerate(lists)]
    return tuple(np.array([o[c] for o in out]) for c in range(4))


def frame_fit(origin, n, pts, nrms, sigma_n, mass=None, robust=False):
    """Weighted quadratic of ``pts`` in the frame of ``origin`` and axis ``n``: height at the
    origin, weighted RMS residual and number of coefficients fitted (docs/DECISIONS.md); with
    ``robust``, the robust fit where it explains the list better."""
    coef, _, rms, fitted = frame_coefficients(origin, n, pts, nrms, sigma_n, mass, robust)
    return coef[0], rms, fitted


def _frame(origin, n, pts, nrms, sigma_n, mass=None):
    """The listed points in the frame of ``origin`` and axis ``n``: tangent coordinates over
    the list radius, heights, the weights (distance, normal agreement, ``mass``) and that
    radius."""
    rel = pts - origin
    d2 = (rel ** 2).sum(axis=1)
    radius2 = d2.max()
    weights = np.exp(-d2 / radius2) if radius2 > 0 else np.ones(len(pts))
    if sigma_n > 0:
        agree = np.minimum(np.abs(nrms @ n), 1.0)
        weights = weights * np.exp(-((1 - agree) / sigma_n) ** 2)
    if mass is not None:
        weights = weights * mass
    u, v = _basis(n)
    scale = np.sqrt(radius2) if radius2 > 0 else 1.0
    return rel @ u / scale, rel @ v / scale, rel @ n, weights, scale


def frame_coefficients(origin, n, pts, nrms, sigma_n, mass=None, robust=False):
    """:func:`frame_fit`'s quadratic itself: its six coefficients (in the tangent coordinates
    of :func:`_basis` over the list radius), that radius, the RMS residual and the number of
    coefficients fitted."""
    x, y, z, weights, scale = _frame(origin, n, pts, nrms, sigma_n, mass)
    design = _monomials(x, y)[:, :6]
    coef, fitted = _solve(design, weights, z, 6)
    rms = _rms(weights, z - design @ coef)
    if robust and rms > 0:
        spread = ROBUST_SPREAD * rms
        origin = (x == 0) & (y == 0) & (z == 0)
        other, other_fitted = robust_fit(design, weights, z, spread, origin)
        if (_welsch(weights, z - design @ other, spread)
                > (1 + ROBUST_MARGIN) * _welsch(weights, z - design @ coef, spread)):
            coef, fitted = other, other_fitted
            rms = _rms(weights, z - design @ coef)
    return coef, scale, rms, fitted


def _solve(design, weights, z, top):
    """Weighted least squares on the first 6, 3 or 1 columns (at most ``top``): the first that
    is well posed; zeros and 0 when none is."""
    coef = np.zeros(6)
    for m in (6, 3, 1):
        if m <= top and _well_posed(design[:, :m], weights):
            sw = np.sqrt(weights)
            coef[:m] = np.linalg.lstsq(sw[:, None] * design[:, :m], sw * z, rcond=None)[0]
            return coef, m
    return coef, 0


def _rms(weights, resid):
    return np.sqrt((weights * resid ** 2).sum() / weights.sum())


def _welsch(weights, resid, spread):
    """The weight ``sum(w exp(-(r / spread)^2))`` a fit gathers from its close neighbours."""
    return (weights * np.exp(-(resid / spread) ** 2)).sum()


def _top(weights):
    """The most columns a reweighted fit may use, from Kish's effective sample size."""
    size = weights.sum() ** 2 / (weights ** 2).sum() if (weights ** 2).sum() > 0 else 0.0
    return 6 if size >= ROBUST_SAMPLES[0] else 3 if size >= ROBUST_SAMPLES[1] else 1


def robust_fit(design, weights, z, spread, origin):
    """The robust quadratic: a plane through the neighbours near the point's own height (the
    point itself, ``origin``, left out), then ``REFITS`` refits to its own residuals, each time
    with the weights times ``exp(-(r / spread)^2)``; coefficients and their number."""
    wts = np.where(origin, 0.0, weights * np.exp(-(z / spread) ** 2))
    coef, fitted = _solve(design, wts, z, min(3, _top(wts)))
    if fitted == 0:
        coef, fitted = _solve(design, weights, z, 3)
    for _ in range(REFITS):
        wts = weights * np.exp(-((z - design @ coef) / spread) ** 2)
        coef, fitted = _solve(design, wts, z, _top(wts))
    return coef, fitted


def on_fit(point, origin, n, coef, scale):
    """``point`` moved along ``n`` onto the quadratic ``coef`` of :func:`frame_coefficients`
    fitted in the frame of ``origin`` and ``n``."""
    u, v = _basis(n)
    rel = point - origin
    x, y, z = np.array([rel @ u / scale]), np.array([rel @ v / scale]), rel @ n
    return point + (_monomials(x, y)[0, :6] @ coef - z) * n


def aware_point(points, normals, members, i, sigma_n, mass=None, robust=False):
    """Feature-aware fit of point i over its list, in the frame of p_i and n_i; ``mass``
    multiplies each member's weight."""
    return frame_fit(points[i], normals[i], points[members], normals[members], sigma_n,
                     None if mass is None else mass[members], robust)


def aware_fit(points, normals, lists, sigma_n, mass=None, robust=False):
    out = [aware_point(points, normals, m, i, sigma_n, mass, robust)
           for i, m in enumerate(lists)]
    return tuple(np.array([o[c] for o in out]) for c in range(3))


def aware_iteration(points, normals, k, sigma_n=0.05, mass=None, shift=True):
    """One iteration of the feature-aware pipeline: PCA normals (oriented like ``normals``, or
    away from the centroid), on the first iteration (``normals`` None) shifted if ``shift``,
    bilateral filter, feature-aware fit (each neighbour's weight times its ``mass`` if given;
    without ``mass``, with its robust alternative), projection along n*_i."""
    lists, _ = knn_lists(points, k)
    nrm = pca_normals(points, lists)
    hints = points - points.mean(axis=0) if normals is None else normals
    nrm *= np.where((nrm * hints).sum(axis=1) < 0, -1.0, 1.0)[:, None]
    if normals is None and shift:
        nrm = shifted_normals(points, nrm, lists, max(1, round(SHIFT["candidates"] * k)),
                              SHIFT["tolerance"])[0]
    filtered = filter_normals(points, nrm, lists)
    height, _, _ = aware_fit(points, filtered, lists, sigma_n, mass, robust=mass is None)
    return points + height[:, None] * filtered, filtered


def list_plane(points, members):
    """Centroid, unit normal, surface variation (inf without a plane) and RMS distance to the
    plane of ``points[members]``."""
    x = points[members]
    centre = x.mean(axis=0)
    w, v = np.linalg.eigh((x - centre).T @ (x - centre))
    lowest = max(w[0], 0.0)
    planar = w[1] > DEGENERATE_RATIO * w[2] and lowest + w[1] + w[2] > 0
    variation = lowest / (lowest + w[1] + w[2]) if planar else math.inf
    return centre, v[:, 0], variation, math.sqrt(lowest / len(members))


def shifted_normals(points, normals, lists, candidates, tolerance):
    """Each point's normal from the flattest plane among the lists of its first ``candidates``
    neighbours that passes within ``tolerance`` RMS spreads of it (the first on a tie), signed
    like ``normals``; its own normal where none does. Also the index of the list taken (-1 for
    none) and, for the tests, whether that choice is clear of ties and of the tolerance's edge.
    """
    planes = [list_plane(points, members) for members in lists]
    out = np.array(normals, dtype=float)
    chosen = np.full(len(points), -1)
    clear = np.ones(len(points), bool)
    for i, members in enumerate(lists):
        least = math.inf
        qualified = []
        for j in members[:candidates]:
            centre, n, variation, spread = planes[j]
            if variation == math.inf:
                continue
            dist = abs((points[i] - centre) @ n)
            if abs(dist - tolerance * spread) <= 1e-9 * max(spread, 1e-300):
                clear[i] = False  # rounding decides whether it qualifies
            if dist <= tolerance * spread:
                qualified.append((variation, n))
                if variation < least:
                    least, chosen[i] = variation, j
        if chosen[i] >= 0:
            n = planes[chosen[i]][1]
            out[i] = -n if n @ normals[i] < 0 else n
            # A near-tie matters only between planes of different normals.
            if any(abs(other - least) <= 1e-9 * max(least, 1e-300) and abs(m @ n) < 1 - 1e-9
                   for other, m in qualified):
                clear[i] = False
    return out, chosen, clear


def likelihood(resid, form):
    """Eq. (2) as reconstructed in docs/ALGORITHM.md."""
    dbar = resid.mean()
    out = np.empty_like(resid)
    for i, d in enumerate(resid):
        if form == "residual":
            out[i] = d / dbar if dbar > 0 else 0.0
        elif dbar == 0:
            out[i] = 1.0
        elif form == "exp":
            out[i] = np.exp(-d / dbar)
        else:
            out[i] = min(dbar / d, 1.0) if d > 0 else 1.0
    return out


def region(points, lists, i, radius, n_vote=9):
    """N_R(i) by the growing process of Section 3, as a list in discovery order."""
    def near(j):
        return np.linalg.norm(points[j] - points[i]) <= radius

    members = [j for j in lists[i][:n_vote] if near(j)]
    seen = set(members)
    todo = deque(members)
    while todo:
        j = todo.popleft()
        for cand in lists[j][:n_vote]:
            if cand not in seen and near(cand):
                seen.add(cand)
                members.append(cand)
                todo.append(cand)
    return members


def feature_point(points, normals, members, i, delta, alpha, beta):
    """Feature intensity s_i of eq. (3) over the region ``members``."""
    dist = np.array([np.linalg.norm(points[j] - points[i]) for j in members])
    sigma = 2 * dist.max() / 3
    tensor = np.zeros((3, 3))
    total = np.zeros(3)
    for j, d in zip(members, dist):
        n = normals[j] if normals[j] @ normals[i] >= 0 else -normals[j]
        v = points[i] - points[j]
        w = np.cross(np.cross(v, n), v)
        if np.linalg.norm(w) > 0 and d > 0:
            w /= np.linalg.norm(w)
            voted = 2 * (n @ w) * w - n
        else:
            voted = n
        u = np.exp(-d / sigma) if sigma > 0 else 1.0
        tensor += u * np.outer(voted, voted)
        total += u * voted
    w, v = np.linalg.eigh(tensor)
    v3, v2, v1 = np.clip(w, 0, None)
    e1 = v[:, 2]
    nbar_len = np.linalg.norm(total)
    align = abs(total @ e1) / nbar_len if nbar_len > 0 else 0.0
    if align < delta:
        return 1.0
    if v3 > alpha * (v1 - v2) and v3 > beta * (v2 - v3):
        return 1.0
    return (v2 - v3) / v1


def feature_intensity(points, normals, lists, radius, delta=0.2, alpha=0.3, beta=0.3):
    s, sizes = [], []
    for i in range(len(points)):
        members = region(points, lists, i, radius)
        s.append(feature_point(points, normals, members, i, delta, alpha, beta))
        sizes.append(len(members))
    return np.array(s), np.array(sizes)


def filter_normals(points, normals, lists):
    """Eq. (4) with sigma_c = r_i / 2 and sigma_s = std of the deviation angles."""
    out = np.empty_like(normals)
    for i, members in enumerate(lists):
        flipped = np.array([normals[j] if normals[j] @ normals[i] >= 0 else -normals[j]
                            for j in members])
        dist = np.linalg.norm(points[members] - points[i], axis=1)
        angle = np.arccos(np.clip(flipped @ normals[i], -1, 1))
        sigma_c = dist.max() / 2
        sigma_s = angle.std()
        if sigma_s <= 1e-12:
            out[i] = normals[i]
            continue
        wc = np.exp(-dist ** 2 / (2 * sigma_c ** 2)) if sigma_c > 0 else np.ones(len(members))
        ws = np.exp(-angle ** 2 / (2 * sigma_s ** 2))
        total = ((wc * ws)[:, None] * flipped).sum(axis=0)
        out[i] = total / np.linalg.norm(total)
    return out


def bilateral_points(points, normals, lists, sigma_c=None, sigma_s=None):
    """The BIL baseline of docs/ALGORITHM.md: move along n_i by the bilateral mean height."""
    out = np.empty_like(points)
    for i, members in enumerate(lists):
        rel = points[members] - points[i]
        dist = np.linalg.norm(rel, axis=1)
        heights = rel @ normals[i]
        sc = dist.max() / 2 if sigma_c is None else sigma_c
        ss = heights.std() if sigma_s is None else sigma_s
        wc = np.exp(-dist ** 2 / (2 * sc ** 2)) if sc > 0 else np.ones(len(members))
        ws = np.exp(-heights ** 2 / (2 * ss ** 2)) if ss > 0 else np.ones(len(members))
        out[i] = points[i] + normals[i] * (wc * ws * heights).sum() / (wc * ws).sum()
    return out


def move_points(points, proj, filtered, lik, feat, lam):
    """Section 4.2: p* = p + (-1)^tau [lam e^-l + (1 - lam) e^-s] |q - p| n*."""
    out = np.empty_like(points)
    for i in range(len(points)):
        diff = proj[i] - points[i]
        tau = 0 if filtered[i] @ diff > 0 else 1
        m = (-1) ** tau * (lam * np.exp(-lik[i]) + (1 - lam) * np.exp(-feat[i]))
        out[i] = points[i] + m * np.linalg.norm(diff) * filtered[i]
    return out


def resort_lists(points, lists):
    """Each list's members sorted by their current distance (stable: self stays first)."""
    out, dists = [], []
    for i, members in enumerate(lists):
        d = np.sqrt(((points[members] - points[i]) ** 2).sum(axis=1))
        order = np.argsort(d, kind="stable")
        out.append(np.asarray(members)[order])
        dists.append(d[order])
    return out, dists


def robust_iteration(points, normals, k, lam=0.5, form="exp", radius_factor=10.0, lists=None):
    """One full iteration of the robust method with brute-force neighbours, or with the members
    of ``lists`` (from earlier positions) re-sorted by the current distances."""
    lists, dists = knn_lists(points, k) if lists is None else resort_lists(points, lists)
    if normals is None:
        normals = pca_normals(points, lists)
        hints = points - points.mean(axis=0)
        normals *= np.where((normals * hints).sum(axis=1) < 0, -1.0, 1.0)[:, None]
    h = np.mean([d[-1] for d in dists])
    proj, resid, _, _ = mls_fit(points, normals, lists, h)
    lik = likelihood(resid, form)
    spacing = np.mean([d[1] for d in dists])
    feat, _ = feature_intensity(points, normals, lists, radius_factor * spacing)
    filtered = filter_normals(points, normals, lists)
    return move_points(points, proj, filtered, lik, feat, lam), filtered, lik, feat


def propagate_orientation(normals, lists, limit):
    """Hoppe et al.'s orientation: Prim's minimum spanning tree over the undirected graph of
    the first ``limit`` list entries, weights ``1 - |n_i . n_j|``, each point flipped to agree
    with the point it is reached from. Lazy heap of ``(weight, point, parent)`` tuples (ties
    to the lower point, then the lower parent); components start at their lowest index.
    Returns the signed normals and the component of each point."""
    import heapq

    n = len(normals)
    nrm = [list(map(float, v)) for v in normals]
    edges = [[] for _ in range(n)]
    for i, members in enumerate(lists):
        for j in members[:limit]:
            if j != i:
                edges[i].append(int(j))
                edges[int(j)].append(i)
    component = [-1] * n
    count = 0
    for seed in range(n):
        if component[seed] >= 0:
            continue
        heap = [(0.0, seed, seed)]
        while heap:
            _, j, p = heapq.heappop(heap)
            if component[j] >= 0:
                continue
            component[j] = count
            if nrm[j][0] * nrm[p][0] + nrm[j][1] * nrm[p][1] + nrm[j][2] * nrm[p][2] < 0.0:
                nrm[j] = [-x for x in nrm[j]]
            for m in edges[j]:
                if component[m] < 0:
                    w = 1.0 - abs(nrm[j][0] * nrm[m][0] + nrm[j][1] * nrm[m][1]
                                  + nrm[j][2] * nrm[m][2])
                    heapq.heappush(heap, (w, m, j))
        count += 1
    return np.array(nrm), np.array(component)


def orient_components(points, normals, component, orient):
    """Each component flipped when the sum of ``n_i . d_i`` over it is negative (``d_i``:
    from the centroid, ``+z``, or towards the viewpoint)."""
    out = normals.copy()
    for c in set(component.tolist()):
        rows = component == c
        if isinstance(orient, str) and orient == "up":
            d = np.tile([0.0, 0.0, 1.0], (rows.sum(), 1))
        elif isinstance(orient, str):
            d = points[rows] - points.mean(axis=0)
        else:
            d = np.asarray(orient) - points[rows]
        if sum(float(a @ b) for a, b in zip(out[rows], d)) < 0.0:
            out[rows] = -out[rows]
    return out


def outlier_score(points, lists):
    """max(list radius / (2 median), offset from the plane of the other members /
    max(6 median, 3 times the median distance of those members to their plane)), medians over
    the cloud floored at 1e-9 of the bounding-box diagonal."""
    radius = np.array([np.linalg.norm(points[m[-1]] - points[i]) for i, m in enumerate(lists)])
    offsets, spreads = [], []
    for i, members in enumerate(lists):
        rest = points[members[1:]]
        centre = rest.mean(axis=0)
        w, v = np.linalg.eigh((rest - centre).T @ (rest - centre))
        offsets.append(abs((points[i] - centre) @ v[:, 0]))
        spreads.append(np.median(np.abs((rest - centre) @ v[:, 0])))
    offsets = np.array(offsets)
    floor = max(1e-9 * np.linalg.norm(points.max(axis=0) - points.min(axis=0)),
                np.finfo(float).tiny)
    return np.maximum(radius / (2.0 * max(np.median(radius), floor)),
                      offsets / np.maximum(6.0 * max(np.median(offsets), floor),
                                           3.0 * np.array(spreads)))


def cell_of(p, low, edge):
    """Integer grid coordinates of ``p``: ``floor((p - low) * (1 / edge))`` (the kernels
    multiply by the inverse edge)."""
    return tuple(np.floor((p - low) * (1.0 / edge)).astype(int))


def cell_means(points, normals, edge, low=None):
    """Mean point and mean normal (signs turned to the cell's first normal) of each grid cell
    (:func:`cell_of`, from ``low``, by default the points' lowest corner) and the rows it
    holds, keyed by the cell's integer coordinates."""
    cells = {}
    low = points.min(axis=0) if low is None else low
    for i, p in enumerate(points):
        cells.setdefault(cell_of(p, low, edge), []).append(i)
    out = {}
    for key, members in cells.items():
        mean = points[members].mean(axis=0)
        if normals is None:
            out[key] = (mean, None, np.array(members))
            continue
        first = normals[members[0]]
        turned = [normals[j] if normals[j] @ first >= 0 else -normals[j] for j in members]
        total = np.sum(turned, axis=0)
        norm = np.linalg.norm(total)
        out[key] = (mean, total / norm if norm > 0 else first, np.array(members))
    return out


def blended(point, targets, distance, origins, radius):
    """``point`` plus the mean of its steps to ``targets``, weighted by ``1 / distance``, of
    those steps within their fit's support: landing no farther than its list ``radius`` from
    the fit's origin (in ``origins``). Without any, the point stays."""
    steps = np.array(targets) - point
    keep = np.linalg.norm(np.array(targets) - origins, axis=1) <= radius
    if not keep.any():
        return point.copy()
    weights = 1.0 / np.maximum(distance[keep], 1e-300)
    return point + (weights[:, None] * steps[keep]).sum(axis=0) / weights.sum()


# Lists bounded by a radius (pssd_fast.graph.nearest_within, bounded_graph).
def nearest_within(data, queries, k, bound):
    """Each query's list: the points of ``data`` nearer than its ``k + 1``-th nearest (none of
    several tied at that distance: the set a tree returns does not depend on the tree) and
    nearer than ``bound`` (strictly, as pykdtree's bound), by distance, then index. A list of
    (indices, distances) pairs."""
    out = []
    for q in queries:
        d = np.sqrt(((data - q) ** 2).sum(axis=1))
        order = np.lexsort((np.arange(len(data)), d))
        cut = d[order[k]] if len(data) > k else np.inf
        keep = np.array([j for j in order if d[j] < cut and d[j] < bound], dtype=np.int64)
        out.append((keep, d[keep]))
    return out


# The noise probe (docs/ALGORITHM.md, "The noise probe"; pssd_fast.kernels.noise).
NOISE_REFITS = 2  # reweighted fits after the first
NOISE_WIDTH = 2.5  # the reweighting's width, in robust spreads
MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): a unit Gaussian's median |x| is 1 / this


PIVOT_TOL = 1e-9  # a Cholesky pivot fails at this fraction of its column's own weight


def _pivots(gram, tol=PIVOT_TOL):
    """How many leading pivots of the Cholesky factorisation of ``gram`` pass: each column's
    variance left after the earlier columns above ``tol`` times its own (kernels.linalg's
    test, which decides the noise probe's fallbacks)."""
    lower = np.zeros_like(gram)
    for col in range(len(gram)):
        left = gram[col, col] - lower[col, :col] @ lower[col, :col]
        if not left > tol * gram[col, col]:
            return col
        lower[col, col] = np.sqrt(left)
        for row in range(col + 1, len(gram)):
            lower[row, col] = (gram[row, col] - lower[row, :col] @ lower[col, :col]) / lower[
                col, col]
    return len(gram)


def _noise_residuals(design, weights, z):
    """Residuals of the weighted quadratic of the heights ``z`` (``design``'s six columns),
    else of the plane (three), else of the mean height, the first whose normal equations pass
    :func:`_pivots`; ``z`` itself where none does."""
    for m in (6, 3, 1):
        cols = design[:, :m]
        if _pivots(cols.T @ (weights[:, None] * cols)) == m:
            sw = np.sqrt(weights)
            return z - cols @ np.linalg.lstsq(sw[:, None] * cols, sw * z, rcond=None)[0]
    return z


def local_noise(points, lists, lengths):
    """For each point and each prefix length of its list (self first): the robust spread of
    the prefix's heights about their quadratic, and the prefix's radius (to its farthest
    member). The quadratic is fitted in the frame of the prefix's covariance (heights along
    its smallest eigenvector, tangent coordinates over the radius along the other two,
    relative to the point) by weighted least squares (the plane, else the mean height, where
    the quadratic's normal equations fail :func:`_pivots`); the spread is ``MAD_TO_SIGMA``
    times the median ``|residual|``, and the fit is repeated ``NOISE_REFITS`` times with
    weights ``exp(-(r / (NOISE_WIDTH s))^2)``, ``s`` the last spread, while that spread is
    above 0."""
    scale = np.zeros((len(points), len(lengths)))
    radius = np.zeros((len(points), len(lengths)))
    for i in range(len(points)):
        for c, m in enumerate(lengths):
            rel = points[np.asarray(lists[i])[:m]] - points[i]
            r = np.sqrt((rel ** 2).sum(axis=1).max())
            centred = rel - rel.mean(axis=0)
            _, v = np.linalg.eigh(centred.T @ centred)
            inv = 1.0 / r if r > 0 else 0.0
            design = _monomials(rel @ v[:, 2] * inv, rel @ v[:, 1] * inv)[:, :6]
            z = rel @ v[:, 0]
            weights = np.ones(m)
            resid = _noise_residuals(design, weights, z)
            s = MAD_TO_SIGMA * np.median(np.abs(resid))
            for _ in range(NOISE_REFITS):
                if not s > 0:
                    break
                weights = np.exp(-(resid / (NOISE_WIDTH * s)) ** 2)
                resid = _noise_residuals(design, weights, z)
                s = MAD_TO_SIGMA * np.median(np.abs(resid))
            scale[i, c], radius[i, c] = s, r
    return scale, radius


def noise_probe(points, lengths, table, min_ratio):
    """The noise probe on a cloud small enough to be read whole (``points``: its distinct
    positions): each point's ``max(lengths)`` nearest, :func:`local_noise` of every prefix in
    ``lengths``; for each length the median reading and the mean radius, read back to a noise
    through ``table`` (``{length: ((radius / sigma, reading / sigma), ...)}``, log-linear
    between rows, held at the ends) by bisection in ``log sigma``; the least noise among the
    lengths whose mean radius spans ``min_ratio`` of theirs (else the longest's), and the
    spacing ``mean radius of the longest * sqrt(pi / longest)``. Returns ``(sigma,
    spacing)``."""
    lists, _ = knn_lists(points, max(lengths))
    scale, radius = local_noise(points, lists, np.array(lengths))
    found = []
    for c, length in enumerate(lengths):
        read, mean_radius = float(np.median(scale[:, c])), float(np.mean(radius[:, c]))
        found.append((mean_radius, read_back(read, mean_radius, table[length])))
    usable = [sigma for r, sigma in found if r >= min_ratio * sigma]
    sigma = min(usable) if usable else found[-1][1]
    return sigma, found[-1][0] * math.sqrt(math.pi / lengths[-1])


def read_back(read, radius, table):
    """The noise ``sigma`` whose reading by lists of ``radius`` is ``read``: ``sigma f(radius /
    sigma) = read``, ``f`` the ``table`` (``((radius / sigma, reading / sigma), ...)``,
    log-linear between rows, held at the ends), by bisection in ``log sigma``."""
    xs = np.log([row[0] for row in table])
    fs = np.log([row[1] for row in table])
    lo, hi = math.log(read) - 1.0, math.log(read) + 10.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if mid + np.interp(math.log(radius) - mid, xs, fs) < math.log(read):
            lo = mid
        else:
            hi = mid
    return math.exp(0.5 * (lo + hi))


def own_variances(points, rows, k, bound):
    """What the own fit of each of ``points[rows]`` reads of the noise: its list
    (:func:`nearest_within`, ``k`` within ``bound``), the PCA normal of the list, the
    feature-aware quadratic with its robust alternative and no normal weight
    (:func:`frame_fit`, ``sigma_n`` 0), its squared height over ``1 - H``
    (:func:`own_leverage`)."""
    out = []
    for i, (members, _) in zip(rows, nearest_within(points, points[rows], k, bound)):
        pts = points[members]
        n = pca_normal(points, members)[0]
        height = frame_fit(points[i], n, pts, np.tile(n, (len(pts), 1)), 0.0, robust=True)[0]
        leverage = own_leverage(points[i], n, pts, np.tile(n, (len(pts), 1)), 0.0)
        out.append(height ** 2 / max(1.0 - leverage, np.finfo(float).eps))
    return np.array(out)


def own_sigma(points, rows, k, bound, radius, table):
    """The noise the own fits of ``points[rows]`` read: the root mean of their
    :func:`own_variances`, read back through ``table`` for lists of ``radius``
    (:func:`read_back`)."""
    return read_back(math.sqrt(own_variances(points, rows, k, bound).mean()), radius, table)


def method_plan(sigma, spacing, n, cell, radius, shortest, longest, reach, refine_radius,
                refine_k, span):
    """The default method's sizes from the noise and the spacing, as docs/ALGORITHM.md states
    them: the cell edge (the larger of ``cell[0]`` spacings and ``cell[1]`` noise widths); the
    means within ``radius`` noise widths, one per cell of the surface (``pi (radius sigma)^2``
    over the larger of the spacing and the edge, squared), at least ``shortest``, at most
    ``longest`` and ``n - 1``; their bound, ``reach`` radii of such a list; the refinement's
    points within ``refine_radius`` noise widths (over the spacing alone, at least
    ``refine_k``), their bound, and whether those lists span ``span`` noise widths."""
    edge = max(cell[0] * spacing, cell[1] * sigma)
    side = max(spacing, edge)
    k = min(max(shortest, min(longest, round(math.pi * (radius * sigma) ** 2 / side ** 2))),
            n - 1)
    k_r = min(max(refine_k, min(longest, round(math.pi * (refine_radius * sigma) ** 2
                                               / spacing ** 2))), n - 1)
    return {"cell_edge": edge, "k": k, "bound": reach * math.sqrt(k / math.pi) * side,
            "refine": {"k": k_r, "bound": reach * math.sqrt(k_r / math.pi) * spacing,
                       "own_noise": math.sqrt(k_r / math.pi) * spacing >= span * sigma}}


# The default method (pssd_fast.method): its iterations on the cell means, every point onto
# their fits, the test and the failing points' own fits.
def bounded_lists(points, k, bound, rows=None):
    """The lists of :func:`nearest_within` of ``points`` among themselves for ``rows`` (all by
    default), the point alone for the others."""
    lists = [np.array([i]) for i in range(len(points))]
    chosen = np.arange(len(points)) if rows is None else np.asarray(rows)
    for i, (members, _) in zip(chosen, nearest_within(points, points[chosen], k, bound)):
        lists[i] = members
    return lists


def _list_radius(points, lists):
    return np.array([np.linalg.norm(points[m] - points[i], axis=1).max()
                     for i, m in enumerate(lists)])


def _signed(normals, hints):
    return normals * np.where((normals * hints).sum(axis=1) < 0, -1.0, 1.0)[:, None]


def _supported(points, normals, height, radius):
    """Each point moved by ``height`` along its normal, held where that step is not finite or
    longer than its list's ``radius`` (docs/DECISIONS.md, "No point flung"); and the held."""
    held = ~(np.abs(height) <= radius) | ~np.isfinite(height)
    return points + np.where(held, 0.0, height)[:, None] * normals, held


def method_iterations(means, mass, k, bound, iterations, sigma_n=0.05, given=None,
                      keep=False):
    """The iterations on the cell means (weights times ``mass``, the points each stands for):
    lists of the ``k`` nearest means within ``bound``; the ``given`` normals in the first
    iteration (in every one with ``keep``), else PCA normals, away from the centroid and
    shifted in the first iteration, signed like the last filtered normals after it; the
    normal filter; the feature-aware quadratic (no robust alternative on means); the
    projection. Returns the means, the last iteration's origins (the means at its start), its
    lists and its filtered normals."""
    current, previous = np.array(means, dtype=float), None
    for iteration in range(iterations):
        lists = bounded_lists(current, k, bound)
        hints = current - current.mean(axis=0) if previous is None else previous
        if given is not None and (iteration == 0 or keep):
            nrm = np.array(given, dtype=float)
        else:
            nrm = _signed(pca_normals(current, lists), hints)
        if previous is None and given is None:
            nrm = shifted_normals(current, nrm, lists, max(1, round(SHIFT["candidates"] * k)),
                                  SHIFT["tolerance"])[0]
        filtered = filter_normals(current, nrm, lists)
        height, _, _ = aware_fit(current, filtered, lists, sigma_n, mass)
        moved, _ = _supported(current, filtered, height, _list_radius(current, lists))
        origins, current, previous = current, moved, filtered
    return current, origins, lists, previous


def method_project(points, origins, normals, lists, mass, bound, blend=3, sigma_n=0.05):
    """Each point moved onto the quadratics (:func:`frame_coefficients`, weights times
    ``mass``) of its ``blend`` nearest ``origins`` within ``bound`` (:func:`nearest_within`),
    blended (:func:`blended`); the normal of the nearest. Returns the points and normals."""
    fits = [frame_coefficients(origins[j], normals[j], origins[m], normals[m], sigma_n,
                               mass[m])[:2] for j, m in enumerate(lists)]
    moved, out_normals = np.empty_like(points), np.empty_like(points)
    for i, (near, distance) in enumerate(nearest_within(origins, points, blend, bound)):
        targets = [on_fit(points[i], origins[j], normals[j], *fits[j]) for j in near]
        moved[i] = blended(points[i], targets, distance, origins[near],
                           np.array([fits[j][1] for j in near]))
        out_normals[i] = normals[near[0]]
    return moved, out_normals


def method_failing(means, members, residual2, sigma, bound, cells=8, test=3.0, own=None,
                   test_own=2.0):
    """Whether each cell fails the test: over the points of the cell and of its ``cells - 1``
    nearest cells within ``bound`` (``members``: each cell's points; ``m`` the points), the sum
    of the squared residuals above ``m sigma^2 (1 + test sqrt(2 / m))``; or, with ``own`` (each
    point's noise variance and what its own fit leaves), above the sum of the first times
    ``1 + test_own sqrt(4 / m)`` plus the sum of the second."""
    out = []
    for near, _ in nearest_within(means, means, cells, bound):
        rows = np.concatenate([members[c] for c in near])
        m = len(rows)
        fails = residual2[rows].sum() > m * sigma ** 2 * (1 + test * np.sqrt(2 / m))
        if own is not None:
            noise2, spread2 = own
            fails |= residual2[rows].sum() > spread2[rows].sum() + noise2[rows].sum() * (
                1 + test_own * np.sqrt(4 / m))
        out.append(fails)
    return np.array(out)


def own_leverage(origin, n, pts, nrms, sigma_n):
    """The plain fit of :func:`frame_coefficients` (no robust alternative): the weight of the
    first listed point, the origin itself, in the fitted height, ``w_0 (X' W X)^-1_00`` over
    the columns fitted; 0 where the first point is not the origin or nothing was fitted."""
    if not (pts[0] == origin).all():
        return 0.0
    x, y, z, weights, _ = _frame(origin, n, pts, nrms, sigma_n)
    design = _monomials(x, y)[:, :6]
    _, fitted = _solve(design, weights, z, 6)
    if fitted == 0:
        return 0.0
    cols = design[:, :fitted]
    return weights[0] * np.linalg.inv(cols.T @ (weights[:, None] * cols))[0, 0]


def method_own_noise(points, hints, k, bound, sigma_n=0.05, reads=1.0):
    """Each point's noise by its own fit: lists of its ``k`` nearest within ``bound``, PCA
    normals signed along ``hints``, filtered; the squared height of its feature-aware quadratic
    (robust alternative included) over ``reads (1 - H)``, ``H`` the plain fit's leverage
    (:func:`own_leverage`); and that times ``H``."""
    lists = bounded_lists(points, k, bound)
    nrm = _signed(pca_normals(points, lists), hints)
    filtered = filter_normals(points, nrm, lists)
    height, _, _ = aware_fit(points, filtered, lists, sigma_n, robust=True)
    leverage = np.array([own_leverage(points[i], filtered[i], points[m], filtered[m], sigma_n)
                         for i, m in enumerate(lists)])
    noise2 = height ** 2 / (reads * (1 - leverage))
    return noise2, noise2 * leverage


def method_refine(start, normals, flagged, k, bound, iterations=2, sigma_n=0.05, given=None,
                  keep=False):
    """The flagged points' own iterations from ``start``: each over its ``k`` nearest points
    within ``bound`` (the others lend their positions and ``normals``); the ``given`` normals
    in the first iteration (in every one with ``keep``), else PCA normals signed like its last
    normal and shifted in the first iteration; the filter, the feature-aware quadratic with
    its robust alternative, the projection held beyond the list's radius. Returns the flagged
    points' positions, normals and whether they were held in some iteration."""
    points, normals = np.array(start, dtype=float), np.array(normals, dtype=float)
    rows = np.flatnonzero(flagged)
    held = np.zeros(len(points), bool)
    for iteration in range(iterations):
        lists = bounded_lists(points, k, bound, rows)
        nrm = normals.copy()
        if given is not None and (iteration == 0 or keep):
            nrm[rows] = given[rows]
        else:
            nrm[rows] = _signed(pca_normals(points, [lists[i] for i in rows]), normals[rows])
        if iteration == 0 and given is None:
            nrm[rows] = shifted_normals(points, nrm, lists, max(1, round(SHIFT["candidates"] * k)),
                                        SHIFT["tolerance"])[0][rows]
        filtered = filter_normals(points, nrm, lists)
        with np.errstate(divide="ignore", invalid="ignore"):  # the lists of one point
            height, _, _ = aware_fit(points, filtered, lists, sigma_n, robust=True)
        moved, held_now = _supported(points, filtered, height, _list_radius(points, lists))
        points[rows], normals[rows] = moved[rows], filtered[rows]
        held[rows] |= held_now[rows]
    return points[rows], normals[rows], held[rows]
