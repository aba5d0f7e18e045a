"""pytest-benchmark timings of PLY reading and writing, beside denoising the same points.

Run with ``pytest benchmarks/test_bench_io.py --benchmark-enable``. Each raw range view of the
``realscans/`` folder of ``PSSD_DATA`` (skipped when there is none) is read, written as it came
(ASCII ``.ply.gz``) and as binary ``.ply``, and its points are denoised at the defaults, in one
group per view, so that the file times read as fractions of a denoising (``python -m
benchmarks.io`` tabulates the same).
"""
import pytest

import pssd_fast
from pssd_fast import io as pio

from .io import as_binary
from .models import data_folder, missing

FOLDER = data_folder("realscans")
VIEWS = sorted(FOLDER.glob("*.ply.gz")) if FOLDER.is_dir() else []
views = pytest.mark.parametrize(
    "path", VIEWS or [pytest.param(None, marks=pytest.mark.skip(
        reason=missing("realscans", ["*.ply.gz"])))],
    ids=lambda path: path.name.removesuffix(".ply.gz") if path else "none")


def group(path):
    return f"ply-{path.name.removesuffix('.ply.gz')}"


@views
def test_read(benchmark, path):
    benchmark.group = group(path)
    benchmark(pio.read, path)


@views
@pytest.mark.parametrize("binary", [False, True], ids=["as it came", "binary"])
def test_write(benchmark, path, binary, tmp_path):
    benchmark.group = group(path)
    cloud = pio.read(path)
    cloud, out = (as_binary(cloud), "out.ply") if binary else (cloud, "out.ply.gz")
    benchmark(pio.write, tmp_path / out, cloud, overwrite=True)


@views
def test_denoise(benchmark, path):
    benchmark.group = group(path)
    pssd_fast.warmup()
    points = pio.read(path).points
    benchmark.pedantic(pssd_fast.denoise, args=(points,), rounds=3)
