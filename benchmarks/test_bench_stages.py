"""pytest-benchmark timings of each stage and of a whole iteration at 100,000 points.

Run with ``pytest benchmarks --benchmark-enable``; the kNN query is benchmarked in the same
session (group "reference") so that stage times can be read as ratios to it.
"""
import numpy as np
import pytest
from pykdtree.kdtree import KDTree

import pssd_fast
from pssd_fast import datasets, stages

N_POINTS = 100_000
K = 25


@pytest.fixture(scope="module")
def prepared():
    pssd_fast.warmup()
    points = datasets.cad_part(n_points=N_POINTS, noise=0.005, seed=0).points
    graph = pssd_fast.neighbors(points, K)
    nrm = pssd_fast.estimate_normals(points, graph=graph)
    return points, graph, nrm


@pytest.mark.benchmark(group="reference")
def test_knn_query(benchmark, prepared):
    points = prepared[0]
    benchmark(lambda: KDTree(points).query(points, k=K))


@pytest.mark.benchmark(group="stages")
@pytest.mark.parametrize("stage", ["neighbors", "normals", "mls", "feature", "filter"])
def test_stage(benchmark, prepared, stage):
    points, graph, nrm = prepared
    calls = {
        "neighbors": lambda: pssd_fast.neighbors(points, K),
        "normals": lambda: pssd_fast.estimate_normals(points, graph=graph),
        "mls": lambda: pssd_fast.mls_fit(points, nrm, graph=graph),
        "feature": lambda: pssd_fast.feature_intensity(points, nrm, graph=graph),
        "filter": lambda: pssd_fast.filter_normals(points, nrm, graph=graph),
    }
    benchmark(calls[stage])


@pytest.mark.benchmark(group="iteration")
def test_robust_iteration(benchmark, prepared):
    points = prepared[0]
    result = benchmark(lambda: pssd_fast.denoise(points, iterations=1))
    assert np.isfinite(result.points).all()
    assert stages.FIT_DEGREES
