"""What the likelihood and the feature intensity cost when a result's field is first read.

Usage::

    python -m benchmarks.fields                       # 100,000 and 1,000,000 points
    python -m benchmarks.fields --sizes 300000 --noise 0.005

Under presets "default" and "fast" ``pssd_fast.denoise`` computes ``result.likelihood`` and
``result.feature_intensity`` when they are first read (or during the run with
``extras=True``). On the generated CAD part (after ``pssd_fast.warmup()``, in one process):
the run's seconds, then the first read of each field, each next to the run and to pykdtree's
k=25 query of the same Morton-sorted points.

Results: ``benchmarks/results/fields.md`` and ``.json``.
"""
import argparse
import time
from pathlib import Path

import numpy as np

import pssd_fast
from pssd_fast import datasets

from .stages import knn_query_seconds, write_results

RESULTS = Path(__file__).resolve().parent / "results"


def measure(n, noise, preset):
    """One row: the run's and each field's first read's seconds, and the kNN query's."""
    points = np.asarray(datasets.cad_part(n_points=n, noise=noise, seed=0).points)
    knn = knn_query_seconds(points[pssd_fast.morton_order(points)], 25)
    started = time.perf_counter()
    result = pssd_fast.denoise(points, preset=preset)
    row = {"points": n, "noise": noise, "preset": preset, "knn": knn,
           "run": time.perf_counter() - started}
    for name in ("likelihood", "feature_intensity"):
        started = time.perf_counter()
        getattr(result, name)
        row[name] = time.perf_counter() - started
    return row


def table(rows):
    lines = ["| points | noise | preset | run (s) | likelihood (s) | feature intensity (s) | "
             "feature / run | feature / kNN |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['points']:,} | {r['noise']:.2%} | {r['preset']} | {r['run']:.2f} | "
                     f"{r['likelihood']:.3f} | {r['feature_intensity']:.2f} | "
                     f"{r['feature_intensity'] / r['run']:.2f} | "
                     f"{r['feature_intensity'] / r['knn']:.1f} |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--noise", type=float, default=0.0025)
    parser.add_argument("--presets", nargs="+", default=["default"])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    pssd_fast.warmup()
    rows = [measure(n, args.noise, preset) for n in args.sizes for preset in args.presets]
    text = table(rows)
    print(text)
    write_results(args.out, "fields", text + "\n", {"rows": rows})


if __name__ == "__main__":
    main()
