"""The noise probe's calibration (:data:`pssd_fast.noise.CALIBRATION`), measured again.

Usage::

    python -m benchmarks.noise_probe --calibrate      # print the table, beside the library's

What a probe list's robust spread reads of a known noise: 80,000 uniformly random points of the
unit square with Gaussian heights of ``sigma``, at 14 noise levels from 0.009 down by a factor
1.3; for each list length of the probe, the mean list radius over ``sigma`` and the median
reading over ``sigma`` of the points away from the border (``0.15 < x, y < 0.85``), read as
:func:`pssd_fast.noise.probe` reads them. The rows print in the form of ``CALIBRATION``, each
with its ratio to the library's table at the same list radius.
"""
import argparse
import math

import numpy as np

from pssd_fast import core, morton_order, noise
from pssd_fast.graph import knn_graph

POINTS = 80_000
#: The largest noise and the factor between levels (14 levels: list radii 1 to 40 noise widths).
LEVELS = (0.009, 1.3, 14)


def measure(n_points=POINTS, levels=LEVELS, seed=0):
    """``{length: [(mean radius / sigma, median reading / sigma), ...]}``, noisiest first."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 1.0, (n_points, 2))
    lengths = np.array(noise.PROBE["lengths"], np.int64)
    rows = {int(k): [] for k in lengths}
    top, factor, count = levels
    for level in range(count):
        sigma = top / factor ** level
        points = np.column_stack([xy, rng.normal(0.0, sigma, n_points)])
        points = np.ascontiguousarray(points[morton_order(points)])
        scale, radius = core.local_noise(points, knn_graph(points, int(lengths[-1]), False),
                                         lengths)
        inner = ((points[:, :2] > 0.15) & (points[:, :2] < 0.85)).all(axis=1)
        for col, length in enumerate(lengths):
            rows[int(length)].append((float(radius[inner, col].mean() / sigma),
                                      float(np.median(scale[inner, col]) / sigma)))
    return rows


def against_library(rows):
    """Each measured reading over the library's table at the same list radius."""
    out = {}
    for length, pairs in rows.items():
        xs, fs = (np.log(np.array(column)) for column in zip(*noise.CALIBRATION[length]))
        out[length] = [read / math.exp(np.interp(math.log(x), xs, fs)) for x, read in pairs]
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.noise_probe",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--calibrate", action="store_true", required=True,
                        help="measure the calibration table again and print it")
    parser.add_argument("--points", type=int, default=POINTS)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rows = measure(args.points, seed=args.seed)
    ratios = against_library(rows)
    print("CALIBRATION = {")
    for length, pairs in rows.items():
        body = ", ".join(f"({x:.3g}, {f:.4g})" for x, f in pairs)
        print(f"    {length}: ({body}),")
    print("}")
    for length, values in ratios.items():
        print(f"# {length}: measured / library {min(values):.3f} to {max(values):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
