"""Each kernel against its reference in tests/reference.py, on random and degenerate clouds."""
import math

import numpy as np
import pytest

import pssd_fast
from pssd_fast import core
from pssd_fast.kernels import feature, normals

from . import reference
from .conftest import block_regions, plane, sphere, wavy


def _setup(points, k):
    graph = pssd_fast.neighbors(points, k)
    return graph, reference.graph_lists(graph)


def _pca_reference(points, lists):
    nrm = reference.pca_normals(points, lists)
    hints = points - points.mean(axis=0)
    return nrm * np.where((nrm * hints).sum(axis=1) < 0, -1.0, 1.0)[:, None]


def _well_defined_normals(points, lists):
    """Points whose PCA normal is unique (a clear smallest eigenvalue)."""
    gaps = []
    for m in lists:
        w = reference.pca_normal(points, m)[1]
        gaps.append(w[1] - w[0] > 1e-6 * max(w[2], 1e-300))
    return np.array(gaps)


def test_pca_normals(cloud):
    name, points, k = cloud
    graph, lists = _setup(points, k)
    got = pssd_fast.estimate_normals(points, graph=graph)
    ref = _pca_reference(points, lists)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-12)
    ok = _well_defined_normals(points, lists)
    if name == "collinear":
        assert not ok.any()
        # No plane: any unit normal perpendicular to the line will do.
        np.testing.assert_allclose(got @ np.array([1, 2, -1]) / np.sqrt(6), 0, atol=1e-12)
        return
    assert ok.mean() > 0.9
    np.testing.assert_allclose(got[ok], ref[ok], atol=1e-9)


def test_pca_normals_flag_degenerate_lists():
    points = np.repeat(np.eye(3), 12, axis=0)  # 3 locations, 12 copies each
    graph = pssd_fast.neighbors(points, 11)
    out = np.empty_like(points)
    flags = np.empty(len(points), bool)
    normals.pca_normals(points, graph.indptr, graph.indices, points, out, flags)
    assert flags.all()
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)


def test_shifted_normals(cloud):
    """Against the loops of the reference, on every test cloud; the candidates are a third of
    each list so that the shift happens often."""
    name, points, k = cloud
    graph, lists = _setup(points, k)
    hints = _pca_reference(points, lists)
    planes = core.list_planes(points, graph, hints)
    got = core.shifted_normals(points, hints, graph, planes, k // 3, 2.0)
    ref, chosen, clear = reference.shifted_normals(points, hints, lists, k // 3, 2.0)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-12)
    if name == "collinear":  # no list has a plane: every point keeps its own normal
        assert (chosen == -1).all()
        np.testing.assert_array_equal(got, hints)
        return
    if name == "plane":  # every plane is z = 0: which list wins is a tie of rounding errors
        np.testing.assert_allclose(np.abs(got[:, 2]), 1.0, atol=1e-12)
        np.testing.assert_allclose(np.sign(got[:, 2]), np.sign(hints[:, 2]))
        return
    shifted = chosen != np.arange(len(points))
    assert shifted.any() and (chosen >= 0).any()
    # Where the winner is clear of ties and its own normal is unique, the kernel agrees.
    ok = clear & _well_defined_normals(points, lists)[np.maximum(chosen, 0)]
    assert ok.mean() > 0.8
    np.testing.assert_allclose(got[ok], ref[ok], atol=1e-9)


def test_list_planes_give_the_pca_normals(cloud):
    """The shifted normals' PCA pass also serves as the iteration's PCA normals."""
    _, points, k = cloud
    graph = pssd_fast.neighbors(points, k)
    hints = core.outward_hints(points)
    planes = core.list_planes(points, graph, hints)
    nrm, degenerate = core.pca_normals(points, graph, hints)
    np.testing.assert_array_equal(planes.normals, nrm)
    np.testing.assert_array_equal(planes.degenerate, degenerate)


def test_list_planes_of_degenerate_lists_have_no_variation():
    points = np.repeat(np.eye(3), 12, axis=0)  # 3 locations, 12 copies each
    graph = pssd_fast.neighbors(points, 11)
    centres, out = np.empty_like(points), np.empty_like(points)
    variation, spread = np.empty(len(points)), np.empty(len(points))
    normals.list_planes(points, graph.indptr, graph.indices, points, centres, out, variation,
                        spread)
    assert np.isinf(variation).all()
    np.testing.assert_array_equal(spread, 0.0)
    np.testing.assert_array_equal(centres, 0.0)


def test_shifted_normals_take_each_side_of_a_crease():
    """A noisy 90-degree fold: beside the crease, PCA over lists that reach across it tilts the
    normals; the shifted ones come from lists on one face."""
    rng = np.random.default_rng(5)
    u, v = rng.uniform(-1, 1, (2, 4000))
    points = np.column_stack([np.minimum(u, 0), v, np.maximum(u, 0)])
    points += rng.normal(0, 0.005, points.shape)
    truth = np.where((u < 0)[:, None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    graph = pssd_fast.neighbors(points, 40)
    pca = pssd_fast.estimate_normals(points, graph=graph)
    shifted = core.shifted_normals(points, pca, graph, core.list_planes(points, graph, pca), 10,
                                   2.0)

    def error(nrm):
        return np.degrees(np.arccos(np.minimum(np.abs((nrm * truth).sum(axis=1)), 1.0)))

    beside = (np.abs(u) > 0.03) & (np.abs(u) < 0.1)
    assert error(pca)[beside].mean() > 10.0
    assert error(shifted)[beside].mean() < 0.5 * error(pca)[beside].mean()
    far = np.abs(u) > 0.3
    assert error(shifted)[far].mean() < 2.0


def _mean_kth_distance(points, k):
    """Brute force: the mean over points of the distance to the farthest of their ``k`` nearest
    points (the point itself included), from all pairwise distances."""
    d = np.sqrt(((points[:, None, :] - points[None, :, :]) ** 2).sum(axis=2))
    return float(np.sort(d, axis=1)[:, k - 1].mean())


def _normals_for(name, points, lists):
    """Normals the MLS and feature stages are fed: exact ones where PCA has none."""
    if name == "collinear":
        return np.tile([0.0, 0.0, 1.0], (len(points), 1))
    return _pca_reference(points, lists)


def test_mls_fit(cloud):
    name, points, k = cloud
    graph, lists = _setup(points, k)
    nrm = _normals_for(name, points, lists)
    h = _mean_kth_distance(points, k)  # the documented default
    fit = pssd_fast.mls_fit(points, nrm, graph=graph)
    proj, resid, degree, curvature = reference.mls_fit(points, nrm, lists, h)
    assert fit.h == pytest.approx(h, rel=1e-12)
    assert pssd_fast.mls_fit(points, nrm, k=k).h == pytest.approx(h, rel=1e-12)
    np.testing.assert_array_equal(fit.degree, degree)
    # Curvature has units 1/length: compare relative to the largest magnitude.
    np.testing.assert_allclose(fit.curvature, curvature,
                               atol=1e-7 * max(np.abs(curvature).max(), 1.0))
    scale = np.ptp(points, axis=0).max()
    np.testing.assert_allclose(fit.projections, proj, atol=1e-9 * scale, rtol=0)
    np.testing.assert_allclose(fit.residuals, resid, atol=1e-9 * scale, rtol=0)
    expected_degree = {"collinear": 0, "duplicates": 2, "tiny": 3}.get(name)
    if expected_degree is not None:
        assert (degree == expected_degree).all()
    if name == "plane":
        np.testing.assert_allclose(fit.residuals, 0, atol=1e-15)
        np.testing.assert_allclose(fit.projections[:, 2], 0, atol=1e-15)


def test_mls_fit_uses_the_given_h():
    points = wavy(300, noise=0.01, seed=24)
    graph, lists = _setup(points, 20)
    nrm = _pca_reference(points, lists)
    default = pssd_fast.mls_fit(points, nrm, graph=graph)
    for h in (0.4 * default.h, 3.0 * default.h):
        fit = pssd_fast.mls_fit(points, nrm, h=h, graph=graph)
        assert fit.h == h
        proj, resid, _, _ = reference.mls_fit(points, nrm, lists, h)
        np.testing.assert_allclose(fit.projections, proj, atol=1e-9, rtol=0)
        np.testing.assert_allclose(fit.residuals, resid, atol=1e-9, rtol=0)
        # A different width gives visibly different projections (noise 0.01).
        assert np.abs(fit.projections - default.projections).max() > 1e-3
        lik = pssd_fast.sampling_likelihood(points, nrm, h=h, graph=graph)
        np.testing.assert_allclose(lik, reference.likelihood(resid, "exp"), atol=1e-7, rtol=0)


@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("sigma_n", [0.0, 0.05, 0.5])
def test_aware_fit(cloud, sigma_n, weighted):
    name, points, k = cloud
    graph, lists = _setup(points, k)
    nrm = _normals_for(name, points, lists)
    mass = np.random.default_rng(9).integers(1, 40, len(points)).astype(float) if weighted \
        else None
    height, rms, degree = core.aware_fit(points, nrm, graph, sigma_n, mass)
    ref_height, ref_rms, ref_degree = reference.aware_fit(points, nrm, lists, sigma_n, mass)
    np.testing.assert_array_equal(degree, ref_degree)
    scale = np.ptp(points, axis=0).max()
    np.testing.assert_allclose(height, ref_height, atol=1e-9 * scale, rtol=0)
    np.testing.assert_allclose(rms, ref_rms, atol=1e-9 * scale, rtol=0)
    expected_degree = {"collinear": 1, "duplicates": 6, "tiny": 6}.get(name)
    if expected_degree is not None and sigma_n == 0.0:
        assert (degree == expected_degree).all()
    if name == "plane":
        np.testing.assert_allclose(height, 0, atol=1e-15)
        np.testing.assert_allclose(rms, 0, atol=1e-15)


@pytest.mark.parametrize("sigma_n", [0.0, 0.05])
def test_own_fits_leverage(cloud, sigma_n):
    """The plain fit's leverage on each point (its list holds it first) against the
    reference, degenerate clouds included; the heights are those of the robust fit."""
    name, points, k = cloud
    graph, lists = _setup(points, k)
    nrm = _normals_for(name, points, lists)
    height, rms, degree, leverage = core.own_fits(points, nrm, graph, sigma_n)
    ref = reference.aware_fit(points, nrm, lists, sigma_n, robust=True)
    np.testing.assert_array_equal(degree, ref[2])
    scale = np.ptp(points, axis=0).max()
    np.testing.assert_allclose(height, ref[0], atol=1e-9 * scale, rtol=0)
    want = [reference.own_leverage(points[i], nrm[i], points[m], nrm[m], sigma_n)
            for i, m in enumerate(lists)]
    np.testing.assert_allclose(leverage, want, atol=1e-9, rtol=1e-7)
    assert ((leverage >= 0) & (leverage <= 1 + 1e-9)).all()


def two_sheets(n=200, gap=4.0, sigma=0.01, seed=6):
    """Two noisy parallel unit squares ``gap`` noise deviations apart, their normals (+z) and
    each point's own sheet height."""
    rng = np.random.default_rng(seed)
    own = np.repeat([0.0, gap * sigma], n)
    points = np.column_stack([rng.uniform(0, 1, (2 * n, 2)), own + rng.normal(0, sigma, 2 * n)])
    return points, np.tile([0.0, 0.0, 1.0], (2 * n, 1)), own


@pytest.mark.parametrize("sigma_n", [0.0, 0.05])
def test_robust_aware_fit(cloud, sigma_n):
    """The robust fit (thin walls) against the reference on every cloud, degenerate ones
    included."""
    name, points, k = cloud
    graph, lists = _setup(points, k)
    nrm = _normals_for(name, points, lists)
    height, rms, degree = core.aware_fit(points, nrm, graph, sigma_n, robust=True)
    ref = reference.aware_fit(points, nrm, lists, sigma_n, robust=True)
    np.testing.assert_array_equal(degree, ref[2])
    scale = np.ptp(points, axis=0).max()
    np.testing.assert_allclose(height, ref[0], atol=1e-9 * scale, rtol=0)
    np.testing.assert_allclose(rms, ref[1], atol=1e-9 * scale, rtol=0)


@pytest.mark.parametrize("gap", [4.0, 7.5])
def test_robust_aware_fit_keeps_two_sheets_apart(gap):
    """Lists that reach across two close sheets: the plain fit lies between them, the robust
    one (as the reference computes it) on each point's own sheet."""
    points, nrm, own = two_sheets(gap=gap)
    graph, lists = _setup(points, 40)
    height, rms, degree = core.aware_fit(points, nrm, graph, 0.05, robust=True)
    ref = reference.aware_fit(points, nrm, lists, 0.05, robust=True)
    np.testing.assert_array_equal(degree, ref[2])
    np.testing.assert_allclose(height, ref[0], atol=1e-12, rtol=0)
    np.testing.assert_allclose(rms, ref[1], atol=1e-12, rtol=0)
    plain, _, _ = core.aware_fit(points, nrm, graph, 0.05)
    robust_error = np.abs(points[:, 2] + height - own).mean()
    plain_error = np.abs(points[:, 2] + plain - own).mean()
    assert plain_error > 0.25 * gap * 0.01  # the plain fit pulls the sheets together
    assert robust_error < 0.6 * plain_error  # measured: 0.53 at 4 sigma, 0.12 at 7.5 sigma


def test_robust_fit_mirrors_reference_constants():
    from pssd_fast.kernels import mls

    assert (mls.ROBUST_SPREAD, mls.ROBUST_MARGIN, mls.REFITS, mls.ROBUST_SAMPLES) == (
        reference.ROBUST_SPREAD, reference.ROBUST_MARGIN, reference.REFITS,
        reference.ROBUST_SAMPLES)


def test_aware_fit_keeps_each_side_of_a_crease():
    """A noiseless 90-degree fold: with the normal-agreement weight each point is fitted to its
    own face (height 0); without it the fit rounds the crease."""
    g = np.linspace(0, 1, 21)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    points = np.vstack([np.column_stack([u, v, 0 * u]), np.column_stack([0 * u[21:], v[21:],
                                                                         u[21:]])])
    nrm = np.vstack([np.tile([0, 0, 1.0], (len(u), 1)), np.tile([1.0, 0, 0], (len(u) - 21, 1))])
    graph = pssd_fast.neighbors(points, 25)
    aware, _, _ = core.aware_fit(points, nrm, graph, 0.05)
    blind, _, _ = core.aware_fit(points, nrm, graph, 0.0)
    np.testing.assert_allclose(aware, 0, atol=1e-12)
    assert np.abs(blind).max() > 1e-3


def test_mls_fit_reproduces_planes_and_smooth_surfaces():
    rng = np.random.default_rng(5)
    xy = rng.uniform(-1, 1, (300, 2))
    tilted = np.column_stack([xy, 0.3 * xy[:, 0] - 0.7 * xy[:, 1] + 2.0]) @ np.array(
        [[0.36, 0.48, -0.8], [-0.8, 0.6, 0.0], [0.48, 0.64, 0.6]])
    fit = pssd_fast.mls_fit(tilted, k=20)
    assert (fit.degree == 3).all()
    np.testing.assert_allclose(fit.residuals, 0, atol=1e-12)
    np.testing.assert_allclose(fit.projections, tilted, atol=1e-12)
    # A smooth cubic height field: the local cubics follow it closely (no noise to remove).
    cubic = np.column_stack([xy, 0.2 * xy[:, 0] ** 3 - 0.1 * xy[:, 0] * xy[:, 1] ** 2])
    fit = pssd_fast.mls_fit(cubic, k=20)
    assert np.abs(fit.projections - cubic).max() < 1e-3
    assert fit.residuals.max() < 1e-3


def test_mls_curvature_of_spheres_and_planes():
    rng = np.random.default_rng(14)
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    for radius in (0.5, 2.0):
        fit = pssd_fast.mls_fit(radius * p, p, k=20)  # outward normals
        np.testing.assert_allclose(np.median(fit.curvature), 1 / radius, rtol=0.01)
        inward = pssd_fast.mls_fit(radius * p, -p, k=20)
        np.testing.assert_allclose(inward.curvature, -fit.curvature, atol=1e-9 / radius)
    flat = pssd_fast.mls_fit(plane(300), k=15)
    np.testing.assert_allclose(flat.curvature, 0, atol=1e-9)


#: Eq. (2) by hand for residuals 0..4 (mean 2): exp(-d / 2), min(2 / d, 1), d / 2.
_LIKELIHOOD_TABLE = {"exp": np.exp(-np.arange(5) / 2.0), "ratio": [1.0, 1.0, 1.0, 2 / 3, 0.5],
                     "residual": [0.0, 0.5, 1.0, 1.5, 2.0]}


@pytest.mark.parametrize("form", ["exp", "ratio", "residual"])
def test_likelihood_forms(form):
    rng = np.random.default_rng(6)
    resid = np.concatenate([rng.exponential(size=50), [0.0]])
    out, dbar = core.sampling_likelihood(resid, form)
    assert dbar == pytest.approx(math.fsum(resid) / len(resid), rel=1e-14)
    np.testing.assert_allclose(out, reference.likelihood(resid, form), rtol=1e-14)
    # The defining properties: a function of d_i alone, monotone, 1 on the surface.
    by_resid = out[np.argsort(resid, kind="stable")]
    if form == "residual":
        assert np.all(np.diff(by_resid) >= 0) and out[-1] == 0.0
    else:
        assert np.all(np.diff(by_resid) <= 0) and out[-1] == 1.0
        assert np.all((out > 0) & (out <= 1))
    # Exact values where d is 0, half, once and twice the mean.
    table, table_dbar = core.sampling_likelihood(np.arange(5.0), form)
    assert table_dbar == 2.0
    np.testing.assert_allclose(table, _LIKELIHOOD_TABLE[form], rtol=1e-15)
    if form == "exp":
        assert table[2] == pytest.approx(math.exp(-1.0), rel=1e-15)
    zero, _ = core.sampling_likelihood(np.zeros(5), form)
    np.testing.assert_array_equal(zero, 0.0 if form == "residual" else 1.0)


def test_sampling_likelihood_orders_points_by_residual():
    points = plane(300, seed=7)
    points[:10, 2] += 0.05  # ten outliers above a clean plane
    lik = pssd_fast.sampling_likelihood(points, k=15)
    fit = pssd_fast.mls_fit(points, k=15)
    assert np.all((lik > 0) & (lik <= 1))
    order = np.argsort(fit.residuals)
    assert np.all(np.diff(lik[order]) <= 0)
    assert lik[:10].mean() < lik[10:].mean()


def test_region_growing_matches_reference(cloud):
    name, points, k = cloud
    graph, lists = _setup(points, k)
    radius = 10 * core.mean_spacing(graph)
    n = len(points)
    for start in sorted({0, n // 3, max(0, n - feature.BLOCK)}):
        stop = min(n, start + feature.BLOCK)
        for i, got in zip(range(start, stop), block_regions(points, graph, start, stop, radius)):
            assert got == set(reference.region(points, lists, i, radius))


def test_exp_polynomial_matches_exp():
    # The vote's weights exp(-|p_j - p_i| / sigma_e) have arguments in [0, 1.5].
    x = np.linspace(0.0, 1.5 * (1 + 1e-12), 10001)
    got = np.array([feature._exp_neg(v) for v in x])
    np.testing.assert_allclose(got, np.exp(-x), rtol=4e-15)


def test_feature_intensity(cloud):
    name, points, k = cloud
    graph, lists = _setup(points, k)
    nrm = _normals_for(name, points, lists)
    radius = 10 * core.mean_spacing(graph)
    got = pssd_fast.feature_intensity(points, nrm, graph=graph)
    ref, sizes = reference.feature_intensity(points, nrm, lists, radius)
    _, got_sizes = core.feature_intensity(points, nrm, graph, radius, 0.2, 0.3, 0.3)
    np.testing.assert_array_equal(got_sizes, sizes)
    assert np.all((got >= 0) & (got <= 1))
    np.testing.assert_allclose(got, ref, atol=1e-9)
    if name == "plane":
        np.testing.assert_allclose(got, 0, atol=1e-12)


def _corner_faces(axes):
    """Grid samples of the unit squares spanned by pairs of ``axes`` at the origin, with normals."""
    g = np.linspace(0, 1, 41)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    pts, nrm = [], []
    for normal_axis in axes:
        others = [a for a in range(3) if a != normal_axis]
        p = np.zeros((u.size, 3))
        p[:, others[0]], p[:, others[1]] = u, v
        pts.append(p)
        nrm.append(np.tile(np.eye(3)[normal_axis], (u.size, 1)))
    points, normals_ = np.vstack(pts), np.vstack(nrm)
    _, first = np.unique(points.round(12), axis=0, return_index=True)  # shared edges once
    first.sort()
    return points[first], normals_[first]


def test_feature_intensity_on_a_fold_and_a_corner():
    """Faces score 0, a 90-degree fold scores clearly, a corner of three faces scores 1."""
    points, nrm = _corner_faces([2, 0])  # z = 0 and x = 0 half-planes: fold along y
    s = pssd_fast.feature_intensity(points, nrm, k=12, radius_factor=3)
    on_fold = (np.abs(points[:, [0, 2]]).max(axis=1) < 1e-9) & (np.abs(points[:, 1] - .5) < .3)
    far = np.maximum(points[:, 0], points[:, 2]) > 0.3
    assert s[on_fold].min() > 0.3
    assert s[far].max() < 1e-6
    points, nrm = _corner_faces([0, 1, 2])
    s = pssd_fast.feature_intensity(points, nrm, k=12, radius_factor=3)
    assert s[np.linalg.norm(points, axis=1) < 1e-9] == pytest.approx([1.0])


def test_filter_normals(cloud):
    name, points, k = cloud
    graph, lists = _setup(points, k)
    nrm = _normals_for(name, points, lists)
    rng = np.random.default_rng(8)
    # Perturb and flip some normals: the filter must cope with inconsistent signs.
    noisy = nrm + rng.normal(0, 0.1, nrm.shape)
    noisy /= np.linalg.norm(noisy, axis=1)[:, None]
    noisy[::3] *= -1
    got = pssd_fast.filter_normals(points, noisy, graph=graph)
    # acos amplifies rounding near agreement (d acos/dx is infinite at 1): 1e-16 in a dot
    # product becomes ~1e-8 in an angle, so the tolerance is looser than elsewhere.
    np.testing.assert_allclose(got, reference.filter_normals(points, noisy, lists), atol=1e-8)
    assert np.all((got * noisy).sum(axis=1) > 0)
    same = pssd_fast.filter_normals(points, nrm if name == "collinear" else np.tile(
        [0, 0, 1.0], (len(points), 1)), graph=graph)
    np.testing.assert_allclose(np.abs(same[:, 2]), 1.0)


def test_move_points():
    rng = np.random.default_rng(9)
    n = 200
    points, proj = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    filtered = rng.normal(size=(n, 3))
    filtered /= np.linalg.norm(filtered, axis=1)[:, None]
    lik, feat = rng.uniform(size=n), rng.uniform(size=n)
    proj[0] = points[0]  # no offset: no move
    proj[1] = np.nan  # a failed projection: the point is held where it is
    for lam in (0.0, 0.3, 1.0):
        got, held = core.move(points, proj, filtered, lik, feat, lam)
        ref = reference.move_points(points, proj, filtered, lik, feat, lam)
        np.testing.assert_allclose(got[2:], ref[2:], atol=1e-14)
        np.testing.assert_array_equal(got[:2], points[:2])
        np.testing.assert_array_equal(held, np.arange(n) == 1)


def test_estimate_normals_follows_orient():
    points = sphere()
    inward = -(points - points.mean(axis=0))
    out = pssd_fast.estimate_normals(points, orient=inward)
    assert ((out * inward).sum(axis=1) >= 0).all()
    default = pssd_fast.estimate_normals(points)
    np.testing.assert_allclose(default, -out, atol=1e-12)


@pytest.mark.parametrize("call, error, match", [
    (lambda p: pssd_fast.mls_fit(p, h=0.0), ValueError, "h must be positive"),
    (lambda p: pssd_fast.sampling_likelihood(p, likelihood="max"), ValueError,
     "unknown likelihood"),
    (lambda p: pssd_fast.feature_intensity(p, delta=-1), ValueError, "delta must be positive"),
    (lambda p: pssd_fast.estimate_normals(p, orient=p[:5]), ValueError, "orient must have one"),
    (lambda p: pssd_fast.filter_normals(p, graph=pssd_fast.neighbors(p[:100], 10)), ValueError,
     "built for these points"),
    # A graph of as many other points (here these, reversed) was taken as theirs.
    (lambda p: pssd_fast.estimate_normals(p[::-1], graph=pssd_fast.neighbors(p, 10)),
     ValueError, r"graph.distances of row 0 are not those of these points"),
    (lambda p: pssd_fast.neighbors(p, k=9), ValueError, "k must be at least 10"),
    # Lists of k, not a denoising, need the points: the message says what k needs.
    (lambda p: pssd_fast.neighbors(p[:10], k=20), ValueError, r"need at least k \+ 1 = 21 "
     r"points for k = 20; got 10 points \(k is at least 10: pass a larger cloud\)"),
    (lambda p: pssd_fast.estimate_normals(p[:15], k=20), ValueError, r"got 15 points \(lower "
     r"k or pass a larger cloud\)"),
])
def test_stage_arguments_are_checked(call, error, match):
    with pytest.raises(error, match=match):
        call(wavy())


def test_stages_follow_the_input_dtype():
    """float32 points (away from the origin) give float32 results within one float32 rounding
    of the float64 reference run on the same values, and equal to the float64 stage rounded."""
    single = (wavy(200, noise=0.005, seed=25) * 10 + [1000.0, -2000.0, 50.0]).astype(np.float32)
    wide = single.astype(np.float64)  # the values the stages see, exactly
    k = 20
    lists, _ = reference.knn_lists(wide, k)
    nrm = _pca_reference(wide, lists)
    well_defined = _well_defined_normals(wide, lists)
    assert well_defined.all()
    h = _mean_kth_distance(wide, k)
    proj, resid, _, curvature = reference.mls_fit(wide, nrm, lists, h)
    radius = 10 * np.mean([np.sort(np.linalg.norm(wide - p, axis=1))[1] for p in wide])
    expected = {
        "estimate_normals": (pssd_fast.estimate_normals, {}, nrm, 1e-9),
        "mls_fit.projections": (lambda p, **kw: pssd_fast.mls_fit(p, **kw).projections,
                                {"normals": nrm}, proj, 1e-9),
        "mls_fit.residuals": (lambda p, **kw: pssd_fast.mls_fit(p, **kw).residuals,
                              {"normals": nrm}, resid, 1e-9),
        "mls_fit.curvature": (lambda p, **kw: pssd_fast.mls_fit(p, **kw).curvature,
                              {"normals": nrm}, curvature, 1e-7),
        "sampling_likelihood": (pssd_fast.sampling_likelihood, {"normals": nrm},
                                reference.likelihood(resid, "exp"), 1e-9),
        "feature_intensity": (pssd_fast.feature_intensity, {"normals": nrm},
                              reference.feature_intensity(wide, nrm, lists, radius)[0], 1e-9),
        "filter_normals": (pssd_fast.filter_normals, {"normals": nrm},
                           reference.filter_normals(wide, nrm, lists), 1e-8),
    }
    for name, (call, kwargs, ref, atol) in expected.items():
        got = call(single, k=k, **kwargs)
        assert got.dtype == np.float32, name
        np.testing.assert_array_equal(got, call(wide, k=k, **kwargs).astype(np.float32),
                                      err_msg=name)
        ulp = np.spacing(np.abs(ref).astype(np.float32)).astype(np.float64)
        excess = np.abs(got.astype(np.float64) - ref) - ulp
        assert excess.max() <= atol, (name, excess.max())
    fit = pssd_fast.mls_fit(single, nrm, k=k)
    assert fit.h == pytest.approx(h, rel=1e-12)


@pytest.mark.parametrize("sigmas", [(None, None), (0.05, 0.01)])
def test_bilateral_point_filter(cloud, sigmas):
    name, points, k = cloud
    graph, lists = _setup(points, k)
    nrm = _normals_for(name, points, lists)
    sigma_c, sigma_s = sigmas
    got = core.filter_points(points, nrm, graph, sigma_c or 0.0, sigma_s or 0.0)
    ref = reference.bilateral_points(points, nrm, lists, sigma_c, sigma_s)
    np.testing.assert_allclose(got, ref, atol=1e-12 * np.ptp(points, axis=0).max())
    if name == "plane":
        np.testing.assert_array_equal(got, points)


def test_grow_block_says_when_its_node_tables_are_full():
    points = wavy(400, seed=9)
    graph, _ = _setup(points, 12)
    radius = 10 * core.mean_spacing(graph)
    table, slot_at = np.empty(16, np.int32), np.empty(16, np.int64)
    args = (np.empty(8, np.int32), np.empty(8, np.uint64), np.empty(8, np.uint64),
            np.empty(8, np.bool_), np.empty(8, np.int64), np.empty((8, 8), np.int32),
            np.empty(8, np.int32))
    assert feature.grow_block(points, graph.indptr, graph.indices, 0, feature.BLOCK,
                              radius * radius, 9, np.empty((3, feature.BLOCK)), table, slot_at,
                              *args) == -1
    regions = block_regions(points, graph, 0, feature.BLOCK, radius)
    assert max(len(r) for r in regions) > 8


def test_feature_intensity_grows_its_node_tables_past_their_first_size():
    """Regions spanning a whole cloud larger than the first node tables (feature.NODES)."""
    points = wavy(feature.NODES + 900, noise=0.002, seed=10)
    graph, lists = _setup(points, 10)
    nrm = _pca_reference(points, lists)
    radius = 10.0  # beyond the cloud's diameter: a region is its point's connected component
    s, sizes = core.feature_intensity(points, nrm, graph, radius, 0.2, 0.3, 0.3)
    component, todo = {0}, [0]
    while todo:
        for j in lists[todo.pop()][:9]:
            if j not in component:
                component.add(j)
                todo.append(j)
    assert len(component) > feature.NODES
    inside = np.array(sorted(component))
    np.testing.assert_array_equal(sizes[inside], len(component))
    for i in inside[:: len(inside) // 4]:
        expected = reference.feature_point(points, nrm, inside, i, 0.2, 0.3, 0.3)
        assert s[i] == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("sigma_n", [0.0, 0.05])
def test_surface_fits(cloud, sigma_n):
    """Each point's kept quadratic: at the point, the fit of test_aware_fit; at points of a
    second noisy draw, the reference quadratic of their nearest point."""
    name, surface, k = cloud
    graph, lists = _setup(surface, k)
    nrm = _normals_for(name, surface, lists)
    coef, rms, degree = core.surface_fits(surface, nrm, graph, sigma_n)
    height, ref_rms, ref_degree = reference.aware_fit(surface, nrm, lists, sigma_n)
    scale = np.ptp(surface, axis=0).max()
    np.testing.assert_array_equal(degree, ref_degree)
    np.testing.assert_allclose(coef[:, 0], height, atol=1e-9 * scale, rtol=0)
    np.testing.assert_allclose(rms, ref_rms, atol=1e-9 * scale, rtol=0)
    rng = np.random.default_rng(7)
    points = surface[rng.integers(0, len(surface), 50)] + rng.normal(0, 0.01 * scale, (50, 3))
    # Any rows and distances (the weights) will do: each point's three fits, then the first
    # alone; points land outside some fits' balls, which leaves those fits out.
    nearest = rng.integers(0, len(surface), (50, 3))
    distance = rng.uniform(0.0, 0.3 * scale, (50, 3))
    distance[0, 1] = 0.0  # a point on an origin: that fit alone
    outcomes = set()
    for rows, dist in ((nearest, distance), (nearest[:, :1].copy(), distance[:, :1].copy())):
        moved, held = core.evaluate_fits(points, surface, nrm, coef, rows, dist)
        outcomes.update(held.tolist())
        for p, near, d, got, was_held in zip(points, rows, dist, moved, held):
            fits = [reference.frame_coefficients(surface[j], nrm[j], surface[lists[j]],
                                                 nrm[lists[j]], sigma_n)[:2] for j in near]
            targets = [reference.on_fit(p, surface[j], nrm[j], *fit)
                       for j, fit in zip(near, fits)]
            radius = np.array([fit[1] for fit in fits])
            want = reference.blended(p, targets, d, surface[near], radius)
            np.testing.assert_allclose(got, want, atol=1e-9 * scale, rtol=0)
            assert was_held == (np.linalg.norm(np.array(targets) - surface[near], axis=1)
                                > radius).all()
    if name != "tiny":  # eleven points: every list spans the cloud, and every fit reaches
        assert outcomes == {False, True}  # points moved and points held
    if name == "plane":
        np.testing.assert_allclose(moved[~held, 2], 0, atol=1e-12)


def test_evaluate_fits_holds_a_point_whose_step_is_not_finite():
    points = np.array([[0.1, 0.2, 0.3], [0.0, 0.0, 1.0]])
    origins = np.zeros((2, 3))
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    coef = np.zeros((2, 7))
    coef[:, 6] = 1.0
    distance = np.ones((2, 1))
    moved, held = core.evaluate_fits(points, origins, nrm, coef, np.array([[0], [1]]), distance)
    # The plane z = 0: each point drops onto it.
    np.testing.assert_allclose(moved, [[0.1, 0.2, 0.0], [0.0, 0.0, 0.0]])
    assert not held.any()
    coef[0, 5] = np.inf
    moved, held = core.evaluate_fits(points, origins, nrm, coef, np.array([[0], [1]]), distance)
    np.testing.assert_array_equal(held, [True, False])
    np.testing.assert_array_equal(moved[0], points[0])
    # Blended with a finite step, the step that is not finite is left out.
    coef[1, 0] = 0.5  # the plane z = 0.5
    moved, held = core.evaluate_fits(points[:1], origins, nrm, coef, np.array([[0, 1]]),
                                     np.ones((1, 2)))
    assert not held[0]
    np.testing.assert_allclose(moved[0], [0.1, 0.2, 0.5])


def test_evaluate_fits_uses_a_fit_only_within_its_support():
    """A fit broken on purpose (its surface 10 list radii above its origin), or read so far
    from its origin that the point would land outside the ball of its list, is left out; with
    no fit left, the point stays, held. A point far above a sound fit's surface still drops
    onto it."""
    points = np.array([[0.1, 0.2, 0.3]])
    origins = np.zeros((2, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (2, 1))
    coef = np.zeros((2, 7))
    coef[:, 6] = 2.0  # list radius 0.5
    coef[0, 0] = 5.0  # the broken fit: the plane z = 5, 10 radii up
    coef[1, 0] = 0.1  # a sound one: z = 0.1
    moved, held = core.evaluate_fits(points, origins, nrm, coef, np.array([[0, 1]]),
                                     np.array([[0.3, 0.4]]))
    assert not held[0]
    np.testing.assert_allclose(moved[0], [0.1, 0.2, 0.1])  # the sound fit alone
    moved, held = core.evaluate_fits(points, origins, nrm, coef, np.array([[0]]),
                                     np.array([[0.3]]))
    assert held[0] and (moved == points).all()
    # The sound fit read from beyond its radius: it would land outside its ball.
    far = np.array([[0.45, 0.3, 0.05]])
    moved, held = core.evaluate_fits(far, origins, nrm, coef, np.array([[1]]),
                                     np.array([[0.54]]))
    assert held[0] and (moved == far).all()
    # Far above the sound surface, within its radius across: the whole drop is supported.
    high = np.array([[0.1, 0.2, 3.0]])
    moved, held = core.evaluate_fits(high, origins, nrm, coef, np.array([[1]]),
                                     np.array([[3.0]]))
    assert not held[0]
    np.testing.assert_allclose(moved[0], [0.1, 0.2, 0.1])


def test_a_point_on_the_fitted_patch_stays():
    """A point lying on a noiseless quadratic patch barely moves onto the fit of its nearest
    patch point."""
    from pssd_fast.graph import knn_graph

    g = np.linspace(-1, 1, 15)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    surface = np.column_stack([x, y, 0.2 * x * x - 0.1 * x * y])
    nrm = np.column_stack([-0.4 * x + 0.1 * y, 0.1 * x, np.ones_like(x)])
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    points = np.array([[0.05, -0.03, 0.2 * 0.05**2 + 0.1 * 0.05 * 0.03]])
    distance = np.linalg.norm(surface - points[0], axis=1)
    nearest = np.argsort(distance)[:3]
    coef, _, degree = core.surface_fits(surface, nrm, knn_graph(surface, 16, False), 0.0)
    moved, _ = core.evaluate_fits(points, surface, nrm, coef, nearest[None],
                                  distance[nearest][None])
    assert (degree[nearest] == 6).all() and np.abs(moved - points).max() < 1e-4


@pytest.mark.parametrize("name", ["wavy", "sphere", "duplicates"])
def test_evaluate_fits_skips_the_rows_past_the_surface(name):
    """Rows past the surface's (a query bounded by a radius found fewer than it asked for):
    none. A point moves onto the fits of its other rows, as the reference blends them, exactly
    as if those alone were listed; with none, it stays, held."""
    surface = {"wavy": wavy, "sphere": sphere}.get(name, wavy)(300)
    if name == "duplicates":
        surface = np.repeat(surface[:100], 3, axis=0)
    graph, lists = _setup(surface, 16)
    nrm = _pca_reference(surface, lists)
    coef, _, _ = core.surface_fits(surface, nrm, graph, 0.05)
    m = len(surface)
    rng = np.random.default_rng(9)
    points = surface[rng.integers(0, m, 60)] + rng.normal(0, 0.01, (60, 3))
    nearest = rng.integers(0, m, (60, 3))
    distance = rng.uniform(0.01, 0.2, (60, 3))
    missing = rng.uniform(size=(60, 3)) < 0.4
    missing[:5] = True  # nothing found at all
    nearest[missing] = np.where(rng.uniform(size=missing.sum()) < 0.5, m, m + 7)
    distance[missing] = np.inf
    moved, held = core.evaluate_fits(points, surface, nrm, coef, nearest, distance)
    assert held[:5].all() and (moved[:5] == points[:5]).all()
    for i in range(5, 60):
        rows = ~missing[i]
        if not rows.any():
            assert held[i] and (moved[i] == points[i]).all()
            continue
        alone, alone_held = core.evaluate_fits(points[i:i + 1], surface, nrm, coef,
                                               nearest[i:i + 1, rows].copy(),
                                               distance[i:i + 1, rows].copy())
        np.testing.assert_array_equal(moved[i], alone[0])
        assert held[i] == alone_held[0]
        near = nearest[i, rows]
        fits = [reference.frame_coefficients(surface[j], nrm[j], surface[lists[j]],
                                             nrm[lists[j]], 0.05)[:2] for j in near]
        targets = [reference.on_fit(points[i], surface[j], nrm[j], *fit)
                   for j, fit in zip(near, fits)]
        want = reference.blended(points[i], targets, distance[i, rows], surface[near],
                                 np.array([fit[1] for fit in fits]))
        np.testing.assert_allclose(moved[i], want, atol=1e-9, rtol=0)
