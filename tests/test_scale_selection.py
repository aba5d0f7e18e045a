"""The per-point scale prototype of ``benchmarks.scale_selection``: its nested fits against
plain weighted least squares, and the rule on a small cloud."""
import numpy as np
import pytest

import pssd_fast
from benchmarks import scale_selection, sheets
from pssd_fast import core, datasets
from pssd_fast.graph import knn_graph
from pssd_fast.kernels.linalg import orthonormal_basis
from pssd_fast.pipelines import aware

SIGMA_N = 0.3
#: The outputs of ``scale_selection.scale_fits``, in its order.
FITS = ("quad", "plane", "rss", "rss_plane", "weight", "radius", "rss_cubic")


def reference_fits(points, normals, lists, scales, extra):
    """Each point's weighted cubic, quadratic and plane over the first ``s`` of its list, by
    ``np.linalg.lstsq``: heights, residual sums of squares, summed weight and list radius."""
    n, width = lists.shape
    out = {name: np.full((n, len(scales)), np.nan) for name in FITS}
    for i in range(n):
        nrm = normals[lists[i, 0]]
        u, v = np.array(orthonormal_basis(*nrm)).reshape(2, 3)
        d = points[lists[i]] - points[i]
        scale = 1.0 / np.sqrt((d * d).sum(axis=1).max())
        x, y, z = d @ u * scale, d @ v * scale, d @ nrm
        w = np.exp(-((1.0 - np.minimum(np.abs(normals[lists[i]] @ nrm), 1.0)) / SIGMA_N) ** 2)
        w = w * extra[i]
        basis = np.column_stack([np.ones(width), y, x, x * y, y * y, x * x, x ** 3, x * x * y,
                                 x * y * y, y ** 3])
        for s, count in enumerate(scales):
            sw = np.sqrt(w[:count])
            for m, height, rss in ((6, "quad", "rss"), (3, "plane", "rss_plane"),
                                   (10, None, "rss_cubic")):
                a = basis[:count, :m] * sw[:, None]
                if np.linalg.matrix_rank(a) == m:
                    coef = np.linalg.lstsq(a, z[:count] * sw, rcond=None)[0]
                    if height is not None:
                        out[height][i, s] = coef[0]
                    out[rss][i, s] = np.sum((a @ coef - z[:count] * sw) ** 2)
            out["weight"][i, s] = w[:count].sum()
            out["radius"][i, s] = np.sqrt((d[count - 1] ** 2).sum())
    return out


def kernel_fits(points, normals, graph, scales, extra):
    n = points.shape[0]
    out = {name: np.empty((n, len(scales))) for name in FITS}
    scale_selection.scale_fits(points, normals, graph.indptr, graph.indices, scales, SIGMA_N,
                               extra, *(out[name] for name in FITS))
    return out


@pytest.mark.parametrize("flat", [False, True], ids=["curved", "planar"])
def test_nested_fits_agree_with_least_squares(flat):
    rng = np.random.default_rng(4)
    cloud = datasets.make("sphere", n_points=400, noise=0.0 if flat else 0.01, seed=4)
    points = np.array(cloud.points)
    if flat:
        points[:, 2] = 0.0  # every list on one plane: the quadratic is still well posed
    normals = rng.normal(size=points.shape) * 0.1 + [0.0, 0.0, 1.0]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    scales = np.array([8, 16, 30], np.int64)
    graph = knn_graph(points, 30, False)
    extra = rng.uniform(0.0, 1.0, (points.shape[0], 30))
    extra[:, 0] = 1.0
    got = kernel_fits(points, normals, graph, scales, extra)
    want = reference_fits(points, normals, graph.indices.reshape(-1, 30), scales, extra)
    for name in want:
        np.testing.assert_array_equal(np.isnan(got[name]), np.isnan(want[name]), err_msg=name)
        np.testing.assert_allclose(got[name], want[name], rtol=1e-7, atol=1e-12, err_msg=name)


def test_collinear_lists_have_no_quadratic():
    t = np.linspace(0.0, 1.0, 40)
    points = np.column_stack([t, 2.0 * t, np.zeros_like(t)])
    normals = np.tile([0.0, 0.0, 1.0], (40, 1))
    graph = knn_graph(points, 12, False)
    got = kernel_fits(points, normals, graph, np.array([6, 12], np.int64), np.ones((40, 12)))
    assert np.isnan(got["quad"]).all() and np.isnan(got["plane"]).all()
    assert np.isnan(got["rss_cubic"]).all()
    np.testing.assert_array_equal(got["weight"], [[6.0, 12.0]] * 40)


def test_the_rule_denoises_a_sparse_sphere_below_the_default():
    cloud = datasets.make("sphere", n_points=4000, noise=0.005, seed=2)
    plain = cloud.surface_distance(pssd_fast.denoise(cloud.points).points).mean()
    with scale_selection.selected_scales() as move:
        points = pssd_fast.denoise(cloud.points).points
    assert cloud.surface_distance(points).mean() < 0.9 * plain
    assert len(move.kept) == 4 and all(sum(kept) == 4000 for kept in move.kept)


def reference_residuals(points, normals, lists, coef):
    out = np.empty(lists.shape)
    for i in range(lists.shape[0]):
        nrm = normals[lists[i, 0]]
        u, v = np.array(orthonormal_basis(*nrm)).reshape(2, 3)
        d = points[lists[i]] - points[i]
        x, y = d @ u * coef[i, 6], d @ v * coef[i, 6]
        c = coef[i]
        out[i] = d @ nrm - (c[0] + c[1] * y + c[2] * x + c[3] * x * y + c[4] * y * y
                            + c[5] * x * x)
    return out


def test_residuals_about_a_fit_agree_with_numpy():
    rng = np.random.default_rng(5)
    points = rng.normal(size=(200, 3))
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    lists = knn_graph(points, 12, False).indices.reshape(-1, 12)
    coef = rng.normal(size=(200, 7))
    got = np.empty((200, 12))
    scale_selection.residuals_about(points, normals, lists, coef, got)
    np.testing.assert_allclose(got, reference_residuals(points, normals, lists, coef),
                               rtol=1e-9, atol=1e-12)


def test_the_rule_keeps_two_close_sheets_apart():
    points, height, clean_xy = sheets.sheets(4000, 7.5, seed=1)
    with scale_selection.selected_scales() as move:
        out = pssd_fast.denoise(points).points
    assert sheets.score(out, height, clean_xy) < 0.5
    assert move.across[0] > 0  # the thin-wall weights were in play


class _Clock:
    """What ``aware.fit_and_move`` needs of a clock: run the stage."""

    def run(self, stage, func, *args):
        return func(*args)


def test_where_the_plane_test_fails_the_curved_option_picks_the_height():
    points = np.array(datasets.make("cad_part", n_points=3000, noise=0.005, seed=2).points)
    graph = knn_graph(points, 64, False)
    nrm, _ = core.pca_normals(points, graph, core.outward_hints(points))
    flat_only = scale_selection.ScaleMove(curved="default")
    moved = flat_only(points, nrm, graph, 0.05, _Clock())[0]
    flat = flat_only.flat[0]
    assert 0 < flat.sum() < len(flat)
    default = aware.fit_and_move(points, nrm, graph, 0.05, _Clock())[0]
    np.testing.assert_allclose(moved[~flat], default[~flat], rtol=0, atol=1e-12)
    walked = scale_selection.ScaleMove()
    rule = walked(points, nrm, graph, 0.05, _Clock())[0]
    np.testing.assert_array_equal(moved[flat], rule[flat])
    assert np.abs(moved[~flat] - rule[~flat]).max() > 0
    at_k = scale_selection.ScaleMove(curved="at-k")
    capped = at_k(points, nrm, graph, 0.05, _Clock())[0]
    np.testing.assert_array_equal(at_k.flat[0], flat)
    np.testing.assert_array_equal(capped[flat], rule[flat])
    # Points whose walk stopped at k or below keep the walked quadratic; wider ones do not.
    wide = walked.picked[0] > np.searchsorted(walked.scales, 64)
    assert wide[~flat].any() and (~wide[~flat]).any()
    np.testing.assert_array_equal(capped[~flat & ~wide], rule[~flat & ~wide])
    assert np.abs(capped[~flat & wide] - rule[~flat & wide]).max() > 0


def test_the_cubic_test_ends_walks_on_wrinkles_not_on_a_plane():
    """A wrinkled height field leaves cubic terms at the wide scales, and the walk stops
    before them; on a noisy plane the cubic terms explain only noise, and the walk is the
    same."""
    rng = np.random.default_rng(7)
    xy = rng.uniform(0.0, 1.0, (4000, 2))
    for wrinkles, wrinkled in ((0.02 * np.sin(12.0 * xy[:, 0]), True), (0.0, False)):
        points = np.column_stack([xy, wrinkles + rng.normal(0.0, 0.002, len(xy))])
        graph = knn_graph(points, 64, False)
        nrm, _ = core.pca_normals(points, graph, np.tile([0.0, 0.0, 1.0], (len(xy), 1)))
        walked, cubic = scale_selection.ScaleMove(), scale_selection.ScaleMove(cubic=4.0)
        walked(points, nrm, graph, 0.05, _Clock())
        cubic(points, nrm, graph, 0.05, _Clock())
        shorter = cubic.picked[0] < walked.picked[0]
        assert (cubic.picked[0] <= walked.picked[0]).all()
        # About 13% of the walks on the wrinkles and 1% on the plane (chance: a 4-sigma test).
        assert shorter.mean() > 0.1 if wrinkled else shorter.mean() < 0.02
