"""Per-stage time of one robust iteration, next to pykdtree's kNN query on the same points.

Usage::

    python -m benchmarks.stages [--sizes 100000 1000000] [--repeats 3] [--n-jobs N]

Prints a markdown table and writes it, with the raw numbers as JSON, to ``benchmarks/results/``.
Times are the best of ``--repeats`` warm runs (JIT compilation excluded and reported apart); the
ratio column divides by the kNN query time measured in the same run, because absolute times on
shared machines drift.
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np
from pykdtree.kdtree import KDTree

import pssd_fast
from pssd_fast import atomic, datasets

from . import report

RESULTS = Path(__file__).resolve().parent / "results"
STAGES = ("neighbors", "normals", "mls", "likelihood", "feature", "filter", "update")


def write_cad_part(n_points, noise, path):
    """The generated CAD part (seed 0) saved to ``path`` by a process of its own: a child's peak
    resident size starts at its parent's (Linux keeps ``ru_maxrss`` across fork and exec), so
    the process that starts the measured children must stay small."""
    subprocess.run([sys.executable, "-c", "import sys, numpy as np; from pssd_fast import "
                    "datasets; np.save(sys.argv[3], datasets.cad_part(n_points=int(sys.argv[1]), "
                    "noise=float(sys.argv[2]), seed=0).points)", str(n_points), repr(noise),
                    str(path)], check=True)


def cad_parts(sizes, noise, folder):
    """``(n, path)`` for each size: the CAD part of ``n`` points written into ``folder``
    (:func:`write_cad_part`)."""
    for n in sizes:
        path = Path(folder) / f"cad_{n}.npy"
        write_cad_part(n, noise, path)
        yield n, path


def add_output(parser, stem):
    """The options of a benchmark's results: ``--out`` (the folder), ``--stem`` (the files'
    name, ``stem`` by default) and ``--quiet``."""
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--stem", default=stem, help="name of the results files")
    parser.add_argument("--quiet", action="store_true")


def knn_query_seconds(points, k):
    """Wall time of building pykdtree's tree and querying every point's k neighbours."""
    started = time.perf_counter()
    KDTree(points).query(points, k=k)
    return time.perf_counter() - started


def reference_seconds(points, k):
    """The kNN query on the points as given and on the points in Morton order.

    The generated cloud comes in random order, where the query is several times slower than on
    spatially sorted points; the ratio column uses the faster (Morton-order) query, the stricter
    reference.
    """
    return {"knn_query_input_order": knn_query_seconds(points, k),
            "knn_query": knn_query_seconds(points[pssd_fast.morton_order(points)], k)}


def measure(n_points, k, repeats, n_jobs, noise):
    cloud = datasets.cad_part(n_points=n_points, noise=noise, seed=0)
    points = cloud.points
    best = {stage: np.inf for stage in STAGES}
    best["total"] = best["knn_query"] = best["knn_query_input_order"] = np.inf
    for _ in range(repeats):
        for name, seconds in reference_seconds(points, k).items():
            best[name] = min(best[name], seconds)
        started = time.perf_counter()
        result = pssd_fast.denoise(points, iterations=1, k=k, preset="paper", n_jobs=n_jobs)
        best["total"] = min(best["total"], time.perf_counter() - started)
        for stage, seconds in result.stats["iterations"][0]["times"].items():
            best[stage] = min(best[stage], seconds)
    return best


def machine():
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores "
            f"({numba.get_num_threads()} numba threads), Python {platform.python_version()}, "
            f"numba {numba.__version__}, numpy {np.__version__}")


def table(rows, k):
    head = ("| points | kNN query, input order (s) | kNN query, Morton order (s) | "
            + " | ".join(STAGES) + " | iteration (s) | iteration / kNN |")
    lines = [head, "|" + "---|" * (len(STAGES) + 5)]
    for n, t in rows.items():
        cells = " | ".join(f"{t[s]:.3f}" for s in STAGES)
        lines.append(f"| {n:,} | {t['knn_query_input_order']:.3f} | {t['knn_query']:.3f} | "
                     f"{cells} | {t['total']:.3f} | {t['total'] / t['knn_query']:.1f} |")
    return "\n".join(lines) + (f"\n\nStage times in seconds, one robust iteration of the "
                                f"paper's pipeline (preset 'paper'), k={k}.\n")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--k", type=int, default=25)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--n-jobs", type=int, default=None)
    parser.add_argument("--noise", type=float, default=0.005)
    args = parser.parse_args(argv)

    compile_seconds = pssd_fast.warmup()
    rows = {n: measure(n, args.k, args.repeats, args.n_jobs, args.noise) for n in args.sizes}
    text = (f"Machine: {machine()}\n\nInput: the generated CAD part, noise {args.noise:.2%} of "
            f"the diagonal. Warm-up (compile or cache load): {compile_seconds:.1f} s.\n\n"
            + table(rows, args.k))
    print(text)
    write_results(RESULTS, "stages", text,
                  {"k": args.k, "noise": args.noise, "compile_seconds": compile_seconds,
                   "seconds": {str(n): t for n, t in rows.items()}})


def save_rows(args, text, rows, compile_seconds, log):
    """Write a benchmark's ``text`` and ``rows`` as ``args.stem`` in ``args.out``
    (:func:`write_results`), pass the text to ``log`` and return the rows."""
    write_results(args.out, args.stem, text, {"compile_seconds": compile_seconds,
                                              "rows": rows}, indent=1)
    log(text)
    return rows


def write_results(folder, stem, text, data, indent=2):
    """``stem.md`` (``text``) and ``stem.json`` (``data`` with the machine first) in
    ``folder``, each written atomically; in ``benchmarks/results/``, docs/benchmarks.md's
    tables are then rebuilt (:func:`benchmarks.report.update`). Says so on stderr: a run
    into the committed results replaces them."""
    folder.mkdir(parents=True, exist_ok=True)
    write_atomic(folder / f"{stem}.md", text)
    write_atomic(folder / f"{stem}.json",
                 json.dumps({"machine": machine(), **data}, indent=indent))
    rebuilt = folder.resolve() == report.RESULTS
    if rebuilt:
        report.update()
    print(f"wrote {folder / stem}.md and .json" + (
        "; docs/benchmarks.md's tables rebuilt from benchmarks/results (--out elsewhere keeps "
        "them)" if rebuilt else ""), file=sys.stderr)


def positive(kind):
    """An argparse type: a number of ``kind`` (int or float) above 0, else argparse's one-line
    usage error naming the option."""
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"{text} is not above 0")
        return value
    parse.__name__ = f"positive {kind.__name__}"
    return parse


def child_result(command, env=None):
    """The JSON of the last line a benchmark's child process prints; where the child fails,
    the run stops with the child's own last line of error, not a CalledProcessError that
    hides it."""
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode:
        said = done.stderr.strip().splitlines()
        raise SystemExit(f"{command[2]} failed: "
                         f"{said[-1] if said else f'exit status {done.returncode}'}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def write_atomic(path, text):
    """Write ``text`` whole or not at all (:func:`pssd_fast.atomic.replacing`)."""
    with atomic.replacing(path) as fh:
        fh.write(text.encode())


if __name__ == "__main__":
    main()
