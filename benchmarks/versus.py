"""Our defaults against the best-tuned CGAL peers, on the paper's models and generated shapes.

Usage::

    python -m benchmarks.versus                    # 4 shapes x 3 noise levels, cached peers
    python -m benchmarks.versus --refresh-peers    # re-run CGAL (about 15 min on 2 cores)
    python -m benchmarks.versus --shapes cad_part --noise 0.005
    python -m benchmarks.versus --sizes 10000 30000               # 8 shapes, sparse clouds
    python -m benchmarks.versus --sizes 10000 30000 --peers-only  # only fill the peer cache
    python -m benchmarks.versus --sizes 10000 --shapes sphere cube --noise 0.005
    python -m benchmarks.versus --sizes 10000 30000 --seed 1    # other draws: out of sample

Shapes: Fandisk, the dragon head and Igea as in Table 1 (``benchmarks.models``, paper point
counts, unit diagonal) and the library's generated CAD-like part
(``pssd_fast.datasets.cad_part``, 100,000 points). With ``--sizes`` every chosen shape is sampled
at each of the given point counts instead, and the shapes may also be the other generated ones
(plane, sphere, cylinder, cube; default: all eight). Noise: isotropic Gaussian, sigma 0.25%,
0.5% and 1% of the bounding-box diagonal, seed 0 (``--seed``: another draw of the noise, and
of the generated shapes' samples, whose cells are then out of sample; results go to
``..._seed<N>.md``). Errors in 1e-4 of the diagonal: *mean* is the mean point-to-surface
distance, *edge* the mean over points whose clean position lies within 1% of the diagonal of
an edge sharper than 30 degrees (none on the plane and the sphere: their edge cells are "-"
and not compared). Shapes in :data:`IN_SAMPLE` are marked in the tables (at seed 0 only).

Peers (``pip install ".[compare]"``): CGAL jet smoothing (k in {24, 48, 96}, 1 or 2 passes),
CGAL bilateral smoothing (k in {60, 120}, 3 passes), Open3D's ``smooth_mls`` (k in {24, 48,
96}, 1 or 2 passes) and Open3D's ``smooth_bilateral`` (k in {24, 48}, 1 or 3 passes,
``sigma_s`` half and ``sigma_r`` 0.1, 0.3 or 1 times the median distance to the k-th
neighbour). "Best" is taken strictly: for each family and each cell, the minimum over its
settings separately for the mean and for the edge column (the two minima may come from
different settings). Peer runs are deterministic and slow, so their scores are cached in
``benchmarks/results/versus_peers.json`` under "shape|noise" (sized cells: "shape|noise|N"); a
cached cell runs only the families it lacks, ``--refresh-peers`` recomputes them all.

Ours: ``denoise(points)`` at its defaults, ``preset="fast"`` and ``preset="paper"``. Times are
warm wall times divided by pykdtree's k=25 kNN query (tree build + query, points in Morton
order) measured in the same run; *per it.* is the default's mean iteration (all stages, the
noise probe that chooses ``k`` excluded). Results go to ``benchmarks/results/versus.md`` and
``.json``; with ``--sizes`` to ``versus_sparse.md`` and ``.json``.
"""
import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

import pssd_fast
from pssd_fast import datasets

from . import models
from .metrics import UNIT
from .stages import knn_query_seconds, machine, write_atomic, write_results

RESULTS = Path(__file__).resolve().parent / "results"
PEER_CACHE = RESULTS / "versus_peers.json"
#: Shapes of the dense run (paper point counts; ``CAD_POINTS`` for the part).
SHAPES = ("fandisk", "dragon", "igea", "cad_part")
#: Shapes of a sized run (``--sizes``): the paper's models and every generated shape.
SIZED_SHAPES = tuple(models.MODELS) + tuple(datasets.GENERATORS)
#: The shapes the default's constants were calibrated on: their cells are in-sample.
IN_SAMPLE = {"cad_part"}
NOISE_LEVELS = (0.0025, 0.005, 0.01)
CAD_POINTS = 100_000
def _passes(p):
    return f"{p} pass{'es' if p > 1 else ''}"


#: Peer family -> label -> keyword arguments.
PEER_SETTINGS = {
    "jet": {f"k={k}, {_passes(p)}": {"k": k, "passes": p} for k in (24, 48, 96) for p in (1, 2)},
    "bilateral": {f"k={k}, 3 passes": {"k": k, "passes": 3} for k in (60, 120)},
    "o3d_mls": {f"k={k}, {_passes(p)}": {"k": k, "passes": p}
                for k in (24, 48, 96) for p in (1, 2)},
    "o3d_bilateral": {f"k={k}, {_passes(p)}, sigma_r {r:g}": {"k": k, "passes": p,
                                                              "sigma_s": 0.5, "sigma_r": r}
                      for k in (24, 48) for p in (1, 3) for r in (0.1, 0.3, 1.0)},
}
#: Each family's wrapper in ``benchmarks.peers`` and its name in the tables.
PEER_CALLS = {"jet": "cgal_jet", "bilateral": "cgal_bilateral", "o3d_mls": "open3d_mls",
              "o3d_bilateral": "open3d_bilateral"}
PEER_NAMES = {"jet": "CGAL jet", "bilateral": "CGAL bilateral", "o3d_mls": "Open3D MLS",
              "o3d_bilateral": "Open3D bilateral"}
#: Short column heads of each family.
SHORT = {"jet": "jet", "bilateral": "bil.", "o3d_mls": "o3d MLS", "o3d_bilateral": "o3d bil."}
FAMILIES = tuple(PEER_SETTINGS)
COLUMNS = ("mean", "edge")


@dataclass(frozen=True)
class Case:
    """One cell: the noisy input and a scorer returning a score per name of ``columns``
    (here (mean, edge) in 1e-4 of the diagonal, edge None when no point lies near an edge),
    and the seed of its draw."""

    shape: str
    noise: float
    points: np.ndarray
    score: Callable[[np.ndarray], tuple]
    seed: int = 0
    columns: tuple = COLUMNS


def make_case(shape, noise, n_points=None, model_cache=None, seed=0):
    """The noisy input of ``shape`` at ``noise`` and its scorer.

    Parameters
    ----------
    shape : str
        A paper model (``models.MODELS``) or a generated shape (``datasets.GENERATORS``).
    noise : float
        Noise sigma as a fraction of the diagonal.
    n_points : int, optional
        Points; default the paper's count for a model, ``CAD_POINTS`` for a generated shape.
    model_cache : dict, optional
        (shape, n_points) -> loaded model, shared between the noise levels of one shape.
    seed : int
        The draw of the noise (and of a generated shape's samples; a model's stay fixed).
    """
    if shape in datasets.GENERATORS:
        return _generated_case(shape, noise, CAD_POINTS if n_points is None else n_points, seed)
    return _model_case(shape, noise, n_points, {} if model_cache is None else model_cache, seed)


def _generated_case(shape, noise, n_points, seed):
    """A generated shape, scored by its analytic distance in 1e-4 of its diagonal."""
    cloud = datasets.make(shape, n_points=n_points, noise=noise, seed=seed)
    near = cloud.edge_distance < models.EDGE_BAND * cloud.diagonal
    unit = UNIT * cloud.diagonal
    return Case(shape, noise, np.array(cloud.points),
                lambda points: _split(cloud.surface_distance(points) / unit, near), seed)


def _model_case(shape, noise, n_points, model_cache, seed):
    """A paper model (unit diagonal), scored by the distance to its mesh."""
    from .metrics import surface_distance
    if (shape, n_points) not in model_cache:
        model_cache[shape, n_points] = models.load(shape, n_points=n_points)
    model = model_cache[shape, n_points]
    near = model.edge_distance < models.EDGE_BAND
    return Case(shape, noise, model.noisy(noise, seed=seed),
                lambda points: _split(surface_distance(points, model.vertices, model.faces)
                                      / UNIT, near), seed)


def _split(dist, near):
    """(mean, edge) of the distances ``dist``; edge None when no point is ``near`` an edge."""
    return float(dist.mean()), float(dist[near].mean()) if near.any() else None


def _key(shape, noise, n_points=None, seed=0):
    """The peer-cache key of a cell: "shape|noise", "|N" for a sized cell and "|seedS" for a
    seed other than 0."""
    return (f"{shape}|{noise:g}" + ("" if n_points is None else f"|{n_points}")
            + ("" if seed == 0 else f"|seed{seed}"))


def load_peer_cache(path=PEER_CACHE):
    if path.exists():
        return json.loads(path.read_text())
    return {"machine": machine(), "cells": {}}


def peer_cell(case, key, cache_path, refresh, log, families=FAMILIES):
    """The peer scores of one cell from the cache, running those of ``families`` it lacks
    (all of them with ``refresh``) and caching them."""
    cached = {} if refresh else load_peer_cache(cache_path)["cells"].get(key, {})
    missing = [family for family in families if family not in cached]
    if not missing:
        return cached
    cell = {**cached, **run_peers(case, log, missing)}
    cache = load_peer_cache(cache_path)  # re-read: another run may have added cells meanwhile
    cache["cells"][key] = cell
    cache["machine"] = machine()
    cache_path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(cache_path, json.dumps(cache, indent=1))
    return cell


#: The library behind each family (``benchmarks.peers.available``'s names).
LIBRARY = {"jet": "cgal", "bilateral": "cgal", "o3d_mls": "open3d", "o3d_bilateral": "open3d"}


def missing_peers(families, instead="leave those peers out with --peers"):
    """A message naming the libraries ``families`` need that do not import, or ``""``
    (``instead``: what else the user can do)."""
    from . import peers
    have = peers.available()
    absent = sorted({LIBRARY[f] for f in families if not have[LIBRARY[f]]})
    if not absent:
        return ""
    return (f"the peers {', '.join(f for f in families if LIBRARY[f] in absent)} need "
            f"{' and '.join(absent)}, which do not import here: install them with "
            f"pip install \".[compare]\" (Open3D also needs the system's libusb-1.0), or "
            f"{instead}")


def check_inputs(parser, args, what, names):
    """Exit through ``parser`` where a file of ``names`` is not in ``args.data`` (naming
    ``what`` was not found) or a peer family of ``args.peers`` is not installed."""
    missing = [name for name in names if not (args.data / name).is_file()]
    if missing:
        parser.exit(1, f"{what} were not found in {args.data}: {', '.join(missing)} "
                       f"(pass --data or set PSSD_DATA)\n")
    absent = missing_peers(args.peers)
    if absent:
        parser.exit(1, absent + "\n")


def run_peers(case, log, families=FAMILIES):
    """Every setting of the peer ``families`` on one case: family -> label -> {each of
    ``case.columns``, seconds}."""
    from . import peers
    out = {}
    for family in families:
        call = getattr(peers, PEER_CALLS[family])
        out[family] = {}
        for label, kwargs in PEER_SETTINGS[family].items():
            result = call(case.points, **kwargs)
            scores = dict(zip(case.columns, case.score(result.points)))
            out[family][label] = {**scores, "seconds": result.seconds}
            log(f"  {PEER_NAMES[family]:16s} {label:26s} "
                + " ".join(f"{_fmt(value, 2):>7s}" for value in scores.values())
                + f" {result.seconds:7.2f} s")
    return out


def best_of(family_rows, column):
    """(value, label) of the setting with the lowest ``column``; (None, None) when the cell
    has no such score (no edge points)."""
    scored = {label: row[column] for label, row in family_rows.items()
              if row[column] is not None}
    if not scored:
        return None, None
    label = min(scored, key=scored.get)
    return scored[label], label


def best_entry(family_rows, columns=COLUMNS):
    """A family's minima: each column's value, the setting behind it and that setting's time;
    ``seconds`` is the time behind the first column."""
    entry = {}
    for col in columns:
        value, label = best_of(family_rows, col)
        entry.update({col: value, f"{col}_setting": label,
                      f"{col}_seconds": None if label is None else family_rows[label]["seconds"]})
    entry["seconds"] = entry[f"{columns[0]}_seconds"]
    return entry


def run_ours(case, preset, repeats=1):
    """Our method at a preset: scores, best wall time and iteration count."""
    seconds = np.inf
    for _ in range(repeats):
        started = time.perf_counter()
        result = pssd_fast.denoise(case.points, preset=preset)
        seconds = min(seconds, time.perf_counter() - started)
    mean, edge = case.score(result.points)
    per_iteration = [sum(r["times"].values()) for r in result.stats["iterations"]]
    probe = result.stats["auto_k"]
    return {"mean": mean, "edge": edge, "seconds": seconds,
            "iterations": result.stats["n_iterations"], "k": result.stats["k"],
            "iteration_seconds": float(np.mean(per_iteration)),
            "probe_seconds": None if probe is None else probe["seconds"]}


def knn_reference(points, k=25, repeats=3):
    """pykdtree's k=25 kNN query time (Morton order, best of ``repeats``)."""
    ordered = np.ascontiguousarray(points[pssd_fast.morton_order(points)])
    return min(knn_query_seconds(ordered, k) for _ in range(repeats))


def measure_row(case, peer_rows, repeats, log):
    """One table row: the noisy and our scores and times, and each peer family's minima."""
    noisy = case.score(case.points)
    row = {"shape": case.shape, "noise": case.noise, "points": len(case.points),
           "in_sample": case.shape in IN_SAMPLE and case.seed == 0, "seed": case.seed,
           "noisy": {"mean": noisy[0], "edge": noisy[1]},
           "knn_seconds": knn_reference(case.points)}
    for preset in ("default", "fast", "paper"):
        ours = row[preset] = run_ours(case, preset, repeats)
        log(f"  ours {preset:8s} {_fmt(ours['mean'], 2):>7s} {_fmt(ours['edge'], 2):>7s} "
            f"{ours['seconds']:7.2f} s")
    for family, settings in peer_rows.items():
        row[family] = best_entry(settings)
    return row


def _fmt(value, digits=1):
    return "-" if value is None else f"{value:.{digits}f}"


def _wl(ours, peer):
    """"win" / "lose" of ``ours`` against ``peer``; "-" when there is nothing to compare."""
    if ours is None or peer is None:
        return "-"
    return "win" if ours < peer else "lose"


def _pair(scores):
    return f"{_fmt(scores['mean'])} / {_fmt(scores['edge'])}"


def _lead(row, sized):
    """The first cells of a row: shape (marked when in-sample), points when sized, noise."""
    shape = row["shape"] + ("\\*" if row["shape"] in IN_SAMPLE else "")
    points = f" {row['points']:,} |" if sized else ""
    return f"| {shape} |{points} {row['noise']:.2%} |"


def _cell(row, sized):
    """A cell's name in the list of lost comparisons."""
    return " ".join([row["shape"]] + ([f"{row['points']:,} pts"] if sized else [])
                    + [f"{row['noise']:.2%}"])


def _comparisons(rows, sized):
    """(name, won) for each real comparison of our default against a peer family's minimum
    (none where either score is missing)."""
    return [(f"{_cell(r, sized)} {col} vs {fam}", r["default"][col] < r[fam][col])
            for r in rows for fam in FAMILIES for col in COLUMNS
            if r["default"][col] is not None and r[fam][col] is not None]


def _tally(rows, sized):
    """The count of comparisons won, naming the lost ones."""
    results = _comparisons(rows, sized)
    lost = [name for name, won in results if not won]
    return (f"Cells won: {len(results) - len(lost)} of {len(results)}."
            + (f" Lost: {'; '.join(lost)}." if lost else ""))


def markdown(rows, compile_seconds, sized=False):
    """The comparison table and the settings that gave each peer minimum (with a points
    column when ``sized``)."""
    lead = "| shape |" + (" points |" if sized else "") + " noise |"
    rule = "|---|---|" + ("---|" if sized else "")
    no_edge = any(r["noisy"]["edge"] is None for r in rows)
    seeds = sorted({r.get("seed", 0) for r in rows})
    peers_head = "".join(f" best {SHORT[f]} | W/L {SHORT[f]} |" for f in FAMILIES)
    peers_time = "".join(f" {SHORT[f]} / kNN |" for f in FAMILIES)
    out = [f"Machine: {machine()}. JIT compilation before timing: {compile_seconds:.1f} s. "
           f"Noise seed: {', '.join(map(str, seeds))}.", "",
           "Errors in 1e-4 of the bounding-box diagonal, *mean* / *edge* (points within 1% of "
           "the diagonal of an edge sharper than 30 degrees"
           + ("; \"-\" where a shape has none" if no_edge else "")
           + "). *Jet* / *Bil.*: the best CGAL jet (k 24, 48, 96; 1-2 passes) and CGAL "
           "bilateral (k 60, 120; 3 passes) result; *o3d MLS* / *o3d bil.*: the best Open3D "
           "`smooth_mls` (k 24, 48, 96; 1-2 passes) and `smooth_bilateral` (k 24, 48; 1 or 3 "
           "passes; 3 range widths) result; each the minimum over its settings taken "
           "separately for each column. *W/L*: win or lose of our default against that peer, "
           "mean then edge. Time: wall time divided by pykdtree's k=25 kNN "
           "query on the same points in the same run (*kNN* in seconds).", "",
           lead + " noisy | ours default (k) | ours paper |" + peers_head + " ours fast | "
           "kNN (s) | default / kNN | default per it. / kNN | fast / kNN | paper / kNN |"
           + peers_time,
           rule + "---|---|---|" + "---|---|" * len(FAMILIES) + "---|---|---|---|---|---|"
           + "---|" * len(FAMILIES)]
    for r in rows:
        d, p, f = r["default"], r["paper"], r["fast"]
        knn = r["knn_seconds"]
        versus = "".join(f" {_pair(r[fam])} | {_wl(d['mean'], r[fam]['mean'])} / "
                         f"{_wl(d['edge'], r[fam]['edge'])} |" for fam in FAMILIES)
        times = "".join(f" {r[fam]['seconds'] / knn:.0f} |" for fam in FAMILIES)
        out.append(
            f"{_lead(r, sized)} {_pair(r['noisy'])} | **{_pair(d)}** ({d['k']}) | "
            f"{_pair(p)} |{versus} {_pair(f)} | {knn:.3f} | "
            f"{d['seconds'] / knn:.0f} | {d['iteration_seconds'] / knn:.0f} | "
            f"{f['seconds'] / knn:.0f} | {p['seconds'] / knn:.0f} |{times}")
    out += ["", _tally(rows, sized)]
    out += ["", "Peer setting behind each minimum (mean / edge) and its time in seconds "
            "(peer times are cached with the scores, from the run that made the cache):", "",
            lead + "".join(f" {SHORT[f]} {col} |" for f in FAMILIES for col in COLUMNS),
            rule + "---|" * (len(FAMILIES) * len(COLUMNS))]
    for r in rows:
        cells = ["-" if r[fam][col + "_setting"] is None else
                 f"{r[fam][col + '_setting']} ({r[fam][col + '_seconds']:.1f} s)"
                 for fam in FAMILIES for col in COLUMNS]
        out.append(f"{_lead(r, sized)} " + " | ".join(cells) + " |")
    out += ["", "Time columns for the peers use the time of the setting behind the mean minimum; "
            "our times are the best of the runs made here, peers' from the cache."]
    if any(r["in_sample"] for r in rows):
        out += ["", "\\* In-sample: the default's constants were calibrated on this shape."]
    return "\n".join(out) + "\n"


def parse_args(argv=None):
    """The command line, with the shape list defaulted for the dense or the sized run."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shapes", nargs="+", choices=list(SIZED_SHAPES),
                        help=f"default {' '.join(SHAPES)}; with --sizes, all eight (the "
                             "generated plane, sphere, cylinder and cube only with --sizes)")
    parser.add_argument("--noise", type=float, nargs="+", default=list(NOISE_LEVELS))
    parser.add_argument("--sizes", type=int, nargs="+", metavar="N",
                        help="run every shape at each of these point counts (writes "
                             "versus_sparse.md/.json)")
    parser.add_argument("--refresh-peers", action="store_true",
                        help="re-run CGAL instead of using versus_peers.json")
    parser.add_argument("--peers-only", action="store_true", help="only fill the peer cache")
    parser.add_argument("--repeats", type=int, default=1, help="timed runs of ours per cell")
    parser.add_argument("--cad-points", type=int, default=CAD_POINTS,
                        help="points of the generated part without --sizes (its peers are "
                             "cached per size)")
    parser.add_argument("--out", type=Path, default=RESULTS,
                        help="folder for the results and the peer cache")
    parser.add_argument("--seed", type=int, default=0,
                        help="the draw of the noise (0: the cells the constants were chosen on)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    if args.shapes is None:
        args.shapes = list(SIZED_SHAPES if args.sizes else SHAPES)
    elif not args.sizes and not set(args.shapes) <= set(SHAPES):
        parser.error(f"without --sizes the shapes are {', '.join(SHAPES)}")
    asked = [shape for shape in args.shapes if shape in models.MODELS]
    if asked and not models.available(asked):
        parser.exit(1, models.missing("meshes", models.files(asked)) + "\n")
    return args


def cells(args):
    """(shape, noise, n_points, cache key) of every cell, in table order."""
    if args.sizes:
        return [(shape, noise, n, _key(shape, noise, n, args.seed))
                for shape in args.shapes for n in args.sizes for noise in args.noise]
    # The part's peers are cached per size: a size other than the table's is its own cell.
    return [(shape, noise, args.cad_points if shape == "cad_part" else None,
             _key(shape, noise, args.cad_points if shape == "cad_part"
                  and args.cad_points != CAD_POINTS else None, args.seed))
            for shape in args.shapes for noise in args.noise]


def main(argv=None):
    args = parse_args(argv)
    log = (lambda line: None) if args.quiet else print
    cache_path = args.out / PEER_CACHE.name
    cached = {} if args.refresh_peers else load_peer_cache(cache_path)["cells"]
    absent = missing_peers(sorted({family for *_, key in cells(args) for family in FAMILIES
                                   if family not in cached.get(key, {})}),
                           "use a peer cache (--out) that holds these cells")
    if absent:  # before any run: the table needs every family
        raise SystemExit(f"benchmarks.versus: {absent}")
    compile_seconds = None if args.peers_only else pssd_fast.warmup()
    model_cache = {}
    rows = []
    for shape, noise, n_points, key in cells(args):
        case = make_case(shape, noise, n_points, model_cache, args.seed)
        log(f"{shape} {noise:.2%} ({len(case.points)} points)")
        peer_rows = peer_cell(case, key, cache_path, args.refresh_peers, log)
        if not args.peers_only:
            rows.append(measure_row(case, peer_rows, args.repeats, log))
    if args.peers_only:
        return rows
    sized = bool(args.sizes)
    text = markdown(rows, compile_seconds, sized)
    stem = ("versus_sparse" if sized else "versus") + (f"_seed{args.seed}" if args.seed else "")
    write_results(args.out, stem, text,
                  {"compile_seconds": compile_seconds, "rows": rows}, indent=1)
    log(text)
    return rows


if __name__ == "__main__":
    main()
