"""Geometry a user recognises: the cube and Fandisk."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets


@pytest.fixture(scope="module")
def cube_run():
    # 60,000 points, Gaussian noise 0.4% of the side (the generator's noise is relative to the
    # diagonal, side * sqrt(3)), 2 iterations of the robust method at its defaults.
    cloud = datasets.cube(n_points=60_000, noise=0.004 / np.sqrt(3), seed=0)
    return cloud, pssd_fast.denoise(cloud.points, iterations=2)


def test_cube_gets_closer_to_the_truth_at_edges_and_on_faces(cube_run):
    cloud, result = cube_run
    before = cloud.surface_distance(cloud.points)
    after = cloud.surface_distance(result.points)
    near_edge = cloud.edge_distance < 0.03
    for mask in (near_edge, ~near_edge):
        assert after[mask].mean() < (2 / 3) * before[mask].mean()


def test_cube_feature_intensity_marks_the_edges(cube_run):
    cloud, result = cube_run
    edge = result.feature_intensity[cloud.edge_distance < 0.01].mean()
    face = result.feature_intensity[cloud.edge_distance >= 0.03].mean()
    assert edge > 5 * face
    assert edge > 0.25 and face < 0.05
