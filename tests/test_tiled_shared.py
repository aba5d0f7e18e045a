"""Tiled runs give the in-core result bit for bit on the shared real files: both LiDAR files
and a raw range view, in memory (``tiled.denoise``) and from a file to a file
(``tiled.denoise_file``). Each test skips with a message naming the folder when its file is
absent."""
import numpy as np
import pytest

import pssd_fast

from .conftest import data_file

pytest.importorskip("dask")
pytest.importorskip("laspy")

from pssd_fast import io, tiled  # noqa: E402  (after the skips: the io extra)

#: The files, each under the kind of data it is; the airborne survey (110,000 points) runs
#: under ``-m slow`` only, to keep the suite short.
FILES = [("lidar", "plane.laz"), ("realscans", "bun000.ply.gz"),
         pytest.param(("lidar", "autzen_trim.laz"), marks=pytest.mark.slow)]


@pytest.fixture(scope="module", params=FILES, ids=lambda kind_and_name: kind_and_name[1])
def real(request):
    """A shared file, its cloud as read and the in-core result of the default."""
    path = data_file(*request.param)
    cloud = io.read(path)
    return path, cloud, pssd_fast.denoise(cloud.points, cloud.normals)


def test_tiles_in_memory_give_the_in_core_result(real):
    _, cloud, whole = real
    n = cloud.points.shape[0]
    tiles = tiled.denoise(cloud.points, cloud.normals, tile_points=n // 3, client="sync")
    assert tiles.stats["tiles"]["count"] >= 2
    for field in ("points", "normals", "displacement", "held"):
        np.testing.assert_array_equal(getattr(tiles, field), getattr(whole, field),
                                      err_msg=field)
    assert tiles.stats["plan"] == whole.stats["plan"]


def test_a_file_tiled_on_disk_gives_the_in_core_file(real, tmp_path):
    """LAS/LAZ: the file itself into a file of its format, against the in-core result written
    as ``pssd denoise`` writes it; the raw view (PLY, which tiled runs do not read) saved as
    ``.npy`` first."""
    path, cloud, whole = real
    n = cloud.points.shape[0]
    if path.suffix == ".laz":
        # A classified file: each surface class on its own, as in core with its classification.
        whole = pssd_fast.denoise(cloud.points, cloud.normals,
                                  classification=cloud.fields.get("classification"))
        source, out, expected = path, tmp_path / "tiled.laz", tmp_path / "in_core.laz"
        io.write(expected, cloud, points=whole.points, normals=whole.normals)
        want = io.read(expected).points
    else:
        source, out = tmp_path / "view.npy", tmp_path / "tiled.npy"
        np.save(source, cloud.points)
        want = whole.points
    stats = tiled.denoise_file(source, out, tile_points=n // 4, client="sync")
    assert stats["tiles"]["count"] >= 2
    assert _plans(stats) == _plans(whole.stats) != []
    np.testing.assert_array_equal(io.read(out).points if out.suffix == ".laz" else np.load(out),
                                  want)


def _plans(stats):
    """The plan of a run, or of each class's run."""
    runs = stats.get("classes", {}).get("runs") or {None: stats}
    return [(code, run["plan"]) for code, run in runs.items() if "plan" in run]
