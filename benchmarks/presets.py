"""Whole denoise runs of each preset at scan sizes: time, accuracy and memory.

Usage::

    python -m benchmarks.presets                                   # 1,000,000 points
    python -m benchmarks.presets --sizes 100000 1000000 --presets default fast paper
    python -m benchmarks.presets --sizes 30000 100000 --noises 0.0025 0.005 0.01 \
        --presets fast jet --out fast_vs_jet
    python -m benchmarks.presets --grid --presets default fast --threads 2 --jobs 7 \
        --out grid_baseline                        # the grid of sizes and noise levels
    python -m benchmarks.presets --grid --presets default fast --against grid_baseline \
        --out grid                                 # and the targets against a baseline

Each (size, noise, preset) cell runs in a fresh process: the child loads the generated CAD part
from a ``.npy`` file, compiles on small clouds, denoises the whole cloud with the preset's own
iterations (``--paper-iterations`` for "paper", 1 by default: the issue's target is one
iteration), reads its peak resident size, scores the result against the true surface and times
pykdtree's k=25 query on the same points in Morton order, the reference of the ratio column.
``jet`` is CGAL's jet smoothing with k=48 and 2 passes (``pip install cgal``), the peer the
``fast`` preset is measured against. Clouds under 1,000,000 points are denoised and queried
three times and the fastest of each kept (their times are a fraction of a second). Errors are
in 1e-4 of the bounding-box diagonal: the mean distance to the true surface over all points,
and over the points within 1% of the diagonal of a sharp edge. Writes
``benchmarks/results/presets.md`` and ``.json`` (``--out``), after every cell.

``--grid`` measures every size of :data:`GRID_SIZES` at every noise of :data:`GRID_NOISES`;
``--jobs`` runs that many cells at once, each with ``--threads`` threads (cells then share the
memory bandwidth; the ratio to the kNN query, measured in the same process, is the number to
read). ``--against STEM`` adds the targets of the default and of ``fast`` checked against the
cells of an earlier run (``benchmarks/results/STEM.json``): the default at most :data:`TARGETS`
``"default_queries"`` kNN queries (``"small_queries"`` on smaller clouds) and its mean and edge
errors at most ``"accuracy"`` times the better of the earlier default and ``fast`` in that
cell; ``fast`` at most ``"fast_queries"`` queries and never farther from the truth than its
input; and the exponent of the default's time from 10^5 to 10^7 points at each noise level and
the largest ratio of its cost between neighbouring sizes (no cliff); and, side by side in each
cell, the most accurate of the runs measured there within the default's cost target and the
cheapest within its accuracy target (what a target out of reach would cost)."""
import argparse
import concurrent.futures
import json
import math
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pssd_fast.run import stored

from .scaling import OUTPUTS, _resident_bytes
from .stages import (RESULTS, child_result, knn_query_seconds, machine, write_cad_part,
                     write_results)

UNIT = 1e-4


#: The peer of the ``fast`` preset: CGAL jet smoothing, k=48, 2 passes.
JET = {"k": 48, "passes": 2}
#: Below this many points the runs and the reference query are repeated (best of three).
REPEAT_BELOW = 1_000_000
#: The grid of ``--grid``: sizes, and noise levels as fractions of the diagonal.
GRID_SIZES = (10_000, 30_000, 100_000, 300_000, 1_000_000, 3_000_000, 10_000_000)
GRID_NOISES = (0.0005, 0.001, 0.0025, 0.005, 0.01)
#: What ``--against`` checks: kNN queries of the default (``small_queries`` below
#: ``small_below`` points) and of ``fast``, the default's errors over the better of the
#: baseline's default and ``fast``, the exponent of the default's time and the ratio of its cost
#: between neighbouring sizes.
TARGETS = {"default_queries": 8.0, "small_queries": 20.0, "small_below": 100_000,
           "fast_queries": 3.0, "accuracy": 1.05, "exponent": 1.1, "neighbours": 1.5}


def query_target(points):
    """The default's cost target, in kNN queries, for a cloud of ``points`` points."""
    return TARGETS["small_queries" if points < TARGETS["small_below"] else "default_queries"]


def child(path, noise, preset, iterations):
    """Measure one cell in this process; print the result as one JSON line."""
    from pssd_fast import datasets
    from pssd_fast.graph import morton_order

    points = np.load(path)
    repeats = 3 if len(points) < REPEAT_BELOW else 1
    if preset == "jet":
        from .peers import cgal_jet

        cgal_jet(points[:5000], **JET)
        rss_before = _resident_bytes()
        runs = [cgal_jet(points, **JET) for _ in range(repeats)]
        total = min(run.seconds for run in runs)
        denoised, stats, output = runs[-1].points, None, 0
    else:
        total, denoised, stats, output, rss_before = _denoise(points, preset, iterations,
                                                              repeats)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    cloud = datasets.cad_part(n_points=len(points), noise=noise, seed=0)
    edge = cloud.edge_distance < 0.01 * cloud.diagonal
    before = cloud.surface_distance(points) / UNIT
    after = cloud.surface_distance(denoised) / UNIT
    ordered = np.ascontiguousarray(points[morton_order(points)])
    knn = min(knn_query_seconds(ordered, 25) for _ in range(repeats))
    cell = {"total": total, "knn_query": knn, "k": JET["k"], "iterations": JET["passes"],
            "noise_estimate": None, "stages": {}, "probe_seconds": None, "cell_edge": None,
            "spacing": None}
    if stats is not None:
        stages = {}
        for record in stats["iterations"]:
            for stage, seconds in record["times"].items():
                stages[stage] = stages.get(stage, 0.0) + seconds
        probe, plan = stats["auto_k"], stats["plan"]
        cell.update({"k": stats["k"], "iterations": stats["n_iterations"],
                     "noise_estimate": stats["noise"], "stages": stages,
                     "probe_seconds": None if probe is None else probe["seconds"]})
        if plan.get("method") == "default":
            cell.update({"cell_edge": plan["cell_edge"],
                         "spacing": plan["noise"]["spacing"]})
    print(json.dumps({
        **cell, "mean_before": float(before.mean()), "edge_before": float(before[edge].mean()),
        "mean_after": float(after.mean()), "edge_after": float(after[edge].mean()),
        "peak_bytes": peak, "bytes_per_point": (peak - rss_before - output) / len(points)}))


def _denoise(points, preset, iterations, repeats):
    """The fastest of ``repeats`` runs of the preset, after compiling on small clouds: seconds,
    points, stats, the bytes of the result's arrays and the resident size before the runs."""
    import pssd_fast
    from pssd_fast import datasets

    run = {"iterations": iterations, "preset": preset}
    # Every kernel, then the preset's own calls (cells of one point and of several), compiled
    # or loaded before timing.
    pssd_fast.warmup()
    pssd_fast.denoise(points[:5000], **run)
    pssd_fast.denoise(datasets.cad_part(n_points=20000, noise=0.02, seed=1).points, **run)
    rss_before = _resident_bytes()
    total = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        result = pssd_fast.denoise(points, **run)
        total = min(total, time.perf_counter() - started)
    output = sum(a.nbytes for a in (stored(result, name) for name in OUTPUTS)
                 if isinstance(a, np.ndarray))
    return total, result.points, result.stats, output, rss_before


def measure(path, noise, preset, iterations, threads):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    return child_result([sys.executable, "-m", "benchmarks.presets", "--child", str(path),
                         "--noise", str(noise), "--presets", preset,
                         "--paper-iterations", str(iterations or 0)], env)


def table(cells):
    lines = ["| points | noise | threads | preset | cell edge / spacing | k | iterations | noisy "
             "mean / edge | denoised mean / edge | kNN k=25 (s) | total (s) | total / kNN | peak "
             "RSS (MB) | bytes/point |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        grid = "–" if not c.get("cell_edge") else f"{c['cell_edge'] / c['spacing']:.2f}"
        name = _name(c)
        lines.append(f"| {c['points']:,} | {c['noise']:.2%} | {c['threads']} | {name} | {grid} | "
                     f"{c['k']} | "
                     f"{c['iterations']} | {c['mean_before']:.1f} / {c['edge_before']:.1f} | "
                     f"{c['mean_after']:.1f} / {c['edge_after']:.1f} | {c['knn_query']:.3f} | "
                     f"{c['total']:.2f} | {c['total'] / c['knn_query']:.1f} | "
                     f"{c['peak_bytes'] / 1e6:.0f} | {c['bytes_per_point']:.0f} |")
    lines.append("")
    lines.append("Stage times (s, summed over the iterations; probe: the noise probe of k):")
    lines.append("")
    for c in cells:
        if c["preset"] == "jet":
            continue
        stages = ", ".join(f"{s} {t:.2f}" for s, t in c["stages"].items())
        probe = "" if c["probe_seconds"] is None else f"probe {c['probe_seconds']:.2f}, "
        lines.append(f"- {c['points']:,} points, {c['noise']:.2%}, {c['preset']}: {probe}"
                     f"{stages}")
    return "\n".join(lines) + "\n"


def _name(cell):
    """A cell's preset as the tables name it."""
    return {"jet": "CGAL jet"}.get(cell["preset"], cell["preset"])


def frontier(cells, baseline):
    """The ``--against`` side-by-side of each cell: of every run measured there, the best
    accuracy within the target cost and the cheapest within the target accuracy (the errors
    over the better of ``baseline``'s default and ``fast``; accuracy ranked by the worse of
    the two ratios)."""
    earlier = {(c["points"], c["noise"], c["preset"]): c for c in baseline}
    lines = ["| points | noise | best accuracy within the target cost | cheapest within the "
             "target accuracy |", "|---|---|---|---|"]
    for key in sorted({(c["points"], c["noise"]) for c in cells}):
        before = [earlier.get((*key, p)) for p in ("default", "fast")]
        if any(b is None for b in before):
            continue
        best = [min(b[f"{col}_after"] for b in before) for col in ("mean", "edge")]
        runs = []
        for c in cells:
            if (c["points"], c["noise"]) == key:
                ratio = max(c["mean_after"] / best[0], c["edge_after"] / best[1])
                runs.append((c["total"] / c["knn_query"], ratio, c))
        cheap = [r for r in runs if r[0] <= query_target(key[0])]
        exact = [r for r in runs if r[1] <= TARGETS["accuracy"]]
        columns = [min(cheap, key=lambda r: r[1]) if cheap else None,
                   min(exact, key=lambda r: r[0]) if exact else None]
        lines.append(f"| {key[0]:,} | {key[1]:.2%} | " + " | ".join(
            "none measured" if r is None else
            f"{_name(r[2])}: {r[0]:.1f} queries, {r[2]['mean_after']:.2f} / "
            f"{r[2]['edge_after']:.2f} ({r[1]:.2f} x)" for r in columns) + " |")
    return "\n".join(lines) + "\n"


def targets(cells, baseline):
    """The ``--against`` table: each cell of the default and of ``fast`` checked against
    :data:`TARGETS` (the default's errors against the better of ``baseline``'s default and
    ``fast`` in that cell), and the exponent of the default's time at each noise level."""
    earlier = {(c["points"], c["noise"], c["preset"]): c for c in baseline}
    lines = ["| points | noise | default / kNN | default mean / edge | best before mean / edge "
             "| ratio mean / edge | fast / kNN | fast mean / edge (noisy) | met |",
             "|---|---|---|---|---|---|---|---|---|"]
    met = total = 0
    for c in cells:
        if c["preset"] != "default":
            continue
        key = (c["points"], c["noise"])
        before = [earlier.get((*key, p)) for p in ("default", "fast")]
        fast = next((f for f in cells if (f["points"], f["noise"], f["preset"]) ==
                     (*key, "fast")), None)
        queries = c["total"] / c["knn_query"]
        ok = queries <= query_target(c["points"])
        best = ratio = None
        if all(b is not None for b in before):
            best = [min(b[f"{col}_after"] for b in before) for col in ("mean", "edge")]
            ratio = [c[f"{col}_after"] / b for col, b in zip(("mean", "edge"), best)]
            ok = ok and max(ratio) <= TARGETS["accuracy"]
        if fast is not None:
            ok = (ok and fast["total"] / fast["knn_query"] <= TARGETS["fast_queries"]
                  and fast["mean_after"] <= fast["mean_before"]
                  and fast["edge_after"] <= fast["edge_before"])
        met += ok
        total += 1
        lines.append(
            f"| {c['points']:,} | {c['noise']:.2%} | {queries:.1f} | {c['mean_after']:.2f} / "
            f"{c['edge_after']:.2f} | "
            + ("- | - | " if best is None else
               f"{best[0]:.2f} / {best[1]:.2f} | {ratio[0]:.2f} / {ratio[1]:.2f} | ")
            + ("- | - | " if fast is None else
               f"{fast['total'] / fast['knn_query']:.1f} | {fast['mean_after']:.2f} / "
               f"{fast['edge_after']:.2f} ({fast['mean_before']:.1f} / "
               f"{fast['edge_before']:.1f}) | ")
            + ("yes" if ok else "**no**") + " |")
    lines += ["", f"Cells meeting every target: {met} of {total}.", ""]
    for noise in sorted({c["noise"] for c in cells}):
        row = sorted((c["points"], c["total"]) for c in cells
                     if c["preset"] == "default" and c["noise"] == noise
                     and 100_000 <= c["points"] <= 10_000_000)
        if len(row) >= 2:
            (n0, t0), (n1, t1) = row[0], row[-1]
            exponent = math.log(t1 / t0) / math.log(n1 / n0)
            lines.append(f"- default's time at {noise:.2%} noise, {n0:,} to {n1:,} points: "
                         f"N^{exponent:.2f} (target at most N^{TARGETS['exponent']})")
        steps = [max(a / b, b / a) for a, b in zip(*(
            [c["total"] / c["knn_query"] for c in sorted(
                (c for c in cells if c["preset"] == "default" and c["noise"] == noise),
                key=lambda c: c["points"])][i:] for i in (0, 1)))]
        if steps:
            lines.append(f"- default's cost per point at {noise:.2%} noise between neighbouring "
                         f"sizes: at most {max(steps):.2f}x (target at most "
                         f"{TARGETS['neighbours']}x)")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000_000])
    parser.add_argument("--presets", nargs="+", default=["default", "fast", "paper"])
    parser.add_argument("--paper-iterations", type=int, default=1,
                        help="iterations of preset 'paper' (0: the preset's own)")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--noises", type=float, nargs="+", default=[0.005],
                        help="noise levels, fractions of the diagonal")
    parser.add_argument("--grid", action="store_true",
                        help="every size of GRID_SIZES at every noise of GRID_NOISES")
    parser.add_argument("--jobs", type=int, default=1, help="cells measured at once")
    parser.add_argument("--against", metavar="STEM",
                        help="check the targets against benchmarks/results/STEM.json")
    parser.add_argument("--noise", type=float, help=argparse.SUPPRESS)  # the child's
    parser.add_argument("--out", default="presets", help="file stem in benchmarks/results/")
    parser.add_argument("--keep", nargs="+", default=[], metavar="PRESET",
                        help="presets whose cells are taken from the earlier results of --out "
                             "instead of being measured again (e.g. jet)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        preset = args.presets[0]
        iterations = args.paper_iterations if preset == "paper" else 0
        child(args.child, args.noise, preset, iterations or None)
        return
    if args.grid:
        args.sizes, args.noises = list(GRID_SIZES), list(GRID_NOISES)
    if args.against is not None and not (RESULTS / f"{args.against}.json").is_file():
        parser.error(f"--against {args.against}: no {RESULTS / args.against}.json (the stems "
                     f"there: {', '.join(sorted(p.stem for p in RESULTS.glob('*.json')))})")
    baseline = None if args.against is None else json.loads(
        (RESULTS / f"{args.against}.json").read_text())["cells"]

    kept = []
    if args.keep:
        earlier = json.loads((RESULTS / f"{args.out}.json").read_text())["cells"]
        kept = [c for c in earlier if c["preset"] in args.keep]
    cells = {}
    order = [(n, noise, preset) for n in args.sizes for noise in args.noises
             for preset in args.presets]

    def save():
        done = [cells[key] for key in order if key in cells]
        text = (f"Machine: {machine()}\n\nInput: the generated CAD part, seed 0; noise in % of "
                f"the diagonal; one process per cell ({args.jobs} at once); CGAL jet: "
                f"k={JET['k']}, {JET['passes']} passes.\n\n" + table(done))
        if baseline is not None:
            text += (f"\nTargets against `{args.against}` (the default at most "
                     f"{TARGETS['default_queries']:g} kNN queries, "
                     f"{TARGETS['small_queries']:g} below {TARGETS['small_below']:,} points, "
                     f"its errors at most "
                     f"{TARGETS['accuracy']} times the better of that run's default and fast; "
                     f"fast at most {TARGETS['fast_queries']:g} queries and no farther from the "
                     f"truth than its input):\n\n" + targets(done, baseline)
                     + "\nEach cell's runs side by side: the most accurate within the "
                     "default's cost target, the cheapest within "
                     f"{TARGETS['accuracy']} times the better errors of `{args.against}` "
                     "(x: the worse of the two error ratios):\n\n" + frontier(done, baseline))
        write_results(RESULTS, args.out, text, {"noises": args.noises, "cells": done})
        return text

    def run(n, noise, path):
        todo = []
        for preset in args.presets:
            reused = [c for c in kept if (c["points"], c["noise"], c["preset"]) ==
                      (n, noise, preset)]
            if reused:
                cells[(n, noise, preset)] = reused[0]
            else:
                todo.append(preset)
        if todo:
            write_cad_part(n, noise, path)
        for preset in todo:
            cell = {"points": n, "noise": noise, "threads": args.threads, "preset": preset,
                    **measure(path, noise, preset, args.paper_iterations, args.threads)}
            cells[(n, noise, preset)] = cell
            print(f"{n:>10,} points {noise:.2%} {preset:>8}: {cell['total']:8.2f} s "
                  f"({cell['total'] / cell['knn_query']:.1f}x kNN), error "
                  f"{cell['mean_after']:.1f} / {cell['edge_after']:.1f}", flush=True)
        path.unlink(missing_ok=True)

    with tempfile.TemporaryDirectory() as scratch, \
            concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        # The largest clouds first, so that the long cells overlap the short ones.
        futures = [pool.submit(run, n, noise, Path(scratch) / f"cloud_{n}_{noise}.npy")
                   for n in sorted(args.sizes, reverse=args.jobs > 1) for noise in args.noises]
        for future in concurrent.futures.as_completed(futures):
            future.result()
            save()
    print(save())


if __name__ == "__main__":
    main()
