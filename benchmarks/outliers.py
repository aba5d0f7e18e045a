"""Outlier removal: 100,000-point clouds with 2% uniform outliers.

For the generated sphere, cube and CAD part and the paper's models (Igea, Fandisk, the dragon
head; skipped when the mesh folder is absent), noise 0.25% of the diagonal, seed 0: outliers
uniform in the bounding box scaled by 1.2 about its centre. Columns: outliers flagged (all of
them, and those farther than 3 noise widths from the surface, which no local test can tell
from noisy surface points), surface points lost, the mean surface error of the kept surface
points after ``denoise(..., remove_outliers=True)`` over that of ``denoise`` on the cloud
without outliers, and the score's time over pykdtree's k=25 kNN query on the same points. The
CGAL columns run ``remove_outliers`` (k = 24, points farther on
average from their 24 nearest neighbours than twice the median of
that average) when the ``cgal`` package is installed.

Run: ``python -m benchmarks.outliers [--points N] [--out benchmarks/results]``.
"""
import argparse
import time
from pathlib import Path

import numpy as np
from pykdtree.kdtree import KDTree

import pssd_fast
from pssd_fast import datasets

from . import metrics, models
from .stages import write_results

SHAPES = ("sphere", "cube", "cad_part")
NOISE = 0.0025
FRACTION = 0.02


def with_outliers(points, fraction=FRACTION, seed=1):
    """``points`` followed by uniform outliers in the bounding box scaled by 1.2."""
    low, high = points.min(axis=0), points.max(axis=0)
    count = int(round(fraction * len(points)))
    extra = (low + high) / 2 + np.random.default_rng(seed).uniform(-0.6, 0.6, (count, 3)) * (
        high - low)
    return np.vstack([points, extra])


def cases(n_points):
    """(name, noisy surface points, sigma, distance function to the true surface)."""
    for name in SHAPES:
        cloud = datasets.make(name, n_points=n_points, noise=NOISE, seed=0)
        yield name, cloud.points, cloud.noise_sigma, cloud.surface_distance
    if models.available():
        for name in ("igea", "fandisk", "dragon"):
            model = models.load(name, n_points)
            sigma = NOISE  # the models have unit diagonal
            yield (name, model.noisy(sigma), sigma,
                   lambda p, m=model: metrics.surface_distance(p, m.vertices, m.faces))


def cgal_kept(points, k=24):
    """Rows CGAL's ``remove_outliers`` keeps, or None without cgal. CGAL removes points whose
    mean distance to their ``k`` nearest neighbours exceeds the threshold; it is set to twice
    the median of that mean over the cloud."""
    try:
        from CGAL import CGAL_Point_set_processing_3 as processing
        from CGAL.CGAL_Point_set_3 import Point_set_3
    except ImportError:
        return None
    spread = np.median(KDTree(points).query(points, k=k + 1)[0][:, 1:].mean(axis=1))
    point_set = Point_set_3()
    point_set.insert_range(points.ravel().tolist())
    processing.remove_outliers(point_set, k, threshold_percent=100.0,
                               threshold_distance=2.0 * float(spread))
    point_set.collect_garbage()
    left = np.array([(p.x(), p.y(), p.z()) for p in point_set.points()])
    dist, rows = KDTree(points).query(left, k=1)
    assert (dist == 0).all()
    return np.sort(rows.astype(np.int64))


def row(name, surface, sigma, distance):
    points = with_outliers(surface)
    n_surface = len(surface)
    started = time.perf_counter()
    KDTree(points).query(points, k=25)
    knn = time.perf_counter() - started
    started = time.perf_counter()
    score = pssd_fast.outlier_score(points)
    score_seconds = time.perf_counter() - started
    flagged = score > 1.0
    far = distance(points[n_surface:]) > 3 * sigma
    result = pssd_fast.denoise(points, remove_outliers=True)
    clean = pssd_fast.denoise(surface)
    kept_surface = result.kept < n_surface
    ratio = distance(result.points[kept_surface]).mean() / distance(clean.points).mean()
    out = {"shape": name, "points": len(points), "flagged": flagged[n_surface:].mean(),
           "flagged_far": flagged[n_surface:][far].mean(), "far_share": far.mean(),
           "surface_lost": flagged[:n_surface].mean(), "error_ratio": ratio,
           "score_seconds": score_seconds, "knn_seconds": knn}
    rows = cgal_kept(points)
    if rows is not None:
        removed = np.ones(len(points), bool)
        removed[rows] = False
        out.update(cgal_flagged=removed[n_surface:].mean(),
                   cgal_flagged_far=removed[n_surface:][far].mean(),
                   cgal_surface_lost=removed[:n_surface].mean())
    return out


def table(rows):
    cgal = all("cgal_flagged" in r for r in rows)
    head = ("| shape | points | outliers flagged | flagged, > 3 sigma off | surface lost | "
            "error ratio | score / kNN |" + (" CGAL flagged | CGAL > 3 sigma | CGAL surface lost |"
                                            if cgal else ""))
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        line = (f"| {r['shape']} | {r['points']:,} | {r['flagged']:.1%} | {r['flagged_far']:.1%} "
                f"({r['far_share']:.0%} of them) | {r['surface_lost']:.2%} | "
                f"{r['error_ratio']:.3f} | {r['score_seconds'] / r['knn_seconds']:.1f} |")
        if cgal:
            line += (f" {r['cgal_flagged']:.1%} | {r['cgal_flagged_far']:.1%} | "
                     f"{r['cgal_surface_lost']:.2%} |")
        lines.append(line)
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args(argv)
    pssd_fast.warmup()
    rows = []
    for case in cases(args.points):
        rows.append(row(*case))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    text = table(rows)
    print(text)
    write_results(args.out, "outliers", text, {"noise": NOISE, "fraction": FRACTION,
                                               "rows": rows})


if __name__ == "__main__":
    main()
