"""Prototype: the default with ``k`` chosen per point by a test on the fit residuals.

Usage::

    python -m benchmarks.scale_selection                      # 10,000 points, 8 shapes, 3 noises
    python -m benchmarks.scale_selection --sizes 30000 --shapes plane sphere --noise 0.005
    python -m benchmarks.scale_selection --dense                # the 12 cells of versus.md
    python -m benchmarks.scale_selection --sizes 10000 30000 --cubic 4   # with the cubic test
    python -m benchmarks.scale_selection --sizes 10000 30000 --library   # select_scales=True

Not part of the library: it measures a rule for docs/DECISIONS.md ("Sparse clouds") before it
is built into the kernels. The rule with ``--cubic 4`` is in the library as
``denoise(points, select_scales=True)`` (with the noise from a probe of the input and lists up
to 4.5 ``k``); ``--library`` runs that instead, in the same tables. Otherwise it runs
``denoise(points)`` at its defaults with the move of the feature-aware iterations replaced (and restores it afterwards); everything else, the probe
that picks ``k`` included, is the library's. Peer minima come from the cache of
``benchmarks.versus`` (its sized cells); results go to ``results/scale_selection_<sizes>.md``.

The rule, for each point and iteration:

1. Quadratic fits ``z = g(x, y)`` in the frame of the point and its filtered normal over the
   first ``s`` of its neighbours (nearest first), for ``s`` in ``SCALE_FACTORS`` times the
   pipeline's ``k``. Each neighbour weighs its normal agreement, flat in distance, so one pass
   over the longest list accumulates the normal equations of every scale.
2. Thin walls: where the default's own fit at ``k`` took its robust alternative (its list
   reaches across to another sheet), each neighbour also weighs ``exp(-(r / s)^2)``, ``r``
   its height above that fit and ``s`` the lower quartile of the point's own ``|r|`` over its
   ``k`` nearest, over 0.3186, so that the other sheet counts at no scale. Steps 1 and 2 are
   the library's kernel (:func:`pssd_fast.core.scale_fits`); until it was, the prototype had a
   kernel of its own and took ``s`` from the whole cloud (the cloud's median of the points'
   median ``|r|``, over 0.6745): the tables measured before commit 6523321 come from that
   version.
3. Walking up the scales from the smallest whose median list radius is at least
   ``RADIUS_OVER_NOISE`` times the noise at ``k`` (smaller lists cut the noise off and see too
   little of it), a scale is kept while the residual it adds per unit weight stays below
   ``sigma^2 (1 + TAU sqrt(2 / added weight))``: an F-test of "the quadratic still explains
   the wider list". The first scale that fails ends the walk. With ``--cubic TAU``, so does
   the first where the four cubic terms explain more than ``sigma^2 (1 + TAU sqrt(2 / 4))``
   each (a lack of fit the quadratic leaves: a detailed surface's wrinkles, where a sphere
   has none).
4. At the scale kept, the plane replaces the quadratic where the three curvature terms
   explain less than ``sigma^2 (1 + TAU_PLANE sqrt(2 / 3))`` each. Where they explain more,
   ``--curved`` (:data:`CURVED`) says which height the point takes: ``walked``, the
   quadratic at the scale kept; ``at-k``, the quadratic at the scale kept but no wider than
   ``k``; ``default``, the default's own fit. The test cannot tell a detailed surface's
   wrinkles from noise at the wider scales, and their quadratics flatten them.
5. ``sigma^2``: on the first iteration, the median residual variance (``rss / (weight - 6)``)
   at the scale the walk starts from; later iterations use ``LATER_NOISE`` times that value.
   The smoothing leaves far less noise than the input had (the same median falls to about 1%
   of it after one iteration), but what it leaves varies over wider lists than the small
   scales see, so measured again it would stop every walk early on a plane.

``--dense`` runs the cells of the dense table of ``benchmarks.versus`` (the paper's models
and the 100,000-point part) instead, at their sizes there.

``--sheets`` runs the two sheets of ``benchmarks.sheets`` (gaps of 4, 7.5 and 15 sigma)
instead, with and without the rule.
"""
import argparse
from contextlib import contextmanager
from pathlib import Path

import numpy as np

import pssd_fast
from pssd_fast import core
from pssd_fast.graph import knn_graph
from pssd_fast.pipelines import aware

from . import sheets, versus
from .stages import write_atomic

SCALE_FACTORS = (0.25, 0.5, 1.0, 2.0, 3.0)
TAU = 2.0
TAU_PLANE = 1.0
RADIUS_OVER_NOISE = 4.0
LATER_NOISE = 0.03
#: Where the plane test fails, the height a point takes (step 4 above), and the suffix of its
#: results' file names.
CURVED = {"walked": "", "at-k": "_at_k", "default": "_flat"}
RESULTS = Path(__file__).resolve().parent / "results"


class ScaleMove:
    """The replacement of ``aware.fit_and_move``; keeps the first iteration's noise, the
    scales each iteration kept (``kept``: counts per scale), the points whose lists
    reached across a thin wall (``across``: a count) and those given the plane (``flat``: a
    mask), and the scale each point kept (``picked``: columns of ``scales``, the list lengths).
    ``curved``: a key of :data:`CURVED`; ``cubic``: the ``TAU`` of the cubic test of step 3,
    or None for none."""

    def __init__(self, curved="walked", cubic=None):
        self.curved = curved
        self.cubic = cubic
        self.noise2 = None
        self.kept = []
        self.across = []
        self.flat = []
        self.picked = []
        self.scales = None

    def __call__(self, points, nrm, graph, sigma_n, clock, mass=None, walk=None, lists=None):
        n = points.shape[0]
        filtered = core.filter_normals(points, nrm, graph)
        k = graph.indices.shape[0] // n
        scales = np.array(sorted({max(8, round(f * k)) for f in SCALE_FACTORS}), np.int64)
        scales = scales[scales < n]
        lists = knn_graph(points, int(scales[-1]), False)
        default, _, _, coef, across = core.robust_fits(points, filtered, graph, sigma_n)
        fits = core.scale_fits(points, filtered, lists, scales, sigma_n, k, coef, across)
        # The prototype keeps the flat heights (the library's tapered ones are left out).
        quad, plane, rss, rss_plane, rss_cubic, weight, radius, _ = fits
        variance = fits.variance()
        at_k = min(int(np.searchsorted(scales, k)), len(scales) - 1)
        noise_at_k = np.sqrt(np.nanmedian(variance[:, at_k]))
        wide = np.flatnonzero(np.median(radius, axis=0) >= RADIUS_OVER_NOISE * noise_at_k)
        first = int(wide[0]) if len(wide) else len(scales) - 1
        if self.noise2 is None:
            self.noise2 = noise2 = float(np.nanmedian(variance[:, first]))
        else:
            noise2 = LATER_NOISE * self.noise2
        pick = np.full(n, first)
        going = np.isfinite(quad[:, first])
        for s in range(first + 1, len(scales)):
            added = np.maximum(weight[:, s] - weight[:, s - 1], 1e-9)
            rate = (rss[:, s] - rss[:, s - 1]) / added / noise2
            going &= np.isfinite(quad[:, s]) & (rate <= 1.0 + TAU * np.sqrt(2.0 / added))
            if self.cubic is not None:
                # Lack of fit: the four cubic terms explain more than noise at this scale.
                gain = (rss[:, s] - rss_cubic[:, s]) / 4.0 / noise2
                going &= ~(gain > 1.0 + self.cubic * np.sqrt(2.0 / 4.0))
            pick[going] = s
        rows = np.arange(n)
        self.kept.append(np.bincount(pick, minlength=len(scales)).tolist())
        self.picked.append(pick)
        self.scales = scales
        curvature = (rss_plane[rows, pick] - rss[rows, pick]) / 3.0 / noise2
        flat = np.isfinite(plane[rows, pick]) & (curvature <= 1.0 + TAU_PLANE * np.sqrt(2 / 3))
        if self.curved == "walked":
            height = quad[rows, pick]
        elif self.curved == "at-k":
            height = quad[rows, np.minimum(pick, at_k)]
        else:
            height = default
        height = np.where(flat, plane[rows, pick], height)
        walked = np.isfinite(height)
        height = np.where(walked, height, default)
        self.across.append(int(across.sum()))
        self.flat.append(flat)
        support = np.where(walked, radius[rows, pick], graph.list_radius())
        moved, held = core.project(points, filtered, height, support)
        rms = np.sqrt(rss[rows, pick] / np.maximum(weight[rows, pick], 1.0))
        return moved, filtered, rms, np.full(n, 6, np.int8), held, None


@contextmanager
def selected_scales(curved="walked", cubic=None):
    """The default pipeline with :class:`ScaleMove` in place of its move, inside the block."""
    original = aware.fit_and_move
    aware.fit_and_move = move = ScaleMove(curved, cubic)
    try:
        yield move
    finally:
        aware.fit_and_move = original


def _best(peers, column):
    """The lowest ``column`` of both peer families' settings; None where there is none."""
    values = [versus.best_of(peers[family], column)[0] for family in versus.FAMILIES]
    values = [v for v in values if v is not None]
    return min(values) if values else None


def _pair(scores):
    return " / ".join("-" if x is None else f"{x:.1f}" for x in scores)


def run_sheets(gaps=(4.0, 7.5, 15.0), n_points=50_000, curved="walked", library=False):
    """Mean distance of each point to its own sheet, in sigmas, without and with the rule."""
    lines = ["| gap (sigma) | default | with the rule |", "|---|---|---|"]
    for gap in gaps:
        points, height, clean_xy = sheets.sheets(n_points, gap)
        plain = sheets.score(pssd_fast.denoise(points).points, height, clean_xy)
        if library:
            rule = sheets.score(pssd_fast.denoise(points, select_scales=True).points, height,
                                clean_xy)
        else:
            with selected_scales(curved):
                rule = sheets.score(pssd_fast.denoise(points).points, height, clean_xy)
        lines.append(f"| {gap:g} | {plain:.2f} | {rule:.2f} |")
        print(lines[-1], flush=True)
    RESULTS.mkdir(exist_ok=True)
    name = "sheets" + ("_library" if library else CURVED[curved])
    write_atomic(RESULTS / f"scale_selection_{name}.md", "\n".join(lines) + "\n")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000])
    parser.add_argument("--shapes", nargs="+", default=list(versus.SIZED_SHAPES))
    parser.add_argument("--noise", type=float, nargs="+", default=list(versus.NOISE_LEVELS))
    parser.add_argument("--dense", action="store_true",
                        help="the cells of the dense table instead (versus.SHAPES, full size)")
    parser.add_argument("--sheets", action="store_true", help="the thin-wall case instead")
    parser.add_argument("--curved", choices=list(CURVED), default="walked",
                        help="the height where the plane test fails (step 4)")
    parser.add_argument("--library", action="store_true",
                        help="run the library's denoise(select_scales=True) as the rule")
    parser.add_argument("--cubic", type=float, default=None, metavar="TAU",
                        help="also end a walk where the cubic terms explain more than noise "
                             "(step 3); e.g. 4")
    args = parser.parse_args(argv)
    if args.sheets:
        return run_sheets(curved=args.curved, library=args.library)
    if args.dense:
        args.sizes, args.shapes = [None], list(versus.SHAPES)
    cache = versus.load_peer_cache()["cells"]
    lines = ["| shape | points | noise | default | with the rule | best peer | won |",
             "|---|---|---|---|---|---|---|"]
    won = total = 0
    for n_points in args.sizes:
        for shape in args.shapes:
            for noise in args.noise:
                case = versus.make_case(shape, noise, n_points)
                peers = cache[versus._key(shape, noise, n_points)]
                best = [_best(peers, col) for col in versus.COLUMNS]
                plain = case.score(pssd_fast.denoise(case.points).points)
                if args.library:
                    rule = case.score(pssd_fast.denoise(case.points, select_scales=True).points)
                else:
                    with selected_scales(args.curved, args.cubic):
                        rule = case.score(pssd_fast.denoise(case.points).points)
                ok = all(b is None or r < b for r, b in zip(rule, best))
                won += ok
                total += 1
                lines.append(f"| {shape} | {len(case.points):,} | {noise:.2%} | {_pair(plain)} | "
                             f"{_pair(rule)} | {_pair(best)} | {'yes' if ok else 'no'} |")
                print(lines[-1], flush=True)
    lines.append(f"\nCells won on both columns against both peers with the rule: {won} of {total}.")
    RESULTS.mkdir(exist_ok=True)
    name = "dense" if args.dense else "_".join(str(n) for n in args.sizes)
    name += CURVED[args.curved] + ("" if args.cubic is None else f"_cubic{args.cubic:g}")
    name = name + "_library" if args.library else name
    write_atomic(RESULTS / f"scale_selection_{name}.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
