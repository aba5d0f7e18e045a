"""Two parallel sheets close together: does a denoiser keep them apart?

Usage::

    python -m benchmarks.sheets                       # gaps of 4, 7.5 and 15 sigma
    python -m benchmarks.sheets --gaps 4 7.5 --methods default paper

Two 1 x 1 sheets of ``--points`` points each (uniform), ``--gap`` noise deviations apart, with
isotropic Gaussian noise of ``sigma = 0.002``. The score is the mean distance of the points to
their own sheet, in units of ``sigma``, away from the borders (``0.1 <= x, y <= 0.9``): 0.80
for the noisy input; a denoiser that pulls the sheets together scores above it. Methods:
``default``, ``paper``, ``fast``, and CGAL's ``jet`` (k=48, 2 passes) and ``bilateral``
(k=120, 3 passes, sharpness 25 degrees; ``pip install cgal``). Writes
``sheets.md`` and ``.json`` into ``--out`` (``benchmarks/results``).
"""
import argparse
from pathlib import Path

import numpy as np

from .stages import RESULTS, machine, write_results

SIGMA = 0.002


def sheets(n_points, gap, seed=0):
    """Noisy points of two sheets ``gap`` sigmas apart, the height of each one's sheet and its
    position on the sheet before the noise."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 1.0, (2 * n_points, 2))
    height = np.repeat([0.0, gap * SIGMA], n_points)
    points = np.column_stack([xy, height]) + rng.normal(0.0, SIGMA, (2 * n_points, 3))
    return points, height, xy


def score(points, height, clean_xy):
    """Mean distance to the own sheet over the points away from the borders, in sigmas."""
    inside = ((clean_xy >= 0.1) & (clean_xy <= 0.9)).all(axis=1)
    return float(np.abs(points[inside, 2] - height[inside]).mean() / SIGMA)


#: The columns: the presets, then CGAL's jet smoothing (48 points, 2 passes) and bilateral.
METHODS = ("default", "paper", "fast", "jet", "bilateral")


def run(method, points):
    """The method's denoised points."""
    import pssd_fast

    if method in ("default", "fast", "paper"):
        return pssd_fast.denoise(points, preset=method).points
    from .peers import cgal_bilateral, cgal_jet

    if method == "jet":
        return cgal_jet(points, k=48, passes=2).points
    return cgal_bilateral(points).points


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gaps", type=float, nargs="+", default=[4.0, 7.5, 15.0])
    parser.add_argument("--points", type=int, default=50_000, help="points per sheet")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--out", type=Path, default=RESULTS,
                        help="folder for sheets.md/.json (benchmarks/results: the committed "
                             "results and docs/benchmarks.md's table)")
    args = parser.parse_args(argv)
    rows = []
    for gap in args.gaps:
        points, height, clean_xy = sheets(args.points, gap)
        row = {"gap": gap, "noisy": score(points, height, clean_xy)}
        for method in args.methods:
            row[method] = score(run(method, points), height, clean_xy)
        rows.append(row)
        print(", ".join(f"{k} {v:.2f}" for k, v in row.items()), flush=True)
    names = ["noisy", *args.methods]
    lines = ["| gap (sigma) | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for row in rows:
        lines.append(f"| {row['gap']:g} | " + " | ".join(f"{row[m]:.2f}" for m in names) + " |")
    text = (f"Machine: {machine()}\n\nTwo 1 x 1 sheets of {args.points:,} points each, "
            f"isotropic noise sigma = {SIGMA}; mean distance to the own sheet in sigmas, away "
            f"from the borders.\n\n" + "\n".join(lines) + "\n")
    print(text)
    write_results(args.out, "sheets", text, {"rows": rows, "points": args.points})


if __name__ == "__main__":
    main()
