"""A scale per point (``select_scales``): the kernels against the references of
``tests/reference.py``, the probe, and the option through ``denoise``."""
import numpy as np
import pytest

import pssd_fast
from benchmarks import sheets
from pssd_fast import core, datasets
from pssd_fast.denoise import PRESETS
from pssd_fast.graph import knn_graph
from pssd_fast.kernels.linalg import orthonormal_basis
from pssd_fast.pipelines import walks
from pssd_fast.routes import scales

from . import reference

SIGMA_N = 0.3


def _unit(rng, n, tilt):
    normals = rng.normal(size=(n, 3)) * tilt + [0.0, 0.0, 1.0]
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _kernel_heights(points, normals, lists, coef):
    """The heights of each list's members above ``coef`` in the kernel's frame (the
    documented one: the point, its first listed normal, tangent coordinates times
    ``coef[:, 6]``)."""
    out = []
    for i, members in enumerate(lists):
        nrm = normals[members[0]]
        u, v = np.array(orthonormal_basis(*nrm)).reshape(2, 3)
        d = points[members] - points[i]
        x, y = d @ u * coef[i, 6], d @ v * coef[i, 6]
        c = coef[i]
        out.append(d @ nrm - (c[0] + c[1] * y + c[2] * x + c[3] * x * y + c[4] * y * y
                              + c[5] * x * x))
    return out


def _lists(graph):
    width = graph.indptr[1] - graph.indptr[0]
    return list(graph.indices.reshape(-1, width))


def _compare(got, want):
    for name in reference.SCALE_FITS:
        values = getattr(got, name)
        np.testing.assert_array_equal(np.isnan(values), np.isnan(want[name]), err_msg=name)
        np.testing.assert_allclose(values, want[name], rtol=1e-7, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("shape", ["curved", "planar"])
def test_scale_fits_agree_with_least_squares(shape):
    rng = np.random.default_rng(4)
    points = np.array(datasets.make("sphere", n_points=300, noise=0.01, seed=4).points)
    if shape == "planar":
        points[:, 2] = 0.0  # every list on one plane: the quadratic is still well posed
    normals = _unit(rng, 300, 0.1)
    graph = knn_graph(points, 30, False)
    lists = _lists(graph)
    # Some lists reach "across a thin wall": their neighbours also weigh their height above
    # a fit of the wall (random coefficients here).
    coef = rng.normal(size=(300, 7)) * [0.01, 0.01, 0.01, 0.01, 0.01, 0.01, 1.0]
    across = rng.uniform(size=300) < 0.3
    heights = _kernel_heights(points, normals, lists, coef)
    thin = {i: heights[i] for i in np.flatnonzero(across)}
    lengths = np.array([8, 16, 30, 40], np.int64)  # the last is longer than the lists
    got = core.scale_fits(points, normals, graph, lengths, SIGMA_N, 20, coef, across)
    _compare(got, reference.scale_fits(points, normals, lists, lengths, SIGMA_N, 20, thin))
    assert np.isfinite(got.rss_cubic[~across, 1:]).all()
    np.testing.assert_array_equal(got.weight[:, 2], got.weight[:, 3])


def test_the_taper_lowers_the_bias_on_a_sphere():
    # Noise-free points on the unit sphere with their true normals: each point lies on the
    # surface, so a fit's height is its bias alone (the quartic terms a quadratic misses).
    rng = np.random.default_rng(0)
    points = rng.normal(size=(3000, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    graph = knn_graph(points, 200, False)
    lengths = np.array([25, 50, 100, 200], np.int64)
    got = core.scale_fits(points, points.copy(), graph, lengths, SIGMA_N, 50,
                          np.zeros((3000, 7)), np.zeros(3000, np.bool_))
    flat, tapered = np.median(np.abs(got.quad), axis=0), np.median(np.abs(got.tapered), axis=0)
    assert (tapered < 0.7 * flat).all(), (flat, tapered)


@pytest.mark.parametrize("case", ["collinear", "duplicates", "two points"])
def test_degenerate_lists_have_no_fits(case):
    if case == "collinear":
        t = np.linspace(0.0, 1.0, 40)
        points = np.column_stack([t, 2.0 * t, np.zeros_like(t)])
    elif case == "duplicates":
        points = np.tile([1.0, 2.0, 3.0], (40, 1))
    else:
        points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    n = points.shape[0]
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    k = min(12, n)
    graph = knn_graph(points, k, False)
    lengths = np.array([min(6, k), k], np.int64)
    got = core.scale_fits(points, normals, graph, lengths, SIGMA_N, k, np.zeros((n, 7)),
                          np.ones(n, np.bool_))
    assert np.isnan(got.quad).all() and np.isnan(got.plane).all()
    assert np.isnan(got.rss_cubic).all()
    _compare(got, reference.scale_fits(points, normals, _lists(graph), lengths, SIGMA_N, k,
                                       {}))


def _random_fits(rng, n, n_scales):
    weight = np.cumsum(rng.uniform(1.0, 20.0, (n, n_scales)), axis=1)
    rss = np.cumsum(rng.uniform(0.0, 30.0, (n, n_scales)), axis=1)
    fits = {"quad": rng.normal(size=(n, n_scales)), "plane": rng.normal(size=(n, n_scales)),
            "rss": rss, "rss_plane": rss + rng.uniform(0.0, 10.0, (n, n_scales)),
            "rss_cubic": rss - rng.uniform(0.0, 1.0, (n, n_scales)) * rss,
            "weight": weight, "radius": np.cumsum(rng.uniform(size=(n, n_scales)), axis=1),
            "tapered": rng.normal(size=(n, n_scales))}
    # Degenerate fits: NaN heights and residuals, as the kernel leaves them.
    for name, share in (("quad", 0.05), ("plane", 0.05), ("rss_cubic", 0.1),
                        ("tapered", 0.1)):
        fits[name][rng.uniform(size=(n, n_scales)) < share] = np.nan
    fits["rss"][np.isnan(fits["quad"])] = np.nan
    return fits


@pytest.mark.parametrize("first", [0, 2])
def test_walk_scales_agree_with_loops(first):
    rng = np.random.default_rng(first)
    fits = _random_fits(rng, 2000, 5)
    fallback, fallback_rms = rng.normal(size=2000), rng.uniform(size=2000)
    got = core.walk_scales(core.ScaleFits(**fits), first, 1.5, scales.SCALES, fallback,
                           fallback_rms)
    want = reference.walk_scales(fits, first, 1.5, fallback, fallback_rms)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=0)
    height, _, pick, flat = got
    # Every outcome occurs: walks stopped at each column, planes and quadratics (tapered or
    # not), fallbacks.
    assert set(np.unique(pick)) == set(range(first, 5))
    assert 0 < flat.sum() < len(flat)
    assert (height == fallback).any()
    kept = np.arange(2000), pick
    assert (height == fits["tapered"][kept]).any()
    assert ((height == fits["quad"][kept]) & ~flat).any()


def _two_sheets(n, gap, seed):
    points, _, _ = sheets.sheets(n, gap, seed=seed)
    return np.ascontiguousarray(points, dtype=np.float64)


@pytest.mark.parametrize("cloud", ["cad_part", "two sheets"])
def test_the_iteration_fit_matches_the_reference(cloud):
    if cloud == "two sheets":
        points = _two_sheets(300, 4.0, 3)
    else:
        points = np.array(datasets.make("cad_part", n_points=300, noise=0.005, seed=3).points)
    k = 24
    graph = knn_graph(points, k, False)
    hints = points - points.mean(axis=0)
    nrm, _ = core.pca_normals(points, graph, hints)
    filtered = core.filter_normals(points, nrm, graph)
    lengths = scales.lengths(k, points.shape[0])
    lists = knn_graph(points, int(lengths[-1]), False)
    walk = scales.ScalePlan(lengths, 1, 2e-5)
    height, rms, degree, support, pick_got, flat_got = walks.fit(points, filtered, graph,
                                                                   lists, 0.05, walk)
    kept = walks.kept_counts(lengths, pick_got, flat_got)
    want_height, want_rms, pick, flat, walked = reference.scale_iteration_fit(
        points, filtered, _lists(graph), _lists(lists), lengths, 1, 2e-5)
    np.testing.assert_allclose(height, want_height, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(rms, want_rms, rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(pick_got, np.where(walked, pick, -1))
    assert kept["kept"] == np.bincount(pick[walked], minlength=len(lengths)).tolist()
    assert kept["flat"] == int(flat[walked].sum())
    np.testing.assert_array_equal(degree[walked], np.where(flat, 3, 6)[walked])
    # Each height's support: the radius of the prefix it was fitted over, else the list's.
    radius = np.array([np.linalg.norm(points[m] - p, axis=1).max()
                       for p, m in zip(points, _lists(lists))])
    at_k = np.array([np.linalg.norm(points[m] - p, axis=1).max()
                     for p, m in zip(points, _lists(graph))])
    prefix = np.array([np.linalg.norm(points[m[:lengths[c]]] - p, axis=1).max()
                       for p, m, c in zip(points, _lists(lists), pick)])
    np.testing.assert_allclose(support, np.where(walked, prefix, at_k), rtol=1e-12)
    assert (support <= radius * (1 + 1e-12)).all()
    assert walked.mean() > 0.3 and len(set(pick[walked])) > 2  # the walks went places
    if cloud == "two sheets":
        _, _, _, _, taken = core.robust_fits(points, filtered, graph, 0.05)
        assert taken.any()  # the thin-wall weights were in play


def test_the_plan_matches_the_reference():
    cloud = datasets.make("sphere", n_points=600, noise=0.02, seed=5)
    points = np.array(cloud.points)
    k = 32
    plan, lists = scales.plan(points, None, k, 0.05, 1, True)
    lengths = scales.lengths(k, 600)
    np.testing.assert_array_equal(plan.lengths, lengths)
    np.testing.assert_array_equal(lists.indices, knn_graph(points, int(lengths[-1]),
                                                           False).indices)
    # The reference: the first iteration's normals (PCA over k, away from the centroid,
    # shifted, filtered), the nested fits with their thin-wall weights, their medians.
    near, _ = reference.knn_lists(points, k)
    nrm = reference.pca_normals(points, near)
    nrm *= np.where((nrm * (points - points.mean(axis=0))).sum(axis=1) < 0, -1.0, 1.0)[:, None]
    nrm = reference.shifted_normals(points, nrm, near, round(reference.SHIFT["candidates"] * k),
                                    reference.SHIFT["tolerance"])[0]
    filtered = reference.filter_normals(points, nrm, near)
    far, _ = reference.knn_lists(points, lengths[-1])
    height, _, _ = reference.aware_fit(points, filtered, near, 0.05, robust=True)
    plain, _, _ = reference.aware_fit(points, filtered, near, 0.05)
    heights = reference.thin_wall_heights(points, filtered, near, 0.05)
    thin = {i: heights(i, far[i]) for i in range(600) if height[i] != plain[i]}
    fits = reference.scale_fits(points, filtered, far, lengths, 0.05, k, thin)
    variance = fits["rss"] / np.maximum(fits["weight"] - 6.0, 1.0)
    noise = np.sqrt(np.nanmedian(variance[:, list(lengths).index(k)]))
    wide = np.median(fits["radius"], axis=0) >= reference.SCALES["radius_over_noise"] * noise
    first = int(np.flatnonzero(wide)[0]) if wide.any() else len(lengths) - 1
    assert plan.first == first == 1, plan
    np.testing.assert_allclose(plan.noise2, np.nanmedian(variance[:, first]), rtol=1e-6)
    # On a subsample: the prefixes that span the same areas; no lists to hand on.
    sparse, none = scales.plan(points, None, k, 0.05, 2, True)
    assert none is None and 0 <= sparse.first < len(lengths)
    later = plan.at(1)
    assert later.first == 0
    assert later.noise2 == reference.SCALES["later_noise"] * plan.noise2


def test_lengths_stay_inside_the_cloud():
    np.testing.assert_array_equal(scales.lengths(64, 10_000), [16, 32, 64, 128, 192, 288])
    np.testing.assert_array_equal(scales.lengths(10, 64), [8, 10, 20, 30, 45])
    np.testing.assert_array_equal(scales.lengths(20, 64), [8, 10, 20, 40, 60, 63])
    np.testing.assert_array_equal(scales.lengths(4, 5), [4])


@pytest.fixture(scope="module")
def sphere():
    return datasets.make("sphere", n_points=4000, noise=0.005, seed=2)


@pytest.fixture(scope="module")
def selected(sphere):
    return pssd_fast.denoise(sphere.points, select_scales=True)


def test_selected_scales_denoise_a_sparse_sphere_below_the_fit_at_k(sphere, selected):
    plain = pssd_fast.denoise(sphere.points, select_scales=False)
    assert plain.stats["params"]["select_scales"] is False and plain.stats["scales"] is None
    errors = [sphere.surface_distance(r.points).mean() for r in (selected, plain)]
    assert errors[0] < 0.9 * errors[1]


def test_the_default_selects_scales_on_a_small_cloud(sphere, selected):
    out = pssd_fast.denoise(sphere.points)
    assert out.stats["params"]["select_scales"] is True
    np.testing.assert_array_equal(out.points, selected.points)
    np.testing.assert_array_equal(out.normals, selected.normals)


def test_the_default_fits_at_k_above_its_limit(sphere, monkeypatch):
    points = np.array(sphere.points)[:1500]
    monkeypatch.setitem(PRESETS["default"], "scales_up_to", 1499)
    out = pssd_fast.denoise(points, iterations=1)
    assert out.stats["params"]["select_scales"] is False and out.stats["scales"] is None
    np.testing.assert_array_equal(
        out.points, pssd_fast.denoise(points, iterations=1, select_scales=False).points)
    # At the limit, on.
    assert pssd_fast.denoise(points[:1499], iterations=1).stats["scales"] is not None


@pytest.mark.parametrize("n, on_points, given, taken", [
    (10, True, None, True), (11, True, None, False), (10, False, None, False),
    (11, True, True, True), (10, True, False, False), (10, False, True, True)])
def test_resolve(n, on_points, given, taken):
    assert scales.resolve(given, 10, n, on_points) is taken


def test_selected_scales_are_reported(selected):
    stats = selected.stats
    assert stats["params"]["select_scales"] is True
    assert stats["scales"]["lengths"][2] == stats["k"]
    assert 0 < stats["scales"]["noise"] < 0.05 and stats["scales"]["seconds"] > 0
    for record in stats["iterations"]:
        kept = record["scales"]
        assert sum(kept["kept"]) + record["fit_degree"]["mean_height"] + record["fit_degree"][
            "none"] <= 4000
        assert sum(kept["kept"]) > 3900 and 0 < kept["flat"] < 4000


def test_selected_scales_do_not_depend_on_the_threads(sphere, selected):
    points = np.array(sphere.points)[:1500]
    one = pssd_fast.denoise(points, select_scales=True, n_jobs=1)
    two = pssd_fast.denoise(points, select_scales=True, n_jobs=2)
    np.testing.assert_array_equal(one.points, two.points)
    np.testing.assert_array_equal(one.likelihood, two.likelihood)


def test_selected_scales_without_rebuild_graph_re_sort_their_lists(sphere, selected):
    out = pssd_fast.denoise(sphere.points, select_scales=True, rebuild_graph=False)
    # One query of the longest lists (the plan's), re-sorted by the later iterations.
    assert [("neighbors" in r["times"]) for r in out.stats["iterations"]] == [False] + [True] * 3
    errors = [sphere.surface_distance(r.points).mean() for r in (out, selected)]
    assert errors[0] == pytest.approx(errors[1], rel=0.05)
    assert out.stats["rebuild_graph"] is False


def test_selected_scales_take_given_normals(sphere):
    points = np.array(sphere.points)[:1500]
    given = points / np.linalg.norm(points, axis=1, keepdims=True)
    out = pssd_fast.denoise(points, given, select_scales=True, iterations=1)
    plain = pssd_fast.denoise(points, given, iterations=1, select_scales=False)
    assert out.stats["scales"] is not None
    assert np.abs(out.points - plain.points).max() > 0


def test_selected_scales_keep_two_close_sheets_apart():
    points, height, clean_xy = sheets.sheets(4000, 7.5, seed=1)
    out = pssd_fast.denoise(points, select_scales=True)
    assert sheets.score(out.points, height, clean_xy) < 0.5
    assert out.stats["scales"] is not None


def test_the_coarse_route_does_not_select_scales(sphere):
    out = pssd_fast.denoise(sphere.points, preset="fast", select_scales=True)
    assert out.stats["auto_k"]["coarse"] is not None and out.stats["scales"] is None
    auto = pssd_fast.denoise(sphere.points, preset="fast")
    assert auto.stats["params"]["select_scales"] is False and auto.stats["scales"] is None


@pytest.mark.parametrize("kwargs, error, message", [
    ({"select_scales": "yes"}, TypeError, "select_scales must be True, False or 'auto'"),
    ({"select_scales": True, "preset": "paper"}, ValueError,
     "select_scales only applies to the feature-aware"),
])
def test_bad_select_scales(sphere, kwargs, error, message):
    with pytest.raises(error, match=message):
        pssd_fast.denoise(sphere.points, **kwargs)
