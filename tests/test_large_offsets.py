"""Lists beyond 2**31 entries: the kernels read ``indptr`` as int64 offsets into ``indices``,
never through a 32-bit index. A cloud of 2**31 list entries does not fit a test, so the lists
of a small cloud are placed after 2**31 unused entries of a sparse memory-mapped file, and
every kernel that reads lists gives the same bits as on the lists at offset 0."""
from types import SimpleNamespace

import numpy as np
import pytest

import pssd_fast
from pssd_fast import core, datasets, kernels

#: Unused entries before the lists: past the int32 range of offsets.
SKIP = 2**31 + 3


@pytest.fixture(scope="module")
def lists(tmp_path_factory):
    """The cloud, its lists at offset 0 and the same lists after :data:`SKIP` entries."""
    cloud = datasets.cad_part(n_points=1_500, noise=0.01, seed=3)
    # Writable copies: the kernels' signatures of every run (a dataset's arrays are read-only).
    points, normals = cloud.points.copy(), cloud.normals.copy()
    graph = pssd_fast.neighbors(points, 16)
    assert graph.indptr.dtype == np.int64
    nnz = int(graph.indptr[-1])
    path = tmp_path_factory.mktemp("offsets") / "indices.bin"
    # Sparse: only the pages of the lists are written.
    far = np.memmap(path, graph.indices.dtype, mode="w+", shape=(SKIP + nnz,))
    far[SKIP:] = graph.indices
    shifted = SimpleNamespace(indptr=graph.indptr + SKIP, indices=np.asarray(far))
    assert int(shifted.indptr[-1]) > 2**31
    return points, normals, graph, shifted


def _each_kernel(points, normals, graph):
    """The outputs of every kernel that reads lists, on ``graph``'s."""
    hints = points - points.mean(axis=0)
    found = {"pca": core.pca_normals(points, graph, hints),
             "planes": tuple(core.list_planes(points, graph, hints)),
             "mls": core.mls_fit(points, normals, graph, 0.05),
             "aware": core.aware_fit(points, normals, graph, 0.1, np.arange(len(points)) % 5
                                     + 1.0),
             "own": core.own_fits(points, normals, graph, 0.1),
             "filter": core.filter_normals(points, normals, graph),
             "bil": core.filter_points(points, normals, graph, 0.0, 0.0),
             "feature": core.feature_intensity(points, normals, graph, 0.08, 0.2, 0.3, 0.3)}
    offsets, spreads = np.empty(len(points)), np.empty(len(points))
    kernels.outliers.plane_offsets(points, graph.indptr, graph.indices, offsets, spreads)
    found["offsets"] = (offsets, spreads)
    return found


def test_kernels_read_lists_beyond_2_31_entries(lists):
    points, normals, graph, shifted = lists
    near, far = _each_kernel(points, normals, graph), _each_kernel(points, normals, shifted)
    for name, value in near.items():
        value = value if isinstance(value, tuple) else (value,)
        other = far[name] if isinstance(far[name], tuple) else (far[name],)
        for i, (a, b) in enumerate(zip(value, other, strict=True)):
            np.testing.assert_array_equal(a, b, err_msg=f"{name}, output {i}")
