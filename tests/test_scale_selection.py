"""The per-point scale prototype of ``benchmarks.scale_selection`` (its fits are the library's
kernel, tested in ``tests/test_scales.py``): the rule and its variants on small clouds."""
import numpy as np

import pssd_fast
from benchmarks import scale_selection, sheets
from pssd_fast import core, datasets
from pssd_fast.graph import knn_graph
from pssd_fast.pipelines import aware


def test_the_rule_denoises_a_sparse_sphere_below_the_default():
    cloud = datasets.make("sphere", n_points=4000, noise=0.005, seed=2)
    plain = cloud.surface_distance(pssd_fast.denoise(cloud.points,
                                                     select_scales=False).points).mean()
    with scale_selection.selected_scales() as move:
        points = pssd_fast.denoise(cloud.points, select_scales=False).points
    assert cloud.surface_distance(points).mean() < 0.9 * plain
    assert len(move.kept) == 4 and all(sum(kept) == 4000 for kept in move.kept)


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
