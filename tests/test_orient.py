"""Consistent normal orientation: the propagation kernel against its reference, and
the orientations it gives on closed shapes, terrain and sheets."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import core, datasets
from pssd_fast.kernels.orient import propagate_orientation

from . import reference
from .conftest import duplicates, plane, sphere, wavy


def _random_signs(normals, seed):
    return normals * np.random.default_rng(seed).choice([-1.0, 1.0], (len(normals), 1))


@pytest.mark.parametrize("make", [wavy, sphere, plane, duplicates])
def test_propagation_matches_the_reference(make):
    points = make()
    graph = pssd_fast.neighbors(points, k=12)
    lists = reference.graph_lists(graph)
    normals = _random_signs(reference.pca_normals(points, lists), 5)
    expected, expected_component = reference.propagate_orientation(normals, lists,
                                                                   core.ORIENT_NEIGHBOURS)
    out = np.ascontiguousarray(normals)
    component = np.empty(len(points), np.int64)
    count = propagate_orientation(graph.indptr, graph.indices, core.ORIENT_NEIGHBOURS, out,
                                  component)
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(component, expected_component)
    assert count == expected_component.max() + 1


def test_propagation_splits_components_and_orients_each():
    """Two far apart spheres with random signs: two components, both outward (reference)."""
    a, b = sphere(300, seed=1), sphere(300, seed=2) + [5.0, 0, 0]
    points = np.vstack([a, b])
    graph = pssd_fast.neighbors(points, k=12)
    lists = reference.graph_lists(graph)
    normals = _random_signs(reference.pca_normals(points, lists), 6)
    signed, component = reference.propagate_orientation(normals, lists, core.ORIENT_NEIGHBOURS)
    expected = reference.orient_components(points, signed, component, "outward")
    out = normals.copy()
    assert core.orient_normals(points, out, graph, "outward") == 2
    np.testing.assert_array_equal(out, expected)
    centre = np.array([[0.3, -0.2, 0.1], [5.3, -0.2, 0.1]])[component]
    assert ((out * (points - centre)).sum(axis=1) > 0).all()


def _agreement(normals, truth):
    return ((normals * truth).sum(axis=1) > 0).mean()


def test_closed_shapes_point_outward():
    """Sphere, cube and a sphere beside a cube: every normal outward. Away-from-the-centroid
    (orient=None) turns the cube face that faces the sphere inward."""
    sph = datasets.sphere(8000, noise=0.0025, seed=0)
    cube = datasets.cube(12000, noise=0.0025, seed=1)
    for points, truth in ((sph.points, sph.normals), (cube.points, cube.normals)):
        assert _agreement(pssd_fast.estimate_normals(points, orient="outward"), truth) == 1.0
    pair = np.vstack([sph.points, cube.points + [1.3, 0.0, 0.0]])
    truth = np.vstack([sph.normals, cube.normals])
    assert _agreement(pssd_fast.estimate_normals(pair, orient="outward"), truth) == 1.0
    assert _agreement(pssd_fast.estimate_normals(pair), truth) < 0.95


def test_terrain_points_up_and_a_viewpoint_is_faced():
    """A rough terrain (hills, noise, a large offset as in georeferenced data): all normals up
    with "up", all towards a viewpoint high above."""
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 100, (20000, 2))
    z = 5 * np.sin(xy[:, 0] / 15) * np.cos(xy[:, 1] / 20) + rng.normal(0, 0.05, len(xy))
    points = np.column_stack([xy, z]) + [5e5, 4e6, 300.0]
    up = pssd_fast.estimate_normals(points, orient="up")
    assert (up[:, 2] > 0).all()
    view = pssd_fast.estimate_normals(points, orient=[5e5 + 50, 4e6 + 50, 1e4])
    np.testing.assert_array_equal(view, up)
    down = pssd_fast.estimate_normals(points, orient=[5e5 + 50, 4e6 + 50, -1e4])
    np.testing.assert_array_equal(down, -up)


def test_parallel_sheets_stay_opposite():
    """Two parallel squares 0.5 apart: each sheet's normals point away from the other."""
    rng = np.random.default_rng(7)
    sheet = np.column_stack([rng.uniform(0, 2, (6000, 2)), rng.normal(0, 0.002, 6000)])
    points = np.vstack([sheet, sheet[::-1] + [0, 0, 0.5]])
    normals = pssd_fast.estimate_normals(points, orient="outward")
    assert (normals[:6000, 2] < -0.9).all() and (normals[6000:, 2] > 0.9).all()


def test_denoise_orients_and_keeps_positions():
    """orient changes the normals' signs only: the same points, bit for bit, for any thread
    count; the normals outward everywhere on the sphere beside the cube."""
    sph = datasets.sphere(4000, noise=0.0025, seed=0)
    cube = datasets.cube(6000, noise=0.0025, seed=1)
    pair = np.vstack([sph.points, cube.points + [1.3, 0.0, 0.0]])
    truth = np.vstack([sph.normals, cube.normals])
    plain = pssd_fast.denoise(pair, preset="fast")
    runs = [pssd_fast.denoise(pair, preset="fast", orient="outward", n_jobs=j) for j in (1, 2)]
    np.testing.assert_array_equal(runs[0].points, plain.points)
    np.testing.assert_array_equal(runs[0].normals, runs[1].normals)
    assert _agreement(runs[0].normals, truth) == 1.0 > _agreement(plain.normals, truth)
    assert runs[0].stats["orient"] == "outward"


@pytest.mark.parametrize("orient, error, match", [
    ("inward", ValueError, "unknown orient 'inward'"),
    ([1.0, 2.0], ValueError, "viewpoint"),
    ([0.0, np.nan, 1.0], ValueError, "viewpoint"),
    (np.ones((5, 3)), ValueError, "one row per point"),
])
def test_bad_orientations_are_named(orient, error, match):
    with pytest.raises(error, match=match):
        pssd_fast.estimate_normals(wavy(), orient=orient)


def test_orient_refuses_given_normals():
    points = wavy()
    with pytest.raises(ValueError, match="orient applies to estimated normals"):
        pssd_fast.denoise(points, points, orient="up", k=10)


def test_turned_normals_hold_no_negative_zero():
    """A normal turned (times -1) has -0 where it had 0, and one turned twice by the
    propagation and its component's vote has 0 again: both ways of orienting leave 0, so that
    a tiled run, which turns each normal on its own, writes the in-core run's bytes."""
    points = np.column_stack([np.arange(16) % 4, np.arange(16) // 4, np.zeros(16)]) * 1.0
    lists = pssd_fast.neighbors(points, k=10)
    for turn in (lambda n: core.orient_pointwise(points, n, "up", np.zeros(3)),
                 lambda n: core.orient_normals(points, n, lists, "up")):
        normals = np.tile([0.0, -0.0, -1.0], (16, 1))
        turn(normals)
        np.testing.assert_array_equal(normals, np.tile([0.0, 0.0, 1.0], (16, 1)))
        assert not np.signbit(normals).any()
