"""Every preset and method on the real LiDAR files, as a user would run them: how far the
largest move reaches, in units of the input's spacing, and what it costs.

Usage::

    python -m benchmarks.lidar                     # the files of $PSSD_DATA/lidar
    python -m benchmarks.lidar --folder DIR --tile-points 40000

For each ``.las``/``.laz`` file of the folder (``--folder``, else the ``lidar/`` folder of
``PSSD_DATA``: :func:`benchmarks.models.data_folder`) and each run of :data:`RUNS`: ``r16`` is
each point's distance to its 16th nearest other point of the input, the *largest move* the
largest ``displacement / r16``, *> 2 r16* the points past twice that, *held* the points whose
move was refused (docs/DECISIONS.md, "No point flung"). The presets that tile are also run by
``tiled.denoise`` (in memory) and ``tiled.denoise_file`` (the file itself, into a LAS file;
their moves measured on the output's quantised coordinates), with ``--tile-points`` per tile
(default: a third of the file's points).
Times are wall seconds and their ratio to pykdtree's k=25 kNN query of the same points in
Morton order, measured in the same run. Results go to ``benchmarks/results/lidar.md`` and
``.json``.
"""
import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from pykdtree.kdtree import KDTree

import pssd_fast
from pssd_fast import io

from .models import data_folder
from .stages import knn_query_seconds, write_results

RESULTS = Path(__file__).resolve().parent / "results"
#: Every preset and method, as a user would call them.
RUNS = {"default": {}, "fast": {"preset": "fast"}, "paper": {"preset": "paper"},
        "bilateral": {"method": "bilateral"}, "mls": {"method": "mls"}}
#: The runs that tiled runs take.
TILED = ("default", "fast")


def r16(points):
    """Each point's distance to its 16th nearest other point."""
    centred = points - points.mean(axis=0)
    return KDTree(centred).query(centred, k=17)[0][:, -1]


def row(file, run, how, moved, spacing, held, seconds, knn, same=None):
    ratio = moved / spacing
    return {"file": file, "run": run, "how": how, "largest": float(ratio.max()),
            "over_2": int((ratio > 2.0).sum()), "held": held, "seconds": seconds,
            "per_knn": seconds / knn, "same": same}


def measure(path, tile_points, log):
    """The rows of one file."""
    from pssd_fast import tiled

    points = io.read(path).points
    tile_points = tile_points or -(-points.shape[0] // 3)
    spacing = r16(points)
    knn = knn_query_seconds(points[pssd_fast.morton_order(points)] - points.mean(axis=0), 25)
    rows = []
    pssd_fast.denoise(points[:2000])  # compiled before the timings
    for run, options in RUNS.items():
        started = time.perf_counter()
        result = pssd_fast.denoise(points, **options)
        seconds = time.perf_counter() - started
        rows.append(row(path.name, run, "in core", result.displacement, spacing,
                        result.stats["held_points"], seconds, knn))
        log(rows[-1])
        if run not in TILED:
            continue
        started = time.perf_counter()
        tiles = tiled.denoise(points, tile_points=tile_points, client="sync", **options)
        rows.append(row(path.name, run, "tiled.denoise", tiles.displacement, spacing,
                        tiles.stats["held_points"], time.perf_counter() - started, knn,
                        bool(np.array_equal(tiles.points, result.points))))
        log(rows[-1])
        with tempfile.TemporaryDirectory() as folder:
            out = Path(folder) / f"out{path.suffix}"
            started = time.perf_counter()
            stats = tiled.denoise_file(path, out, tile_points=tile_points, client="sync",
                                       **options)
            seconds = time.perf_counter() - started
            written = io.read(out).points
            moved = np.linalg.norm(written - points, axis=1)
            # One tile is the in-core run, written to the same quantised coordinates.
            quantised = Path(folder) / f"in_core{path.suffix}"
            tiled.denoise_file(path, quantised, tile_points=points.shape[0], client="sync",
                               **options)
            equal = bool(np.array_equal(io.read(quantised).points, written))
        rows.append(row(path.name, run, "denoise_file", moved, spacing,
                        stats["held_points"], seconds, knn, equal))
        log(rows[-1])
    return rows, {"points": int(points.shape[0]), "knn_seconds": knn,
                  "duplicates": int(result.stats["duplicates"])}


def markdown(rows, files):
    lines = ["Every preset and method on the real LiDAR files (`python -m benchmarks.lidar`). "
             "*Largest move*: the largest displacement over the point's distance to its 16th "
             "nearest other input point (`r16`); *> 2 r16*: points moved farther than twice "
             "that; *held*: moves refused (for `denoise_file`, as its stats count them). "
             "Time: wall seconds and their ratio to pykdtree's k=25 kNN query of the same "
             "points in the same run.", ""]
    for name, info in files.items():
        lines.append(f"- `{name}`: {info['points']:,} points ({info['duplicates']:,} at the "
                     f"position of another), kNN query {info['knn_seconds']:.3f} s")
    lines += ["", "| file | run | how | largest move / r16 | > 2 r16 | held | seconds | "
              "/ kNN | same as in core |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        same = "-" if r.get("same") is None else ("yes" if r["same"] else "**no**")
        lines.append(f"| {r['file']} | {r['run']} | {r['how']} | {r['largest']:.2f} | "
                     f"{r['over_2']} | {r['held']} | {r['seconds']:.2f} | "
                     f"{r['per_knn']:.0f} | {same} |")
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--folder", type=Path, default=data_folder("lidar"))
    parser.add_argument("--tile-points", type=int, default=None)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    paths = sorted(p for p in args.folder.glob("*") if p.suffix.lower() in (".las", ".laz"))
    if not paths:
        raise SystemExit(f"no .las/.laz file in {args.folder}: pass --folder or set PSSD_DATA")
    rows, files = [], {}
    for path in paths:
        found, files[path.name] = measure(path, args.tile_points, print)
        rows += found
    text = markdown(rows, files)
    print(text)
    write_results(args.out, "lidar", text, {"files": files, "rows": rows})


if __name__ == "__main__":
    main()
