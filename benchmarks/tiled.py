"""Tiled, out-of-core runs on a Dask LocalCluster against the in-core run: time and memory.

Usage::

    python -m benchmarks.tiled                     # 2M and 20M points, tiles of 2M, 1 and 2 workers
    python -m benchmarks.tiled --points 2000000 --tile-points 1000000 --workers 2
    python -m benchmarks.tiled --format laz --out tiled_laz
    python -m benchmarks.tiled --noise 0.001 --points 500000 2000000 --tile-points 500000 \
        --out tiled_halo       # low noise: cells of one point each
    python -m benchmarks.tiled --points 100000000 --noise 0.0025 --tile-points 4000000 \
        8000000 --workers 1 --without-in-core --out tiled_100m   # beyond this machine's memory

The input is the generated CAD part (seed 0, noise 0.5% of the diagonal or ``--noise``) saved
as ``.npy``, or
(``--format laz``) scaled to 100 m and saved as LAZ. Each cell runs in a fresh process: the
in-core cell reads the file, calls ``pssd_fast.denoise`` and writes the result as ``pssd
denoise --fields none`` would; a tiled cell starts a ``LocalCluster`` of that many worker processes
(one thread each for two workers, both cores for one, ``OMP_NUM_THREADS`` alike) and calls
``pssd_fast.tiled.denoise_file``, then reads the driver's and each worker's peak resident size
(``ru_maxrss``), the CPU time of the calling process (its scheduler's threads included) against
that of the workers, and the time of the passes over the file (binning into buckets and tiles,
writing the output; tasks on the workers, planned by the calling process). The tiled output
is compared with the in-core one of the same size, bit for bit (with ``--without-in-core``,
for clouds beyond memory, with the first tiled one: a second tiling of the same file).
Writes ``benchmarks/results/tiled.md`` and ``.json``.
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .stages import RESULTS, cad_parts, child_result, machine, write_results

NOISE = 0.005


def child(kind, source, out, tile_points, workers):
    """Measure one cell in this process; print the result as one JSON line."""
    import pssd_fast

    pssd_fast.warmup()
    cpu = _cpu_seconds()
    if kind == "in-core":
        from pssd_fast import io

        started = time.perf_counter()
        cloud = io.read(source)
        result = pssd_fast.denoise(cloud.points)
        if source.endswith(".npy"):
            np.save(out, result.points)
        else:
            io.write(out, cloud, points=result.points)
        seconds = time.perf_counter() - started
        peaks, workers_cpu = [], 0.0
        stats = result.stats
    else:
        import distributed

        from pssd_fast import tiled

        import dask

        cores = os.cpu_count() or 1
        threads = max(1, cores // workers)
        # The nanny starts workers with OMP_NUM_THREADS=1, which pykdtree's query obeys.
        dask.config.set({"distributed.nanny.pre-spawn-environ.OMP_NUM_THREADS": threads})
        with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster, \
                distributed.Client(cluster) as client:
            client.run(pssd_fast.warmup)
            before = client.run(_cpu_seconds)
            cpu = _cpu_seconds()
            started = time.perf_counter()
            stats = tiled.denoise_file(source, out, tile_points=tile_points, client=client,
                                       n_jobs=threads)
            seconds = time.perf_counter() - started
            workers_cpu = sum(after - before.get(worker, 0.0)
                              for worker, after in client.run(_cpu_seconds).items())
            peaks = list(client.run(
                lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024).values())
    # The passes over the file: every timed pass before and after the rounds (none in core).
    tiles = stats.get("tiles") or {}
    passes = sum(sum(tiles.get(when, {}).values()) for when in ("before", "after"))
    driver_cpu = _cpu_seconds() - cpu
    print(json.dumps({"seconds": seconds, "driver_cpu": driver_cpu, "workers_cpu": workers_cpu,
                      "driver_peak": resource.getrusage(
        resource.RUSAGE_SELF).ru_maxrss * 1024, "worker_peaks": peaks, "k": stats["k"],
        "tiles": stats.get("tiles"),
        "file_passes": passes}))


def _cpu_seconds():
    """CPU time of this process so far, user and system."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def same(a, b):
    """Whether two files hold the same points (``.npy``: the arrays; LAS/LAZ: the point
    records), "True" or "False", read by a process of its own (see ``write_cad_part``: this
    process must stay small)."""
    done = subprocess.run([sys.executable, "-c", "import sys, numpy as np, laspy\n"
                           "def load(p):\n"
                           "    return np.load(p) if p.endswith('.npy') else "
                           "laspy.read(p).points.array\n"
                           "print(np.array_equal(load(sys.argv[1]), load(sys.argv[2])))",
                           str(a), str(b)], capture_output=True, text=True, check=True)
    return done.stdout.strip()


def as_laz(source):
    """``source`` (an ``.npy`` file) rewritten as LAZ beside it, by a process of its own; its
    path."""
    laz = source.with_suffix(".laz")
    subprocess.run([sys.executable, "-c", "import sys, numpy as np; from pssd_fast import io; "
                    "io.write(sys.argv[2], io.PointCloud(points=np.load(sys.argv[1]) * 100))",
                    str(source), str(laz)], check=True)
    source.unlink()
    return laz


def measure(kind, source, out, tile_points, workers):
    return child_result([sys.executable, "-m", "benchmarks.tiled", "--child", kind,
                         str(source), str(out), "--tile-points", str(tile_points),
                         "--workers", str(workers)])


def table(cells):
    lines = ["| points | run | tile points | workers | tiles | time (s) | passes over the file "
             "(s) | driver CPU share | driver peak (MB) | worker peaks (MB) | same as in-core |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        tiles = "-" if c["tiles"] is None else f"{c['tiles']['count']:,}"
        workers = ", ".join(f"{p / 1e6:.0f}" for p in c["worker_peaks"]) or "-"
        lines.append(f"| {c['points']:,} | {c['kind']} | "
                     f"{'-' if c['kind'] == 'in-core' else format(c['tile_points'], ',')} | "
                     f"{c['workers'] or '-'} | {tiles} | {c['seconds']:.1f} | "
                     f"{'-' if c['kind'] == 'in-core' else format(c['file_passes'], '.1f')} | "
                     f"{_share(c)} | "
                     f"{c['driver_peak'] / 1e6:.0f} | {workers} | {c['same']} |")
    return "\n".join(lines) + "\n"


def _share(cell):
    """The calling process's part of a tiled run's CPU time (its own and its workers')."""
    if cell["kind"] == "in-core":
        return "-"
    return f"{cell['driver_cpu'] / (cell['driver_cpu'] + cell['workers_cpu']):.0%}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, nargs="+", default=[2_000_000, 20_000_000])
    parser.add_argument("--tile-points", type=int, nargs="+", default=[2_000_000])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--format", choices=("npy", "laz"), default="npy",
                        help="the input's format (LAZ: the part scaled to 100 m, new LAS 1.4)")
    parser.add_argument("--noise", type=float, default=NOISE,
                        help="noise of the part, a fraction of its diagonal")
    parser.add_argument("--out", default="tiled", help="file stem in benchmarks/results/")
    parser.add_argument("--without-in-core", action="store_true",
                        help="leave the in-core run out (a cloud beyond memory): each tiled "
                             "output is compared with the first tiled one")
    parser.add_argument("--child", nargs=3, metavar=("KIND", "IN", "OUT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        kind, source, out = args.child
        child(kind, source, out, args.tile_points[0], args.workers[0])
        return

    cells = []
    with tempfile.TemporaryDirectory() as scratch:
        for n, source in cad_parts(args.points, args.noise, scratch):
            if args.format == "laz":
                source = as_laz(source)
            reference = Path(scratch) / f"reference{source.suffix}"
            runs = [] if args.without_in_core else [("in-core", 0, 0)]
            runs += [("tiled", t, w) for t in args.tile_points for w in args.workers]
            for kind, tile_points, workers in runs:
                first = not reference.exists()
                out = reference if first else Path(scratch) / f"tiled{source.suffix}"
                cell = {"points": n, "kind": kind, "tile_points": tile_points,
                        "workers": workers,
                        **measure(kind, source, out, tile_points or 1, workers or 1)}
                cell["same"] = "-" if first else same(out, reference)
                cells.append(cell)
                print(f"{n:>12,} {kind:>8} tiles of {tile_points:,}, {workers} workers: "
                      f"{cell['seconds']:.1f} s, driver {cell['driver_peak'] / 1e6:.0f} MB, "
                      f"workers {[round(p / 1e6) for p in cell['worker_peaks']]} MB, same "
                      f"{cell['same']}", flush=True)
                if not first:
                    out.unlink()
            source.unlink()
            reference.unlink()
    compared = ("the first tiled run" if args.without_in_core else "the in-core run")
    text = (f"Machine: {machine()}\n\nInput: the generated CAD part, seed 0, noise "
            f"{args.noise:.2%} of the diagonal, as .{args.format}; one process per cell; "
            f"each tiled output compared with {compared}.\n\n" + table(cells))
    print(text)
    write_results(RESULTS, args.out, text, {"cells": cells})


if __name__ == "__main__":
    main()
