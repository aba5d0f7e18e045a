"""`denoise`: resolves the parameters, then runs the iterations of the chosen pipeline."""
import functools
import numbers
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from . import core, duplicates, inputs, stages
from . import plan as planning
from ._threads import threads
from ._validation import (
    MIN_K, as_normals, as_points, check_choice, check_float, check_int, check_k, check_orient,
    check_size,
)
from .graph import bounds, knn_graph, refresh_graph, truncate_graph
from .kernels.order import gather_rows, scatter_rows
from .pipelines import STEPS, coarse, edges, scales
from .plan import PRESETS
from .progress import Clock, reporter

#: Parameters of each method beyond the common ones, with their defaults.
METHOD_DEFAULTS = {
    "robust": {"h": None, **core.FEATURE_DEFAULTS, "likelihood": "exp", "sigma_n": 0.05,
               "shift_normals": True, "select_scales": None, "keep_normals": False},
    "bilateral": {"sigma_c": None, "sigma_s": None, "keep_normals": False},
    "mls": {"h": None, "keep_normals": False},
}
#: Methods :func:`denoise` offers.
METHODS = tuple(METHOD_DEFAULTS)
#: Robust-method parameters that only the paper's pipeline uses, and those only the
#: feature-aware pipeline uses.
PAPER_ONLY = ("h", "radius_factor", "delta", "alpha", "beta", "likelihood")
AWARE_ONLY = ("sigma_n", "shift_normals", "select_scales")


@dataclass(frozen=True, eq=False)
class DenoiseResult:
    """Output of :func:`denoise`; arrays are in the caller's point order and float dtype.

    Results compare by identity; compare their arrays with :func:`numpy.array_equal`.

    Attributes
    ----------
    points : (n, 3) ndarray
        Denoised positions.
    normals : (n, 3) ndarray
        Robust method: the filtered unit normals ``n*_i`` of the last iteration. Baselines: the
        normals the last iteration used.
    likelihood : (n,) ndarray or None
        Sampling likelihood ``l_i`` of the last iteration (robust method only; the
        feature-aware presets compute it from the RMS residual of their fit).
    feature_intensity : (n,) ndarray or None
        Feature intensity ``s_i`` of the last iteration (robust method only).
    displacement : (n,) ndarray
        ``|p_noisy - p_denoised|``, the quantity of the paper's Table 1 and Fig. 8.
    held : (n,) bool ndarray
        Where a move of the point was refused and the point kept its place instead: a move
        that was not finite, or longer than the radius of the neighbour list behind it (on the
        points, in any iteration; on the cell means of the coarse-to-fine route, in the last
        step onto their fits). ``stats["held_points"]`` counts them (docs/DECISIONS.md, "No
        point flung").
    outlier_score : (n,) ndarray
        :func:`pssd_fast.outlier_score` of the input points (before any iteration, ``k = 64``);
        above 1: flagged as an outlier. Computed on first access (a query of 64 neighbours,
        about 2-4 times the run's cheapest kNN query), unless ``remove_outliers=True`` needed
        it already.
    kept : (n,) int64 ndarray
        Rows of the input that the other arrays hold, in increasing order: every row, or with
        ``remove_outliers=True`` those scoring at most 1 (so ``points[kept]`` is what was
        denoised and ``outlier_score`` has one value per kept row).
    stats : dict
        ``"iterations"``: one dict per iteration with per-stage wall times in seconds
        (``"times"``), the derived scales (``h``, ``mean_spacing``, ``region_radius``,
        ``mean_residual``), fallback counts (``fit_degree`` counts of cubic, quadratic and
        plane fits; ``degenerate_normals``; ``held_points``, points left in place because their
        step was not finite or longer than its list's radius), region sizes and the mean step;
        plus the run's settings (``"k"``; ``"pipeline"``: "paper" or "aware"; ``"plan"``: the
        route ("cells", "points" or "walks"), ``k``, ``rebuild_graph`` and ``select_scales``
        the run took, docs/ALGORITHM.md, "Routes"; ``"auto_k"``:
        the noise probe behind a ``k`` chosen from the data, else None, with ``"coarse"``: the
        cells of the coarse-to-fine route and its final fit, else None; ``"noise"``: the noise
        it estimated, else None), ``"duplicates"`` (rows merged into another at their position,
        :mod:`pssd_fast.duplicates`), ``"held_points"`` (the points of ``held``) and
        ``"total_seconds"``. JSON-serialisable.
    """

    points: np.ndarray
    normals: np.ndarray
    likelihood: Optional[np.ndarray]
    feature_intensity: Optional[np.ndarray]
    displacement: np.ndarray
    held: np.ndarray
    kept: np.ndarray
    stats: dict = field(repr=False)
    # The score once known, else what computes it: the input rows the result holds and n_jobs,
    # or a function.
    _outliers: object = field(default=None, repr=False, compare=False)

    @functools.cached_property
    def outlier_score(self):
        if isinstance(self._outliers, np.ndarray):
            return self._outliers
        if callable(self._outliers):
            return self._outliers()
        points, n_jobs = self._outliers
        return stages.outlier_score(points, n_jobs=n_jobs)


def denoise(points, normals=None, *, method="robust", iterations=None, k=None, lam=None,
            preset="default", rebuild_graph=None, orient=None, remove_outliers=False,
            classification=None, classes=None, n_jobs=None, progress=None, **method_params):
    """Denoise a point-sampled surface while keeping its sharp features.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Noisy coordinates, float32 or float64 (other real dtypes are computed as float64).
        Never modified.
    normals : array_like, shape (n, 3), optional
        Normals of the input points (any length but zero; only local sign consistency matters).
        Used in the first iteration (in every iteration with ``keep_normals=True``); otherwise
        normals are estimated by PCA from the current positions in each iteration, oriented
        like the previous ones.
    method : {"robust", "bilateral", "mls"}, default "robust"
        ``"robust"``: the paper's method (``preset="paper"``) or the library's feature-aware
        refinement of it (the other presets, see Notes). The paper's two baselines (Section 5,
        docs/ALGORITHM.md): ``"bilateral"`` (BIL) moves each point along its normal by the bilateral
        mean of its neighbours' heights; ``"mls"`` moves it to its MLS projection ``q_i``.
    iterations : int, optional
        Number of passes; each recomputes everything from the current positions. Default from
        ``preset``: 4 ("default"; 2 on "fast"'s cells, see ``preset``), 2 ("fast", "paper";
        the paper uses 1 to 3).
    k : int, optional
        Neighbourhood size including the point itself (paper Section 2.2: ``k in [20, 35]``);
        at least 10 and at most ``n - 1``. Default from ``preset``: chosen from the estimated
        noise ("default": 64 to 160 on the input, see ``pssd_fast.pipelines.aware.AUTO_K``, or
        96 to 128 on cell means; "fast": 64 to 96 on cell means), 25 ("paper"). Given, the
        iterations run on the input points with that ``k``.
    lam : float, optional
        ``lambda`` in [0, 1] of Section 4.2: weight of the likelihood term against the feature
        term in the step ``m_i``. Paper's pipeline only (default 0.5); the other presets and
        the baselines refuse it, since their move does not use it.
    preset : {"default", "fast", "paper"}, default "default"
        ``"paper"``: the paper's formulation (k = 25, lambda = 0.5, 2 iterations; the Notes'
        first paragraph). ``"default"``: the feature-aware pipeline (Notes), ``k`` from the
        estimated noise, 4 iterations; chosen on generated shapes to beat CGAL's jet and
        bilateral smoothing (docs/DECISIONS.md; docs/benchmarks.md, "Beyond the paper");
        where the noise spans several point spacings it iterates on cell means (Notes).
        Above 50,000 points, where "fast"'s probe finds the noise at most 0.3 of its list
        radius, it takes "fast"'s cells and iterations, and then the points near features
        iterate on their own lists (the edges route; docs/ALGORITHM.md, "Routes").
        ``"fast"``: the same pipeline, always on cell means (of at least 3 points), 2
        iterations and a cheaper noise probe. For the baselines a preset sets ``k`` ("default" and "fast": from the noise
        probe; "fast" 48), ``iterations`` and ``rebuild_graph``.
    rebuild_graph : bool, optional
        ``True``: query the k nearest neighbours anew in every iteration. ``False``: later
        iterations keep the first iteration's lists, re-sorted by the current distances (one
        kNN query in all; see docs/DECISIONS.md for what it changes). Default from
        ``preset``: on the input points True ("default", "paper") or False ("fast"); on cell
        means False, except "fast" from 13 points a cell.
    orient : {"outward", "up"} or array_like of shape (3,), optional
        Sign of the first iteration's PCA normals (later iterations follow it):
        made consistent by propagation over the neighbour graph, then each connected
        component turned outward, up (``+z``) or towards a viewpoint on balance (see
        :func:`pssd_fast.estimate_normals`). ``None`` (default): each normal away from the
        cloud's centroid, as before (docs/DECISIONS.md, "Normal orientation"). Not with
        ``normals``, whose signs are the caller's. The positions do not depend on it.
    remove_outliers : bool, default False
        Drop the points whose ``outlier_score`` exceeds 1 before denoising; ``kept`` says
        which input rows the result holds.
    classification : array_like of int, shape (n,), optional
        A class code per point, such as the LAS ``classification`` (2 ground, 6 building...);
        only with ``classes``.
    classes : iterable of int, optional
        Denoise only the points whose ``classification`` is one of these. The others are no
        point's neighbours and keep their exact coordinates (and given normals; else NaN
        normals), NaN ``likelihood``, ``feature_intensity`` and ``outlier_score``, and zero
        ``displacement``; ``remove_outliers`` drops outliers among the chosen points only.
        ``stats["classes"]`` counts both. Default: every point.
    n_jobs : int or None, default None
        Threads for the kernels: ``None`` or -1 use every thread numba may use (by default one
        per core), a positive number that many (capped at that maximum). Numba's setting is
        restored afterwards. The output does not depend on it.
    progress : bool or callable, optional
        ``True`` prints a line per stage and iteration on stderr; a callable is called as
        ``progress(iteration, iterations, stage, seconds)`` after each stage; default silent.
    **method_params
        Parameters of the chosen method (docs/ALGORITHM.md). ``"robust"``:

        h : float, optional
            MLS Gaussian width (Section 2.1); default: mean distance to the k-th neighbour.
        radius_factor : float, default 10
            ``R = radius_factor * |E|`` for the region-grown ``N_R`` (Section 3).
        delta, alpha, beta : float, default 0.2, 0.3, 0.3
            Thresholds of eq. (3).
        likelihood : {"exp", "ratio", "residual"}, default "exp"
            Form of the sampling likelihood, eq. (2) (see :func:`sampling_likelihood`).
        keep_normals : bool, default False
            Use the given ``normals`` in every iteration instead of re-estimating them.
        sigma_n : float, default 0.05
            Width of the normal-agreement weight of the feature-aware fit (presets "default"
            and "fast" only): a neighbour ``j`` counts ``exp(-((1 - |n*_i . n*_j|) / sigma_n)^2)``
            times its distance weight.
        shift_normals : bool, default True
            In the first iteration of the feature-aware pipeline (presets "default" and
            "fast"), each point takes the normal of the flattest neighbour list, among those of
            its nearest quarter of ``k``, whose plane passes near it, instead of its own list's:
            beside a sharp edge, a list that does not reach across it (docs/ALGORITHM.md,
            "Shifted normals"). No effect where ``normals`` are given.
        select_scales : bool or None, default None
            Feature-aware pipeline, on the points (not on the cell means of the
            coarse-to-fine route): each point fits nested quadratics over prefixes of a list
            of ``4.5 k`` and keeps the widest that still fits its neighbours within the noise,
            instead of the fit at ``k`` (docs/ALGORITHM.md, "A scale per point"). ``None``:
            on where preset "default" iterates on the points of a cloud of at most 50,000
            points (after ``remove_outliers``), where it wins the sparse clouds the fit at
            ``k`` loses to CGAL (docs/benchmarks.md, "Sparse clouds"); off otherwise. It
            costs a kNN query and a fit over lists of ``4.5 k`` an iteration (about 9 times
            the fit at ``k`` at 30,000 points; with ``rebuild_graph=False`` the lists are
            queried once and re-sorted later, 2 to 3 times faster).
            ``stats["params"]["select_scales"]`` says whether a run took it, ``stats["scales"]`` what the probe set, each iteration's
            record what the walks kept. The tiled runs of :mod:`pssd_fast.tiled` take it too.

        ``h``, ``radius_factor``, ``delta``, ``alpha``, ``beta`` and ``likelihood`` shape the
        paper's pipeline only; the other presets refuse them (ValueError) rather than ignore
        them.

        ``"mls"``: ``h`` and ``keep_normals`` as above. ``"bilateral"``: ``keep_normals`` and

        sigma_c, sigma_s : float, optional
            Spatial and height widths of the bilateral weights; default, per point: half the
            list radius and the standard deviation of the neighbours' heights.

    Returns
    -------
    DenoiseResult

    Raises
    ------
    TypeError
        Non-numeric or complex points, non-integer ``k``, ``iterations`` or ``n_jobs``, or an
        unknown keyword in ``method_params``.
    ValueError
        Wrong shapes, NaN or Inf, too few points for ``k`` (a cloud needs at least 11; with
        ``k`` not given the message names the cloud's size and the preset's ``k``), parameters
        out of range, and parameters the method or the preset's pipeline does not use.

    Notes
    -----
    One robust iteration (paper Sections 2-4): kNN graph; normals; MLS cubic fit giving the
    projection ``q_i`` and residual ``d_i``; sampling likelihood ``l_i``; feature intensity
    ``s_i`` from the normal voting tensor over the region-grown ``N_R(i)``; bilateral filtering
    of the normals to ``n*_i``; and the move ``p*_i = p_i + m_i |q_i - p_i| n*_i``. All
    quantities of an iteration use the positions at its start (Jacobi updates). The points are
    processed in Morton order for memory locality and returned in the caller's order.

    Feature-aware iteration (presets "default" and "fast"; docs/DECISIONS.md): kNN graph; PCA
    normals; bilateral filtering to ``n*_i``; a quadratic fitted in the frame of ``p_i`` and
    ``n*_i`` with each neighbour weighted by distance and by normal agreement (so a point near a
    crease is fitted to its own face); and the projection ``p*_i = p_i + g_i(0, 0) n*_i`` along
    the filtered normal. With ``k=None``, a probe fit on (a subsample of) the input measures the
    noise and sets ``k`` (``stats["auto_k"]``). The last iteration also computes ``l_i`` (from
    the fit's RMS residual) and ``s_i`` (the paper's voting) for the result; the moves use
    neither.

    Coarse to fine (``k=None``; "default" where the probe's noise is at least half its list
    radius and grid cells of 1.5 times the noise hold at least 3 points on average, or on
    "fast"'s cells (see ``preset``), "fast" always, its cells widened to 3 points): the
    iterations run on
    the cell means, each neighbour's fit weight times the points its cell holds; the denoised
    means are averaged again over the same grid and each is fitted by the feature-aware
    quadratic of its 16 nearest, and every input point moves onto the fits of its 3 nearest
    means (by their inverse-distance-weighted steps along their normals). Its
    cost follows the number of cells (the noise), not ``n``; ``stats["auto_k"]["coarse"]``
    describes it (docs/ALGORITHM.md, "Coarse to fine").

    References
    ----------
    .. [1] "Robust Denoising of Point-Sampled Surfaces" (the paper). ``docs/ALGORITHM.md``
       describes the method as implemented, with every ambiguity of the paper decided.
    """
    if classes is not None or classification is not None:
        return _only_classes(points, normals, classification, classes, {
            "method": method, "iterations": iterations, "k": k, "lam": lam, "preset": preset,
            "rebuild_graph": rebuild_graph, "orient": orient, "remove_outliers": remove_outliers,
            "n_jobs": n_jobs, "progress": progress, **method_params})
    check_choice(method, "method", METHODS)
    check_choice(preset, "preset", tuple(PRESETS))
    setting = PRESETS[preset]
    pipeline = setting["pipeline"] if method == "robust" else "paper"
    explicit = set(method_params)
    if rebuild_graph is not None and not isinstance(rebuild_graph, (bool, np.bool_)):
        raise TypeError(f"rebuild_graph must be True or False; got {rebuild_graph!r}")
    params = _method_params(method, method_params)
    _check_pipeline_params(method, preset, pipeline, explicit, lam)
    if pipeline != "aware":
        # The paper's pipeline keeps its PCA normals and its fits.
        params.pop("shift_normals", None)
        params.pop("select_scales", None)
    report = reporter(progress)
    pts, dtype = as_points(points)
    n = pts.shape[0]
    if iterations is not None:
        iterations = check_int(iterations, "iterations", minimum=1)
    auto = k is None and setting["k"] is None
    if k is None:
        # The caller chose no k: the message is about the cloud's size, not about k.
        check_size(n)
        k = setting["k"]
        if not auto and n < k + 1:
            raise ValueError(f"the cloud has {n} points; preset {preset!r} uses k = {k} "
                             f"neighbours and needs at least {k + 1}; pass a smaller k")
    k = None if auto else check_k(k, n)
    lam = setting["lam"] if lam is None else lam
    lam = None if lam is None else check_float(lam, "lam", low=0.0, high=1.0)
    given = None if normals is None else as_normals(normals, n)
    if params["keep_normals"] and given is None:
        raise ValueError("keep_normals=True needs normals; pass normals=... or drop keep_normals")
    if orient is not None:
        orient = check_orient(orient)
        if given is not None:
            raise ValueError("orient applies to estimated normals; the given normals keep their "
                             "signs (pass normals=None or drop orient)")
    if not isinstance(remove_outliers, (bool, np.bool_)):
        raise TypeError(f"remove_outliers must be True or False; got {remove_outliers!r}")

    started = time.perf_counter()
    n_input = n
    kept = np.arange(n)
    score = outlier_seconds = None
    if remove_outliers:
        # Before anything else, so that the result is exactly that of denoise(points[kept]).
        outlier_started = time.perf_counter()
        score_all = stages.outlier_score(pts, n_jobs=n_jobs)
        outlier_seconds = time.perf_counter() - outlier_started
        kept = np.flatnonzero(score_all <= 1.0)
        pts, given, score = pts[kept], None if given is None else given[kept], score_all[kept]
        if k is not None and pts.shape[0] < k + 1:
            raise ValueError(f"only {pts.shape[0]} of {n} points remain after removing "
                             f"outliers, too few for k = {k}; lower k or keep the outliers")
        n = pts.shape[0]
    order, groups = duplicates.ordered(pts)
    distinct = check_distinct(order.shape[0], n, k)
    # Work relative to the bounding-box centre: georeferenced coordinates (1e6 m offsets) would
    # otherwise cost the kNN distances most of their digits.
    centre = 0.5 * np.add(*bounds(pts))
    current = np.empty((distinct, 3))
    gather_rows(pts, order, centre, current)
    given = None if given is None else given[order]
    step = STEPS[pipeline if method == "robust" else method]
    cells = None
    with threads(n_jobs) as n_threads:
        plan = planning.make(
            current, given, preset, distinct=distinct, k=None if auto else k,
            iterations=iterations, layout=lambda noise, key: coarse.layout(current, noise, key),
            aware_pipeline="select_scales" in params, rebuild_graph=rebuild_graph,
            select_scales=params.get("select_scales"), sigma_n=params.get("sigma_n"),
            shift_normals=params.get("shift_normals"))
        iterations = plan.iterations
        if "select_scales" in params:
            params["select_scales"] = plan.select_scales
        if plan.cells is not None:
            # Iterate on the cell means; the input points are projected onto them last.
            cells = coarse.cells_of(current, given, plan.layout, plan.cells)
            fine, fine_given = current, given
            current, given = cells.points, cells.normals
        current, out_normals, extra, records, held = iterate(
            current, given, step, plan.k, iterations, plan.rebuild_graph, plan.lists, lam,
            params, orient, centre, report, None if cells is None else cells.counts,
            plan.walks)
        if cells is not None:
            clock = Clock(report, iterations - 1, iterations)
            surface, surface_normals, extra = coarse.collapse(cells, current, out_normals, extra)
            current, out_normals, nearest, fit, held = coarse.refine(
                fine, surface, surface_normals, cells.surface_k, params["sigma_n"], clock)
            if plan.edges is not None:
                edges.finish(plan.edges, fine, current, out_normals, held, nearest,
                             edges.zones(surface, extra[1], plan.edges["radius"]), order,
                             fine_given, params["keep_normals"], params["sigma_n"], clock)
            records[-1]["times"].update(clock.times)
            extra = tuple(x[nearest] for x in extra)
            plan.probe["coarse"] = coarse.describe(plan.noise, cells.edge, cells.counts,
                                                   surface, cells.surface_k, fit)

    stats = {
        "method": method,
        "n_points": n,
        "duplicates": n - distinct,
        "k": plan.k,
        "lam": lam,
        "preset": preset,
        "pipeline": pipeline,
        "plan": plan.describe(),
        "auto_k": plan.probe,
        "noise": None if plan.probe is None else plan.probe["noise"],
        "scales": plan.walks_record(),
        "rebuild_graph": plan.rebuild_graph,
        "orient": orient if orient is None or isinstance(orient, str) else orient.tolist(),
        "outliers": None if score is None else {
            "flagged": int((score_all > 1.0).sum()), "removed": n_input - n,
            "seconds": outlier_seconds},
        "n_iterations": iterations,
        "held_points": int(held.sum()),
        "params": dict(params),
        "n_jobs": n_threads,
        "iterations": records,
        "total_seconds": time.perf_counter() - started,
    }
    # A copy (in the input's dtype): the caller may change the input before the access.
    outliers = (pts.astype(dtype), n_jobs) if score is None else score.astype(dtype, copy=False)
    return result(pts, dtype, (order, groups), centre, current, out_normals, extra, held, kept,
                  outliers, stats)


def result(pts, dtype, order, centre, current, out_normals, extra, held, kept, outliers, stats):
    """The :class:`DenoiseResult` of a run on ``pts`` (the input rows denoised, in the caller's
    order) whose outputs ``current``, ``out_normals``, ``extra`` and ``held`` are in the order
    of ``(order, groups)`` (:func:`pssd_fast.duplicates.ordered`), relative to ``centre``;
    ``outliers``: the scores or what computes them."""
    shift = _to_caller_order(current, *order)
    points = shift + centre
    displacement = np.linalg.norm(shift - (pts - centre), axis=1)
    if order[1] is not None:
        # A copy's move, from its own input position, as tiled.denoise_file computes it.
        copy = np.ones(pts.shape[0], np.bool_)
        copy[order[0]] = False
        displacement[copy] = np.linalg.norm(points[copy] - pts[copy], axis=1)
    lik, feat = (None, None) if extra is None else (
        _to_caller_order(x, *order).astype(dtype, copy=False) for x in extra)
    return DenoiseResult(
        points=points.astype(dtype, copy=False),
        normals=_to_caller_order(out_normals, *order).astype(dtype, copy=False),
        likelihood=lik,
        feature_intensity=feat,
        displacement=displacement.astype(dtype, copy=False),
        held=_to_caller_order(held, *order),
        _outliers=outliers,
        kept=kept,
        stats=stats,
    )


def iterate(current, given, step, k, iterations, rebuild_graph, probe, lam, params, orient,
            centre, report, counts=None, scale_plan=None):
    """The ``iterations`` of a pipeline ``step`` on ``current`` (Morton order, relative to
    ``centre``), as :func:`denoise` runs them once its parameters are resolved.

    ``probe``: the noise probe's lists, which serve the first iteration (or None); ``counts``:
    the points each of ``current`` stands for (the cell means of the coarse-to-fine route), a
    factor on its weight in the fits, or None; ``scale_plan``: the
    :class:`~pssd_fast.pipelines.scales.ScalePlan` of ``select_scales`` (with one, ``probe`` is
    None or lists of its longest length), or None. Returns the moved points, the last
    iteration's normals and ``(likelihood, feature intensity)`` (or None), one record per
    iteration and the mask of the points held in place in at least one of them.
    """
    # A cell mean weighs as many points as it stands for in the fits.
    weighting = {} if counts is None else {"mass": counts.astype(np.float64)}
    records = []
    out_normals = graph = extra = lists = held = None
    for iteration in range(iterations):
        clock = Clock(report, iteration, iterations)
        walk = None
        if scale_plan is not None:
            # The walks' longest lists, cut to k, are the iteration's: one query for both.
            if probe is not None:
                lists = probe
            elif lists is None or rebuild_graph:
                graph = lists = None  # the last lists go before the new ones are built
                lists = clock.run("neighbors", knn_graph, current, int(scale_plan.lengths[-1]),
                                  False)
            else:
                lists = clock.run("neighbors", refresh_graph, lists, current)
            graph = clock.run("truncate", truncate_graph, lists, current, k)
            walk = {"scale_plan": scale_plan.at(iteration), "scale_lists": lists}
        elif probe is not None:
            # The probe's lists, cut to k, are this iteration's: no second query.
            graph = clock.run("neighbors", truncate_graph, probe, current, k)
        elif graph is None or rebuild_graph:
            graph = None  # the last lists go before the new ones are built, not after
            graph = clock.run("neighbors", knn_graph, current, k, False)
        else:
            graph = clock.run("neighbors", refresh_graph, graph, current)
        probe = None  # its lists (4 bytes x 96 a point) are not kept past their use
        if given is not None:
            nrm, degenerate = clock.run("normals", _given_normals, given)
        else:
            first = orient if out_normals is None else None
            # Shifted normals in the first iteration only: later ones follow the moved points.
            shift_k = k if out_normals is None and params.get("shift_normals") else None
            nrm, degenerate = clock.run("normals", inputs.estimated_normals, current, graph,
                                        out_normals, first, centre, shift_k)
        step_params = params if walk is None else {**params, **walk}
        moved, out_normals, extra, record, held_now = step(
            current, nrm, graph, lam, step_params, clock, iteration == iterations - 1,
            **weighting)
        held = held_now if held is None else held | held_now
        record["degenerate_normals"] = int(degenerate.sum())
        record["mean_step"] = float(np.linalg.norm(moved - current, axis=1).mean())
        records.append(record)
        current = moved
        if not params["keep_normals"]:
            given = None
    return current, out_normals, extra, records, held


def _only_classes(points, normals, classification, classes, options):
    """:func:`denoise` of the points whose ``classification`` is in ``classes``, the others
    kept as they are (see its ``classes``)."""
    pts, dtype = as_points(points)
    n = pts.shape[0]
    chosen, wanted = check_classes(classification, classes, n)
    given = None if normals is None else as_normals(normals, n)
    part = denoise(pts[chosen], None if given is None else given[chosen], **options)
    denoised = np.flatnonzero(chosen)[part.kept]
    holds = ~chosen
    holds[denoised] = True
    kept = np.flatnonzero(holds)
    at = np.searchsorted(kept, denoised)
    out_points = pts[kept].astype(dtype)
    out_points[at] = part.points
    nan = np.full((kept.shape[0], 3), np.nan, dtype)
    out_normals = nan.copy() if given is None else given[kept].astype(dtype)
    out_normals[at] = part.normals

    def spread(values, fill=np.nan):
        if values is None:
            return None
        out = np.full(kept.shape[0], fill, values.dtype)
        out[at] = values
        return out

    stats = {**part.stats, "classes": {
        "classes": wanted, "denoised": int(chosen.sum()), "untouched": int(n - chosen.sum())}}
    return DenoiseResult(
        points=out_points, normals=out_normals, likelihood=spread(part.likelihood),
        feature_intensity=spread(part.feature_intensity),
        displacement=spread(part.displacement, 0), held=spread(part.held, False), kept=kept,
        stats=stats, _outliers=lambda: spread(part.outlier_score))


def check_classes(classification, classes, n):
    """The mask of the points whose ``classification`` is in ``classes``, and the sorted
    classes; ValueError or TypeError naming what is wrong."""
    if classes is None or classification is None:
        raise ValueError("classes and classification go together: classification=... gives "
                         "each point's class, classes=... those to denoise")
    labels = np.asarray(classification)
    if labels.shape != (n,):
        raise ValueError(f"classification must have one value per point, shape ({n},); got "
                         f"shape {labels.shape}")
    if labels.dtype.kind not in "iu":
        raise TypeError(f"classification must hold integers; got dtype {labels.dtype}")
    if isinstance(classes, numbers.Integral):
        classes = [classes]
    try:
        wanted = sorted({check_int(c, "a class") for c in classes})
    except TypeError as exc:
        raise TypeError(f"classes must be integers; got {classes!r}") from exc
    if not wanted:
        raise ValueError("classes is empty: name at least one class to denoise")
    chosen = np.isin(labels, wanted)
    if not chosen.any():
        present = ", ".join(str(c) for c in np.unique(labels)[:20])
        raise ValueError(f"no point is of class {', '.join(map(str, wanted))}; the classes "
                         f"present are {present}")
    return chosen, wanted


def check_distinct(distinct, n, k):
    """``distinct``, the positions among ``n`` points, checked against ``k`` (None: the
    preset chooses it)."""
    if distinct < n and distinct < (MIN_K if k is None else k) + 1:
        raise ValueError(f"the cloud has {n} points but only {distinct} distinct positions; "
                         f"denoising needs at least {(MIN_K if k is None else k) + 1}"
                         + ("" if k is None else f" for k = {k} (lower k)"))
    return distinct


def _to_caller_order(values, order, groups=None):
    """``values`` (rows in Morton order ``order``; with ``groups``, those of the distinct
    positions, :func:`pssd_fast.duplicates.ordered`) back in the caller's order."""
    if groups is not None:
        return values[groups]
    out = np.empty_like(values)
    if values.ndim == 1:
        out[order] = values
    else:
        scatter_rows(values, order, np.zeros(values.shape[1]), out)
    return out


def _check_pipeline_params(method, preset, pipeline, explicit, lam):
    """Refuse parameters that the chosen method or pipeline would silently ignore."""
    if method != "robust":
        if lam is not None:
            raise ValueError(f"lam only applies to the robust method; method {method!r} does "
                             "not use it")
        return
    if pipeline == "aware":
        unused = sorted(explicit & set(PAPER_ONLY)) + (["lam"] if lam is not None else [])
        if unused:
            raise ValueError(f"{', '.join(unused)} only appl{'ies' if len(unused) == 1 else 'y'}"
                             f" to the paper's pipeline; pass preset='paper' to use "
                             f"{'it' if len(unused) == 1 else 'them'} (preset {preset!r} runs "
                             "the feature-aware pipeline)")
    else:
        unused = sorted(explicit & set(AWARE_ONLY))
        if unused:
            raise ValueError(f"{', '.join(unused)} only applies to the feature-aware presets "
                             f"'default' and 'fast', not to preset {preset!r}")


def _method_params(method, method_params):
    """The method's defaults overlaid with the caller's parameters, validated."""
    defaults = METHOD_DEFAULTS[method]
    unknown = sorted(set(method_params) - set(defaults))
    if unknown:
        raise TypeError(f"unknown parameter(s) {', '.join(unknown)} for method {method!r}; "
                        f"valid: {', '.join(defaults)}")
    params = {**defaults, **method_params}
    for name in ("h", "sigma_c", "sigma_s"):
        if params.get(name) is not None:
            params[name] = check_float(params[name], name, positive=True)
    for name in ("radius_factor", "delta", "alpha", "beta", "sigma_n"):
        if name in params:
            params[name] = check_float(params[name], name, positive=True)
    if "likelihood" in params:
        check_choice(params["likelihood"], "likelihood", tuple(core.LIKELIHOOD_FORMS))
    for name in ("keep_normals", "shift_normals"):
        if name in params:
            if not isinstance(params[name], (bool, np.bool_)):
                raise TypeError(f"{name} must be True or False; got {params[name]!r}")
            params[name] = bool(params[name])
    if "select_scales" in params:
        params["select_scales"] = scales.check(params["select_scales"])
    return params


def _given_normals(normals):
    """The caller's normals, with no degenerate neighbourhood to report."""
    return normals, np.zeros(normals.shape[0], np.bool_)
