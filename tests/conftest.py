"""Shared small clouds: random surfaces and the degenerate cases every kernel must survive; and
where the tests find the shared data files."""
import contextlib
import io
import os
from pathlib import Path

import numpy as np
import pytest

import pssd_fast
from benchmarks import models
from pssd_fast import cli
from pssd_fast.kernels import feature

try:
    import plyfile
except ImportError:
    plyfile = None
try:
    import laspy
except ImportError:
    laspy = None

# NPY, NPZ and text need numpy only: their tests run without the io extra.
needs_plyfile = pytest.mark.skipif(plyfile is None, reason="plyfile is not installed")
needs_laspy = pytest.mark.skipif(laspy is None, reason="laspy is not installed")

#: The folder holding the ``pssd_fast`` this process imported: a child process run there imports
#: the same files (and so loads their cached kernels) rather than an installed copy elsewhere.
PACKAGE_PARENT = Path(pssd_fast.__file__).resolve().parent.parent


def pssd(*args, cwd=None):
    """Run ``pssd ARGS`` as the console script runs it (in this process, which spares each
    call a start of Python and numba); return (status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                status = cli.main([str(arg) for arg in args])
            except SystemExit as exc:  # argparse's own errors and --help
                status = exc.code
    finally:
        os.chdir(here)
    return status, out.getvalue(), err.getvalue()


def data_file(kind, name):
    """Path of the shared data file ``kind/name`` (``kind`` one of ``meshes``, ``lidar``,
    ``realscans``, ``punet``), skipping the test with a message naming ``PSSD_DATA`` and the
    folder looked in when it is not there (:func:`benchmarks.models.data_folder`)."""
    path = models.data_folder(kind) / name
    if not path.is_file():
        pytest.skip(models.missing(kind, [name]))
    return path


def refuse_new_files(monkeypatch):
    """Make :mod:`pssd_fast.atomic` unable to create a file, as in a read-only folder (root,
    which runs the tests, ignores permission bits)."""
    from pssd_fast import atomic

    class NoCreate:
        """``os`` where no file can be created."""

        def __getattr__(self, name):
            return getattr(os, name)

        @staticmethod
        def open(path, *args, **kwargs):
            raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(atomic, "os", NoCreate())


def wavy(n=400, noise=0.005, seed=0):
    """A noisy height field z = 0.1 sin(3x) cos(2y) over the unit square."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 1, (n, 2))
    z = 0.1 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1]) + rng.normal(0, noise, n)
    return np.column_stack([xy, z])


def sphere(n=300, noise=0.01, seed=1):
    """Noisy points on the unit sphere, shifted off the origin."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    return p * (1 + rng.normal(0, noise, (n, 1))) + np.array([0.3, -0.2, 0.1])


def plane(n=200, seed=2):
    """Exactly planar points (z = 0): every residual is 0."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0, 1, (n, 2)), np.zeros(n)])


def collinear(n=60):
    """Points on one line: no plane anywhere."""
    t = np.linspace(0, 1, n)
    return np.column_stack([t, 2 * t, -t])


def duplicates(seed=3):
    """A noisy surface with every point present three times (ties at distance 0)."""
    return np.repeat(wavy(80, seed=seed), 3, axis=0)


def tiny(seed=4):
    """Eleven points, the fewest for k = 10."""
    return wavy(11, seed=seed)


CLOUDS = {"wavy": wavy, "sphere": sphere, "plane": plane, "collinear": collinear,
          "duplicates": duplicates, "tiny": tiny}


@pytest.fixture(params=sorted(CLOUDS))
def cloud(request):
    """(name, points, k) for each named cloud."""
    points = CLOUDS[request.param]()
    return request.param, points, min(25, len(points) - 1)


def block_regions(points, graph, start, stop, radius):
    """``N_R(i)`` for ``i`` in ``start..stop`` from one call of the block kernel, as sets."""
    capacity = 1 << int(np.ceil(np.log2(len(points))))  # every point fits
    table, slot_at = np.empty(2 * capacity, np.int32), np.empty(2 * capacity, np.int64)
    nodes, work = np.empty(capacity, np.int32), np.empty(capacity, np.int64)
    ball, reach = np.empty(capacity, np.uint64), np.empty(capacity, np.uint64)
    count = feature.grow_block(points, graph.indptr, graph.indices, start, stop, radius * radius,
                               9, np.empty((3, feature.BLOCK)), table, slot_at, nodes, ball,
                               reach, np.empty(capacity, np.bool_), work,
                               np.empty((capacity, 8), np.int32), np.empty(capacity, np.int32))
    return [set(nodes[:count][(reach[:count] >> np.uint64(b)) & np.uint64(1) == 1].tolist())
            for b in range(stop - start)]
