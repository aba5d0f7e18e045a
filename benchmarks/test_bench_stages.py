"""pytest-benchmark timings of each stage and of each method, grouped by stage and size.

Run with ``pytest benchmarks --benchmark-enable`` (``-m slow`` adds 1,000,000 points). pykdtree's
kNN query on the same points is benchmarked in the same session (group "reference") so stage
times can be read as ratios to it. Kernels are compiled by ``pssd_fast.warmup()`` before any
timing.
"""
import pytest
from pykdtree.kdtree import KDTree

import pssd_fast
from pssd_fast import datasets

K = 25
SIZES = [100_000, pytest.param(1_000_000, marks=pytest.mark.slow)]


@pytest.fixture(scope="module", params=SIZES, ids=lambda n: f"{n // 1000}k")
def prepared(request):
    pssd_fast.warmup()
    cloud = datasets.cad_part(n_points=request.param, noise=0.005, seed=0)
    points = cloud.points[pssd_fast.morton_order(cloud.points)]
    graph = pssd_fast.neighbors(points, K)
    nrm = pssd_fast.estimate_normals(points, graph=graph)
    return request.param, points, graph, nrm


def test_knn_query(benchmark, prepared):
    n, points, _, _ = prepared
    benchmark.group = f"reference-{n // 1000}k"
    benchmark(lambda: KDTree(points).query(points, k=K))


@pytest.mark.parametrize("stage", ["neighbors", "normals", "mls", "likelihood", "feature",
                                   "filter"])
def test_stage(benchmark, prepared, stage):
    n, points, graph, nrm = prepared
    benchmark.group = f"stage-{stage}-{n // 1000}k"
    calls = {
        "neighbors": lambda: pssd_fast.neighbors(points, K),
        "normals": lambda: pssd_fast.estimate_normals(points, graph=graph),
        "mls": lambda: pssd_fast.mls_fit(points, nrm, graph=graph),
        "likelihood": lambda: pssd_fast.sampling_likelihood(points, nrm, graph=graph),
        "feature": lambda: pssd_fast.feature_intensity(points, nrm, graph=graph),
        "filter": lambda: pssd_fast.filter_normals(points, nrm, graph=graph),
    }
    benchmark(calls[stage])


@pytest.mark.parametrize("method, preset, options", [
    ("robust", "default", {}), ("robust", "fast", {}), ("robust", "paper", {}),
    ("bilateral", "paper", {}), ("mls", "paper", {})],
    ids=["default", "fast", "paper", "bilateral", "mls"])
def test_method_one_iteration(benchmark, prepared, method, preset, options):
    n, points, _, _ = prepared
    benchmark.group = f"method-{n // 1000}k"
    benchmark.pedantic(pssd_fast.denoise, args=(points,),
                       kwargs={"method": method, "preset": preset, "iterations": 1, **options},
                       rounds=3)
