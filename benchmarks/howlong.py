"""How long will it take: the default preset's wall-clock seconds by size, noise and threads.

Usage::

    python -m benchmarks.howlong                          # 10,000, 100,000 and 1,000,000 points
    python -m benchmarks.howlong --sizes 10000 100000 --noises 0.001 0.01 --threads 1 2

The input is the library's generated CAD part (``pssd_fast.datasets.cad_part``, seed 0, the
cloud of ``python -m pssd_fast``) with Gaussian noise of each ``--noises`` fraction of its
diagonal. Each (size, noise, threads) cell runs in a fresh process with ``NUMBA_NUM_THREADS``
and ``OMP_NUM_THREADS`` set to its thread count: the child loads the cloud from a ``.npy`` file,
compiles or loads every kernel (:func:`pssd_fast.warmup`), then times ``denoise(points)`` with
every default (the best of three runs below 1,000,000 points, one run from there;
``--repeats``) and pykdtree's k=25 query of the same points in Morton order, the reference of
the ratio column.
Writes ``benchmarks/results/howlong.md`` and ``.json`` (``--out``) after every cell.
"""
import argparse
import json
import os
import platform
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

from .stages import RESULTS, child_result, knn_query_seconds, write_cad_part, write_results

#: Below this many points the run and the reference query are repeated (best of three).
REPEAT_BELOW = 1_000_000


def child(path, repeats=None):
    """Time one cell in this process (the best of ``repeats`` runs; None: 3 below
    :data:`REPEAT_BELOW` points, else 1); print the result as one JSON line."""
    import pssd_fast

    points = np.load(path)
    warmup = pssd_fast.warmup()
    load = os.getloadavg()[0]  # other work on the machine, before this cell's
    repeats = repeats or (3 if len(points) < REPEAT_BELOW else 1)
    seconds = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        result = pssd_fast.denoise(points)
        seconds = min(seconds, time.perf_counter() - started)
    ordered = np.ascontiguousarray(points[pssd_fast.morton_order(points)])
    knn = min(knn_query_seconds(ordered, 25) for _ in range(repeats))
    stats = result.stats
    print(json.dumps({"seconds": seconds, "knn_query": knn, "warmup_seconds": warmup,
                      "load_before": load,
                      "threads": stats["n_jobs"], "iterations": stats["n_iterations"],
                      "k": stats["k"]}))


def measure(path, threads, repeats=None):
    """The child's result for the cloud saved at ``path`` with ``threads`` threads."""
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    repeat = [] if repeats is None else ["--repeats", str(repeats)]
    return child_result([sys.executable, "-m", "benchmarks.howlong", "--child", str(path),
                         *repeat], env)


def cpu():
    """The CPU's model name (Linux), else what :mod:`platform` says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def describe_machine():
    import numba

    return (f"{cpu()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"numba {numba.__version__}, numpy {np.__version__}")


def table(cells, threads):
    """One row per (points, noise): each thread count's seconds and its ratio to the kNN
    query, then the list length and iterations of the run."""
    rows = {}
    for c in cells:
        rows.setdefault((c["points"], c["noise"]), {})[c["threads_asked"]] = c
    head = "| points | noise | " + " | ".join(
        f"{t} thread{'s' * (t > 1)} (s) | x kNN" for t in threads) + " | k, iterations |"
    lines = [head, "|" + "---|" * (3 + 2 * len(threads))]
    for (n, noise), by_threads in rows.items():
        cols = []
        for t in threads:
            c = by_threads.get(t)
            cols += (["-", "-"] if c is None else
                     [f"{c['seconds']:.2f}", f"{c['seconds'] / c['knn_query']:.1f}"])
        first = next(iter(by_threads.values()))
        lines.append(f"| {n:,} | {noise:.2%} | " + " | ".join(cols)
                     + f" | {first['k']}, {first['iterations']} |")
    return "\n".join(lines) + "\n"


def results(cells, threads, repeats, machine):
    """The text of ``howlong.md``: the machine, the input, :func:`table` and the load."""
    runs = ("best of three below 1,000,000 points" if repeats is None else
            f"best of {repeats}" if repeats > 1 else "one run")
    text = f"Machine: {machine}\n\n" + textwrap.fill(
        f"Input: the generated CAD part (`pssd_fast.datasets.cad_part`, seed 0), Gaussian "
        f"noise in % of its diagonal; `pssd_fast.denoise(points)` with every default, "
        f"wall-clock seconds after the kernels are compiled or loaded ({runs}); x kNN: over "
        f"pykdtree's k=25 query of the same points with as many threads. One process per "
        f"cell.", 100) + "\n\n" + table(cells, threads)
    if cells:
        loads = [c["load_before"] for c in cells]
        text += "\n" + textwrap.fill(
            f"Load average (1 minute) before each cell: {min(loads):.1f} to {max(loads):.1f}; "
            f"other work on the machine slows the cells, those with every core most.", 100) + "\n"
    return text


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--noises", type=float, nargs="+", default=[0.001, 0.01],
                        help="noise levels, fractions of the diagonal")
    parser.add_argument("--threads", type=int, nargs="+",
                        default=sorted({1, os.cpu_count() or 1}),
                        help="thread counts (default: 1 and every core)")
    parser.add_argument("--repeats", type=int, default=None,
                        help="runs per cell, the best kept (default: 3 below 1,000,000 points, "
                             "else 1)")
    parser.add_argument("--out", type=Path, default=RESULTS,
                        help="folder for howlong.md/.json")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.child, args.repeats)
        return None
    if min(args.threads) < 1 or (args.repeats is not None and args.repeats < 1):
        parser.error("--threads and --repeats must be at least 1")

    cells = []

    def save():
        text = results(cells, args.threads, args.repeats, describe_machine())
        write_results(args.out, "howlong", text,
                      {"machine": describe_machine(), "sizes": args.sizes,
                       "noises": args.noises, "threads": args.threads,
                       "repeats": args.repeats, "cells": cells})
        return text

    with tempfile.TemporaryDirectory() as scratch:
        for n in args.sizes:
            for noise in args.noises:
                path = Path(scratch) / f"cloud_{n}_{noise}.npy"
                write_cad_part(n, noise, path)
                for threads in args.threads:
                    cell = {"points": n, "noise": noise, "threads_asked": threads,
                            **measure(path, threads, args.repeats)}
                    cells.append(cell)
                    print(f"{n:>10,} points {noise:.2%} {threads} threads: "
                          f"{cell['seconds']:8.2f} s ({cell['seconds'] / cell['knn_query']:.1f}x "
                          f"kNN), k = {cell['k']}, {cell['iterations']} iterations", flush=True)
                    save()
                path.unlink()
    text = save()
    print(text)
    return cells


if __name__ == "__main__":
    main()
