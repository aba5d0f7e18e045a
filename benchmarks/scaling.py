"""Time and peak memory of one robust iteration against the number of points and threads.

Usage::

    python -m benchmarks.scaling                              # 1e4..1e6 points, 1..all cores
    python -m benchmarks.scaling --sizes 10000000 --threads 2 --out scaling_10M
    python -m benchmarks.scaling --preset default --k 0 --sizes 1000000 --out scaling_default

Each (size, threads) cell runs in a fresh process, so that its peak resident size (the OS's
``ru_maxrss``) belongs to that run alone: the child loads the cloud from a ``.npy`` file (no
temporaries), compiles on a small cloud, notes its resident size, denoises and reads the peak.
"Bytes per point" is that peak minus the resident size before the call and minus the result's
arrays, over the number of points. The child then times pykdtree's k=25 query on the same
points in Morton order with the same thread count, the reference of the ratio column. Prints a
markdown table and writes it with the raw numbers (JSON) and a plot (PNG, needs matplotlib) to
``benchmarks/results/``.
"""
import argparse
import json
import os
import resource
import sys
import tempfile
import time

import numpy as np

from pssd_fast.run import stored

from .stages import (RESULTS, STAGES, cad_parts, child_result, knn_query_seconds, machine,
                     write_results)

THREADS = (1, 2, 4, 8, 16)
#: The result's arrays a run returns (the bytes of its output); fields a run of "default" or
#: "fast" computes when first read count only where the run computed them.
OUTPUTS = ("points", "normals", "likelihood", "feature_intensity", "displacement", "kept")


def child(path, k, method, preset, repeats):
    """Measure one cell in this process; print the result as one JSON line."""
    import pssd_fast
    from pssd_fast.graph import morton_order

    points = np.load(path)
    run = dict(iterations=1, k=k or None, method=method, preset=preset)
    pssd_fast.denoise(points[:5000], **run)
    rss_before = _resident_bytes()
    times, total = {}, np.inf
    for _ in range(repeats):
        started = time.perf_counter()
        result = pssd_fast.denoise(points, **run)
        total = min(total, time.perf_counter() - started)
        for stage, seconds in result.stats["iterations"][0]["times"].items():
            times[stage] = min(times.get(stage, np.inf), seconds)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    # Fields computed when first read are not output the run held.
    output = sum(a.nbytes for a in (stored(result, name) for name in OUTPUTS[:-1])
                 if isinstance(a, np.ndarray))
    result_k = result.stats["k"]
    del result
    ordered = points[morton_order(points)]
    knn = min(knn_query_seconds(ordered, 25) for _ in range(repeats))
    n = len(points)
    print(json.dumps({"times": times, "total": total, "knn_query": knn, "k": result_k,
                      "peak_bytes": peak, "rss_before": rss_before,
                      "bytes_per_point": (peak - rss_before - output) / n}))


def _resident_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def measure(path, threads, k, method, preset, repeats):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    return child_result([sys.executable, "-m", "benchmarks.scaling", "--child", str(path),
                         "--k", str(k), "--method", method, "--preset", preset,
                         "--repeats", str(repeats)], env)


def exponent(sizes, seconds):
    """Least-squares slope of log(time) against log(points)."""
    if len(sizes) < 2:
        return float("nan")
    return float(np.polyfit(np.log(sizes), np.log(seconds), 1)[0])


def table(cells, method, preset):
    seen = {stage for c in cells for stage in c["times"]}
    stages_run = [s for s in STAGES if s in seen] + sorted(seen - set(STAGES))
    head = ("| points | threads | k | kNN k=25 (s) | " + " | ".join(stages_run)
            + " | iteration (s) | iteration / kNN | peak RSS (MB) | bytes/point |")
    lines = [head, "|" + "---|" * (len(stages_run) + 8)]
    for c in cells:
        t = c["times"]
        stages = " | ".join(f"{t.get(s, float('nan')):.3f}" for s in stages_run)
        lines.append(f"| {c['points']:,} | {c['threads']} | {c['k']} | {c['knn_query']:.3f} | "
                     f"{stages} | "
                     f"{c['total']:.3f} | {c['total'] / c['knn_query']:.1f} | "
                     f"{c['peak_bytes'] / 1e6:.0f} | {c['bytes_per_point']:.0f} |")
    text = "\n".join(lines) + (f"\n\nOne {method} iteration, preset {preset!r}, times in seconds "
                               "(best of the repeats); bytes/point: peak resident size above "
                               "the input and the result arrays.\n")
    by_threads = {}
    for c in cells:
        by_threads.setdefault(c["threads"], []).append(c)
    for threads, group in sorted(by_threads.items()):
        sizes = [c["points"] for c in group]
        text += (f"\n{threads} thread(s): time grows as N^"
                 f"{exponent(sizes, [c['total'] for c in group]):.2f} "
                 f"(kNN query: N^{exponent(sizes, [c['knn_query'] for c in group]):.2f})")
    by_size = {}
    for c in cells:
        by_size.setdefault(c["points"], {})[c["threads"]] = c["total"]
    for n, row in sorted(by_size.items()):
        if 1 in row and len(row) > 1:
            speedups = ", ".join(f"{t}: {row[1] / s:.2f}x" for t, s in sorted(row.items()))
            text += f"\nSpeed-up over 1 thread at {n:,} points: {speedups}"
    return text + "\n"


def plot(cells, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed (pip install -e '.[viz]'): no plot", file=sys.stderr)
        return
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    threads = sorted({c["threads"] for c in cells})
    for t in threads:
        group = sorted((c for c in cells if c["threads"] == t), key=lambda c: c["points"])
        n = [c["points"] for c in group]
        left.loglog(n, [c["total"] for c in group], "o-", label=f"iteration, {t} thread(s)")
        left.loglog(n, [c["knn_query"] for c in group], "x--", label=f"kNN query, {t} thread(s)")
    left.set_xlabel("points")
    left.set_ylabel("seconds")
    left.set_title("One iteration vs pykdtree's k=25 query")
    left.legend(fontsize=7)
    sizes = sorted({c["points"] for c in cells})
    for n in sizes:
        group = sorted((c for c in cells if c["points"] == n), key=lambda c: c["threads"])
        if len(group) > 1 and group[0]["threads"] == 1:
            right.plot([c["threads"] for c in group],
                       [group[0]["total"] / c["total"] for c in group], "o-", label=f"{n:,} points")
    right.plot(threads, threads, ":", color="grey", label="ideal")
    right.set_xlabel("threads")
    right.set_ylabel("speed-up over 1 thread")
    right.set_title("Thread scaling")
    right.legend(fontsize=7)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--threads", type=int, nargs="+",
                        default=[t for t in THREADS if t <= (os.cpu_count() or 1)])
    parser.add_argument("--k", type=int, default=25, help="0: the preset's choice")
    parser.add_argument("--method", default="robust", choices=("robust", "bilateral", "mls"))
    parser.add_argument("--preset", default="paper",
                        help="denoise preset (default: the paper's pipeline, the issue's target)")
    parser.add_argument("--noise", type=float, default=0.005)
    parser.add_argument("--repeats", type=int, default=2,
                        help="runs per cell, best kept (one run above 2,000,000 points)")
    parser.add_argument("--out", default="scaling", help="file stem in benchmarks/results/")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.child, args.k, args.method, args.preset, args.repeats)
        return

    cells = []
    with tempfile.TemporaryDirectory() as scratch:
        for n, path in cad_parts(args.sizes, args.noise, scratch):
            for threads in args.threads:
                cell = {"points": n, "threads": threads,
                        **measure(path, threads, args.k, args.method, args.preset,
                                  args.repeats if n <= 2_000_000 else 1)}
                cells.append(cell)
                print(f"{n:>10,} points {threads:>2} threads: {cell['total']:8.2f} s "
                      f"({cell['total'] / cell['knn_query']:.1f}x kNN), "
                      f"{cell['bytes_per_point']:.0f} B/point", flush=True)
    text = (f"Machine: {machine()}\n\nInput: the generated CAD part, noise {args.noise:.2%} of "
            f"the diagonal.\n\n" + table(cells, args.method, args.preset))
    print(text)
    write_results(RESULTS, args.out, text, {"method": args.method, "preset": args.preset,
                                            "noise": args.noise, "cells": cells})
    plot(cells, RESULTS / f"{args.out}.png")


if __name__ == "__main__":
    main()
