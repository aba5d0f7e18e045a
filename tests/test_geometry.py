"""Geometry a user recognises: a noisy cube."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets


@pytest.fixture(scope="module")
def cube():
    # 60,000 points, Gaussian noise 0.4% of the side (the generator's noise is relative to the
    # diagonal, side * sqrt(3)).
    return datasets.cube(n_points=60_000, noise=0.004 / np.sqrt(3), seed=0)


@pytest.fixture(scope="module")
def cube_runs(cube):
    """2 iterations of the robust method at the paper's settings and at the library's."""
    return {preset: pssd_fast.denoise(cube.points, iterations=2, preset=preset)
            for preset in ("paper", "default")}


@pytest.mark.parametrize("preset", ["paper", "default"])
def test_cube_gets_closer_to_the_truth_at_edges_and_on_faces(cube, cube_runs, preset):
    cloud, result = cube, cube_runs[preset]
    before = cloud.surface_distance(cloud.points)
    after = cloud.surface_distance(result.points)
    near_edge = cloud.edge_distance < 0.03
    for mask in (near_edge, ~near_edge):
        assert after[mask].mean() < (2 / 3) * before[mask].mean()


def test_cube_feature_intensity_marks_the_edges(cube, cube_runs):
    cloud, result = cube, cube_runs["paper"]  # the rates are stated for the paper's settings
    edge = result.feature_intensity[cloud.edge_distance < 0.01].mean()
    face = result.feature_intensity[cloud.edge_distance >= 0.03].mean()
    assert edge > 5 * face
    assert edge > 0.25 and face < 0.05
