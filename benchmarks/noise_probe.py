"""The noise probe's calibration (:data:`pssd_fast.noise.CALIBRATION`), measured again.

Usage::

    python -m benchmarks.noise_probe --calibrate      # print the table, beside the library's
    python -m benchmarks.noise_probe --own            # the own fits' table (OWN_CALIBRATION)

What a probe list's robust spread reads of a known noise: 80,000 uniformly random points of the
unit square with Gaussian heights of ``sigma``, at 14 noise levels from 0.009 down by a factor
1.3; for each list length of the probe, the mean list radius over ``sigma`` and the median
reading over ``sigma`` of the points away from the border (``0.15 < x, y < 0.85``), read as
:func:`pssd_fast.noise.probe` reads them. The rows print in the form of ``CALIBRATION``, each
with its ratio to the library's table at the same list radius.

What the refinement's own fits read of a known noise (:data:`pssd_fast.noise.OWN_CALIBRATION`,
``--own``): 60,000 uniformly random points of the unit square with Gaussian heights of
``sigma``, at 9 noise levels from 0.3 to 5 spacings (none between 0.6 and 1.8, whose lists of
fewer than the longest points reach 4 noise widths as the longest do at 1.8, reading more);
the refinement's lists sized by the plan from the probe, their radius ``sqrt(k / pi)`` probe
spacings over ``sigma``, and the reading of :func:`pssd_fast.noise.own_sigma` (its root mean
variance, over the whole probe sample rather than its subsample) over ``sigma``, on the whole
plane.
"""
import argparse
import math

import numpy as np

from pssd_fast import core, method, morton_order, noise
from pssd_fast.graph import knn_graph

POINTS = 80_000
#: The largest noise and the factor between levels (14 levels: list radii 1 to 40 noise widths).
LEVELS = (0.009, 1.3, 14)
#: The own fits' planes: their points and noise levels, in spacings (the lists' radii 1.9 to
#: 12 noise widths, each a list length the plan caps: 160 points, or 40 at 0.3 and 0.6).
OWN_POINTS = 60_000
OWN_RATIOS = (0.3, 0.6, 1.8, 2.2, 2.6, 3.0, 3.5, 4.0, 5.0)


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


def measure_own(n_points=OWN_POINTS, ratios=OWN_RATIOS, seed=0):
    """``[(list radius / sigma, reading / sigma), ...]`` of the own fits' reading, noisiest
    first."""
    rng = np.random.default_rng(seed)
    rows = []
    for ratio in ratios:
        sigma = ratio / math.sqrt(n_points)
        points = np.column_stack([rng.uniform(0.0, 1.0, (n_points, 2)),
                                  rng.normal(0.0, sigma, n_points)])
        points = np.ascontiguousarray(points[morton_order(points)])
        taken = noise.sample(points)
        found = noise.probe(points, taken)
        k = min(method.list_length(found.sigma, found.spacing, 0.0, method.REFINE["radius"],
                                   method.REFINE["k"]), n_points - 1)
        radius = method.list_radius(k, found.spacing)
        # The whole probe sample: the expected reading, not one subsample's.
        variances = noise.sampled_variances(points, taken[0], k,
                                            method.list_bound(k, found.spacing, 0.0))
        read = math.sqrt(float(np.mean(variances[np.isfinite(variances)])))
        rows.append((radius / sigma, read / sigma))
    return sorted(rows)


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.noise_probe",
                                     description=__doc__.split("\n\n")[0])
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--calibrate", action="store_true",
                       help="measure the calibration table again and print it")
    which.add_argument("--own", action="store_true",
                       help="measure the own fits' table (OWN_CALIBRATION) again and print it")
    parser.add_argument("--points", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.own:
        pairs = measure_own(args.points or OWN_POINTS, seed=args.seed)
        print("OWN_CALIBRATION = (" + ", ".join(f"({x:.3g}, {f:.3g})" for x, f in pairs) + ")")
        xs, fs = (np.log(np.array(column)) for column in zip(*noise.OWN_CALIBRATION))
        ratios = [f / math.exp(np.interp(math.log(x), xs, fs)) for x, f in pairs]
        print(f"# measured / library {min(ratios):.3f} to {max(ratios):.3f}")
        return 0
    rows = measure(args.points or POINTS, seed=args.seed)
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
