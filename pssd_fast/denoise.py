"""`denoise`: resolves the parameters, then runs the iterations of the chosen pipeline."""
import time

import numpy as np

from . import classes as lidar
from . import core, duplicates, executor, interop
from . import plan as planning
from ._threads import threads
from ._validation import (
    as_normals, as_points, auto, check_choice, check_flag, check_float, check_int, check_k,
    check_orient, check_precision, check_size,
)
from .graph import bounds
from .plan import PRESETS
from .progress import reporter
from .run import (
    DenoiseResult, Input, Iterated, Request, check_distinct, iterate, outlier_scores, result,
    stats,
)
from .store import Memory

#: Parameters of each method beyond the common ones, with their defaults.
METHOD_DEFAULTS = {
    "robust": {"h": "auto", **core.FEATURE_DEFAULTS, "likelihood": "exp", "sigma_n": 0.05,
               "shift_normals": True, "keep_normals": False},
    "bilateral": {"sigma_c": "auto", "sigma_s": "auto", "keep_normals": False},
    "mls": {"h": "auto", "keep_normals": False},
}
#: Methods :func:`denoise` offers.
METHODS = tuple(METHOD_DEFAULTS)
#: Robust-method parameters that only the paper's pipeline uses, and those only the default
#: method uses.
PAPER_ONLY = ("h", "radius_factor", "delta", "alpha", "beta", "likelihood")
DEFAULT_ONLY = ("sigma_n", "shift_normals")


def denoise(points, normals=None, *, method="robust", iterations="auto", k="auto", lam=None,
            preset="default", rebuild_graph="auto", orient=None, remove_outliers=False,
            extras=False, duplicate_tolerance=0.0, classification=None, classes=None,
            n_jobs=None, progress=None, **method_params):
    """Denoise a point-sampled surface while keeping its sharp features.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Noisy coordinates, float32 or float64 (other real dtypes are computed as float64);
        the result has their dtype. float32 far from the origin warns (see Warns). Never
        modified. Or an Open3D or trimesh point cloud, or a structured array with fields
        ``X``, ``Y``, ``Z`` (:mod:`pssd_fast.interop`; their normals are not used).
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
    iterations : int or "auto", default "auto"
        Number of passes; each recomputes everything from the current positions. ``"auto"``:
        from ``preset``, 4 ("default"; 2 on "fast"'s cells, see ``preset``), 2 ("fast",
        "paper"; the paper uses 1 to 3).
    k : int or "auto", default "auto"
        Neighbourhood size including the point itself (paper Section 2.2: ``k in [20, 35]``);
        at least 10 and at most ``n - 1``. ``"auto"``: from ``preset``, chosen from the
        estimated noise ("default": 64 to 160 on the input, or 96 to 128 on cell means;
        "fast": 48 to 96 on cell means), 25 ("paper"); the same noise decides the route (the
        cell means or the points). Given, the iterations run on the input points with that
        ``k``. Every ``"auto"`` and its thresholds: README, "Automatic choices".
    lam : float, optional
        ``lambda`` in [0, 1] of Section 4.2: weight of the likelihood term against the feature
        term in the step ``m_i``. Paper's pipeline only (default 0.5); the other presets and
        the baselines refuse it, since their move does not use it.
    preset : {"default", "fast", "paper"}, default "default"
        ``"paper"``: the paper's formulation (k = 25, lambda = 0.5, 2 iterations; the Notes' first
        paragraph). ``"default"``: the feature-aware pipeline (Notes), ``k`` from the estimated
        noise, 4 iterations; chosen on generated shapes to beat CGAL's jet and bilateral smoothing
        (docs/DECISIONS.md; docs/benchmarks.md, "Beyond the paper"); where the noise spans several
        point spacings it iterates on cell means (Notes). Above 50,000 points, where "fast"'s probe
        finds the noise at most 0.3 of its list radius, it takes "fast"'s cells and iterations, and
        then the points near features iterate on their own lists (the edges route;
        docs/ALGORITHM.md, "Routes"). ``"fast"``: the same pipeline, always on cell means (of at
        least 3 points), 2 iterations and a cheaper noise probe. For the baselines a preset sets
        ``k`` ("default" and "fast": from the noise probe; "fast" 48), ``iterations`` and
        ``rebuild_graph``.
    rebuild_graph : bool or "auto", default "auto"
        ``True``: query the k nearest neighbours anew in every iteration. ``False``: later
        iterations keep the first iteration's lists, re-sorted by the current distances (one
        kNN query in all; see docs/DECISIONS.md for what it changes). ``"auto"``: from
        ``preset``, on the input points True ("default", "paper") or False ("fast"); on cell
        means False, except "fast" from 13 points a cell.
    orient : {"outward", "up"} or array_like of shape (3,), optional
        Sign of the first iteration's PCA normals (later iterations follow it):
        made consistent by propagation over the neighbour graph, then each connected
        component turned outward, up (``+z``) or towards a viewpoint on balance (see
        :func:`pssd_fast.estimate_normals`). ``None`` (default): each normal away from the
        cloud's centroid, as before (docs/DECISIONS.md, "Normal orientation"). Not with
        ``normals``, whose signs are the caller's. The positions do not depend on it.
    extras : bool, default False
        Also return the sampling likelihood and the feature intensity under presets "default"
        and "fast", whose moves use neither (a pass of the paper's voting over the cell means;
        docs/ALGORITHM.md, "The default method"); without it they are None. The paper's
        pipeline always returns them, the baselines never.
    remove_outliers : bool, default False
        Drop the points whose :func:`pssd_fast.outlier_score` exceeds 1 before denoising;
        ``kept`` says which input rows the result holds, ``outlier_score`` their scores.
        Without it the run makes no outlier query (``pssd_fast.outlier_score(points)`` gives
        the scores).
    duplicate_tolerance : float, default 0.0
        Which rows are one position, denoised as one point: the first of them stands for all
        and every row takes its result, with its own ``displacement`` (docs/ALGORITHM.md,
        "Before any iteration: duplicates"). 0: rows with equal coordinates. ``t > 0``, in
        the cloud's units: rows in one cube of edge ``t``, where ``floor((p - low) / t)``
        agrees on every axis (``low``: the bounding box's low corner), so rows less than
        ``t`` apart may still be two positions; at most ``2**52`` cubes along the bounding
        box's longest side. Rows at different positions are never merged.
        ``stats["duplicates"]`` counts the rows merged.
    classification : array_like of int, shape (n,), optional
        A class code per point, such as the LAS ``classification`` (ASPRS LAS 1.4: 0 never
        classified, 1 unclassified, 2 ground, 3-5 vegetation, 6 building, 7 and 18 noise, 9
        water...). Points of two classes are never each other's neighbours: each class
        denoised runs on its own, as ``denoise(points[rows of the class])`` (the call's other
        parameters apply to each run; ``remove_outliers`` drops outliers within each class).
        By default (``classes`` not given) the surface classes present are denoised, each on
        its own: 2 ground, 6 building, 9 water, 10 rail, 11 road surface and 17 bridge deck
        (``pssd_fast.classes.SURFACE_CLASSES``), and every other point is kept as it is; a
        classification of 0 and 1 only carries no class, and the cloud is denoised as one.
        Where no point is of a surface class, ValueError (name the classes). A class chosen
        by default (or by ``"each"``) with fewer points than a run needs (``k + 1``; 11, or
        26 with preset "paper", where ``k`` is not given) is kept as it is, with a
        :class:`pssd_fast.DenoiseWarning` (docs/DECISIONS.md, "LiDAR classes").
    classes : iterable of int, "each" or "all", optional
        Which classes of ``classification`` to denoise, each on its own: these codes (codes no
        point has are ignored), or ``"each"``: every class present. ``"all"``: every point, as
        one cloud, the classification ignored (as without it). The points of the classes not
        denoised are no point's neighbours and keep their exact coordinates (and their
        normals as given, NaN allowed; else NaN normals), NaN ``likelihood``,
        ``feature_intensity`` and (with ``remove_outliers``) ``outlier_score``, and zero
        ``displacement``. ``stats`` are those of the largest class's run but ``n_points``,
        ``duplicates``, ``held_points`` and ``outliers`` (sums over the runs) and
        ``total_seconds`` (the call's); ``stats["classes"]`` says what was denoised
        (``"classes"``: the codes, or ``"all"``), counts the points ``"denoised"`` and
        ``"untouched"``, lists the classes ``"too_small"`` and holds each class's own
        ``stats`` in ``"runs"``.
    n_jobs : int or None, default None
        Threads for the kernels: ``None`` or -1 use every thread numba may use (by default one
        per core), a positive number that many (capped at that maximum). Numba's setting is
        restored afterwards. The output does not depend on it.
    progress : bool or callable, optional
        ``True`` prints a line per stage and iteration on stderr; a callable is called as
        ``progress(iteration, iterations, stage, seconds)`` after each stage; default silent.
    **method_params
        Parameters of the chosen method (docs/ALGORITHM.md). ``"robust"``:

        h : float or "auto", default "auto"
            MLS Gaussian width (Section 2.1); ``"auto"``: mean distance to the k-th neighbour.
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
        select_scales : bool or "auto", default "auto"
            Feature-aware pipeline, on the points (not on the cell means of the coarse-to-fine
            route): each point fits nested quadratics over prefixes of a list of ``4.5 k`` and
            keeps the widest that still fits its neighbours within the noise, instead of the fit at
            ``k`` (docs/ALGORITHM.md, "A scale per point"). ``"auto"``: on where preset "default"
            iterates on the points of a cloud of at most 50,000 points (after ``remove_outliers``),
            where it wins the sparse clouds the fit at ``k`` loses to CGAL (docs/benchmarks.md,
            "Sparse clouds"); off otherwise. It costs a kNN query and a fit over lists of ``4.5 k``
            an iteration (about 9 times the fit at ``k`` at 30,000 points; with
            ``rebuild_graph=False`` the lists are queried once and re-sorted later, 2 to 3 times
            faster). ``stats["params"]["select_scales"]`` says whether a run took it,
            ``stats["scales"]`` what the probe set, each iteration's record what the walks kept.
            The tiled runs of :mod:`pssd_fast.tiled` take it too.

        ``h``, ``radius_factor``, ``delta``, ``alpha``, ``beta`` and ``likelihood`` shape the
        paper's pipeline only; the other presets refuse them (ValueError) rather than ignore
        them.

        ``"mls"``: ``h`` and ``keep_normals`` as above. ``"bilateral"``: ``keep_normals`` and

        sigma_c, sigma_s : float or "auto", default "auto"
            Spatial and height widths of the bilateral weights; ``"auto"``, per point: half
            the list radius and the standard deviation of the neighbours' heights.

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

    Warns
    -----
    DenoiseWarning
        Once a call, where ``points`` are float32 and their step at the largest absolute
        coordinate exceeds 1% of the cloud's mean spacing (UTM coordinates as float32 are 3 cm
        to 1 m apart): the coordinates lost detail that denoising works at, and the
        float32 result is rounded to that step. Pass float64, or subtract an offset before
        converting to float32 (docs/DECISIONS.md, "float32 coordinates far from the origin").
        And where classes chosen by default are too small to denoise (see
        ``classification``).

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
    the filtered normal. With ``k="auto"``, a probe fit on (a subsample of) the input measures the
    noise and sets ``k`` (``stats["auto_k"]``). The last iteration also computes ``l_i`` (from
    the fit's RMS residual) and ``s_i`` (the paper's voting) for the result; the moves use
    neither.

    Coarse to fine (``k="auto"``; "default" where the probe's noise is at least half its list
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
    return run(points, normals, dict(
        method=method, iterations=iterations, k=k, lam=lam, preset=preset,
        rebuild_graph=rebuild_graph, orient=orient, remove_outliers=remove_outliers,
        extras=extras, duplicate_tolerance=duplicate_tolerance, classification=classification,
        classes=classes, n_jobs=n_jobs, progress=progress, **method_params))


def run(points, normals, options, runner=None, tile_points=None, store=None):
    """:func:`denoise` with its keyword arguments as ``options``; the default method's tile
    tasks run on ``runner`` (None: here) in tiles of at most ``tile_points`` points (None: one),
    their arrays kept in ``store`` (None: in memory), as :func:`pssd_fast.tiled.denoise` asks.
    The result does not depend on the tiles."""
    points = interop.coordinates(points)  # Open3D, trimesh and structured arrays
    options = dict(options)
    classification, classes = options.pop("classification", None), options.pop("classes", None)
    if classes is not None or classification is not None:
        return _by_class(points, normals, classification, classes, options, runner,
                         tile_points, store)
    return _run(points, normals, runner, tile_points, store, **options)


def _default(current, given, plan, request, runner, tile_points, store):
    """The default method's run (:mod:`pssd_fast.executor`) as an :class:`Iterated`, and its
    number of tiles."""
    store = Memory() if store is None else store
    tiles = executor.group(current, given, plan, store, tile_points)
    _, records = executor.run(plan, request, tiles, store, runner)
    out = executor.collect(store, tiles, current.shape[0])
    extra = (out["likelihood"], out["feature"]) if request.extras else None
    return Iterated(out["xyz"], out["normals"], extra, records, out["held"]), len(tiles)


def checked_options(options):
    """:func:`denoise`'s keyword arguments ``options`` checked, as far as they can be without
    the points (TypeError or ValueError naming what is wrong): a dict of the run's ``method``,
    ``preset``, ``pipeline``, ``params`` (the method's), ``lam``, ``k`` and ``iterations``
    (None: the run chooses), ``rebuild_graph``, ``orient``, ``remove_outliers``, ``extras``,
    ``duplicate_tolerance``, ``n_jobs`` and ``report``."""
    options = dict(options)
    method, preset = options.pop("method", "robust"), options.pop("preset", "default")
    iterations, k = options.pop("iterations", "auto"), options.pop("k", "auto")
    lam, rebuild_graph = options.pop("lam", None), options.pop("rebuild_graph", "auto")
    orient = options.pop("orient", None)
    remove_outliers, extras = options.pop("remove_outliers", False), options.pop("extras", False)
    tolerance = options.pop("duplicate_tolerance", 0.0)
    n_jobs, progress = options.pop("n_jobs", None), options.pop("progress", None)
    check_choice(method, "method", METHODS)
    check_choice(preset, "preset", tuple(PRESETS))
    setting = PRESETS[preset]
    pipeline = setting["pipeline"] if method == "robust" else method
    explicit = {name for name, value in options.items() if auto(value) is not None}
    rebuild_graph = check_flag(rebuild_graph, "rebuild_graph")
    params = _method_params(method, options)
    _check_pipeline_params(method, preset, pipeline, explicit, lam, rebuild_graph)
    lam = setting["lam"] if lam is None else lam
    for name, flag in (("remove_outliers", remove_outliers), ("extras", extras)):
        if not isinstance(flag, (bool, np.bool_)):
            raise TypeError(f"{name} must be True or False; got {flag!r}")
    return {"method": method, "preset": preset, "pipeline": pipeline, "params": params,
            "lam": None if lam is None else check_float(lam, "lam", low=0.0, high=1.0),
            "k": auto(k), "iterations": auto(iterations, lambda v: check_int(
                v, "iterations", minimum=1)),
            "rebuild_graph": rebuild_graph,
            "orient": None if orient is None else check_orient(orient),
            "remove_outliers": bool(remove_outliers), "extras": bool(extras),
            "duplicate_tolerance": duplicates.check_tolerance(tolerance), "n_jobs": n_jobs,
            "report": reporter(progress)}


def _run(points, normals, runner, tile_points, store, **options):
    """:func:`run` of a cloud without classes."""
    o = checked_options(options)
    method, preset, pipeline, params, lam = (o["method"], o["preset"], o["pipeline"],
                                             o["params"], o["lam"])
    k, iterations, orient, n_jobs = o["k"], o["iterations"], o["orient"], o["n_jobs"]
    setting = PRESETS[preset]
    pts, dtype = as_points(points)
    check_precision(pts, dtype, stacklevel=5)
    n = pts.shape[0]
    if k is None and setting["k"] is not None and pipeline != "default":
        # The caller chose no k: the message is about the cloud's size, not about k.
        check_size(n)
        k = setting["k"]
        if n < k + 1:
            raise ValueError(f"the cloud has {n} points; preset {preset!r} uses k = {k} "
                             f"neighbours and needs at least {k + 1}; pass a smaller k")
    elif k is None:
        check_size(n)
    k = None if k is None else check_k(k, n)
    given = None if normals is None else as_normals(normals, n)
    if params["keep_normals"] and given is None:
        raise ValueError("keep_normals=True needs normals; pass normals=... or drop keep_normals")
    if orient is not None and given is not None:
        raise ValueError("orient applies to estimated normals; the given normals keep their "
                         "signs (pass normals=None or drop orient)")
    remove_outliers, extras = o["remove_outliers"], o["extras"]
    duplicate_tolerance, rebuild_graph, report = (o["duplicate_tolerance"], o["rebuild_graph"],
                                                  o["report"])

    started = time.perf_counter()
    n_input = n
    kept = np.arange(n)
    score = outliers = None
    if remove_outliers:
        # Before anything else, so that the result is exactly that of denoise(points[kept]).
        outlier_started = time.perf_counter()
        score_all = outlier_scores(pts, n_jobs)
        seconds = time.perf_counter() - outlier_started
        kept = np.flatnonzero(score_all <= 1.0)
        pts, given, score = pts[kept], None if given is None else given[kept], score_all[kept]
        if k is not None and pts.shape[0] < k + 1:
            raise ValueError(f"only {pts.shape[0]} of {n} points remain after removing "
                             f"outliers, too few for k = {k}; lower k or keep the outliers")
        outliers = {"flagged": int((score_all > 1.0).sum()), "removed": n_input - kept.shape[0],
                    "seconds": seconds}
        n = pts.shape[0]
    order, groups = duplicates.ordered(pts, duplicate_tolerance)
    distinct = check_distinct(order.shape[0], n, k)
    # Work relative to the bounding-box centre: georeferenced coordinates (1e6 m offsets) would
    # otherwise cost the kNN distances most of their digits.
    low, high = bounds(pts)
    centre = 0.5 * (low + high)
    current = core.relative_rows(pts, order, centre)
    given = None if given is None else given[order]
    request = Request(method, preset, pipeline, lam, params, orient, centre, report, started,
                      bool(extras))
    more = {}
    with threads(n_jobs) as n_threads:
        plan, lists = planning.make(current, given, preset, pipeline, distinct=distinct,
                                    low=low - centre, k=k, iterations=iterations,
                                    rebuild_graph=rebuild_graph)
        if pipeline == "default":
            done, count = _default(current, given, plan, request, runner, tile_points, store)
        else:
            done, count = iterate(current, given, plan, request, lists), 1
        if runner is not None:
            more["tiles"] = {"count": count, "scheduler": runner.name,
                             "threads": runner.threads}
    return result(Input(pts, dtype, order, groups), done, centre, kept,
                  None if score is None else score.astype(dtype, copy=False),
                  stats(request, plan, n, distinct, n_threads, done.records,
                        int(done.held.sum()), outliers=outliers, **more))


def _by_class(points, normals, classification, classes, options, runner, tile_points, store):
    """:func:`denoise` of each class that ``classification`` and ``classes`` choose on its
    own, the other points kept as they are (see its ``classification``)."""
    started = time.perf_counter()
    pts, dtype = as_points(points)
    check_precision(pts, dtype, stacklevel=5)
    n = pts.shape[0]
    runs, small, described, least = lidar.select(classification, classes, n, options)
    lidar.warn_small(small, least, stacklevel=4)
    chosen = np.zeros(n, np.bool_)
    for _, rows in runs:
        chosen[rows] = True
    given = lidar.given_normals(normals, n, chosen)
    done = []
    for code, rows in runs:
        try:
            part = _run(pts[rows], None if given is None else given[rows], runner,
                        tile_points, store, **options)
        except ValueError as exc:
            if code is None:
                raise
            raise ValueError(f"the points of class {code}: {exc}") from exc
        done.append((code, rows, part))
    return lidar.merge(pts, dtype, given, done, small, described, started)


def _check_pipeline_params(method, preset, pipeline, explicit, lam, rebuild_graph):
    """Refuse parameters that the chosen method or pipeline would silently ignore."""
    if pipeline == "default" and rebuild_graph is not None:
        raise ValueError(f"rebuild_graph applies to the paper's pipeline and the baselines; "
                         f"preset {preset!r} queries its lists in every step")
    if method != "robust":
        if lam is not None:
            raise ValueError(f"lam only applies to the robust method; method {method!r} does "
                             "not use it")
        return
    if pipeline == "default":
        unused = sorted(explicit & set(PAPER_ONLY)) + (["lam"] if lam is not None else [])
        if unused:
            raise ValueError(f"{', '.join(unused)} only appl{'ies' if len(unused) == 1 else 'y'}"
                             f" to the paper's pipeline; pass preset='paper' to use "
                             f"{'it' if len(unused) == 1 else 'them'} (preset {preset!r} runs "
                             "the default method)")
    else:
        unused = sorted(explicit & set(DEFAULT_ONLY))
        if unused:
            raise ValueError(f"{', '.join(unused)} only applies to the default method (presets "
                             f"'default' and 'fast'), not to preset {preset!r}")


def _method_params(method, method_params):
    """The method's defaults overlaid with the caller's parameters, validated."""
    defaults = METHOD_DEFAULTS[method]
    unknown = sorted(set(method_params) - set(defaults))
    if unknown:
        raise TypeError(f"unknown parameter(s) {', '.join(unknown)} for method {method!r}; "
                        f"valid: {', '.join(defaults)}")
    params = {**defaults, **method_params}
    for name in ("h", "sigma_c", "sigma_s"):
        if name in params:
            params[name] = auto(params[name], lambda v: check_float(v, name, positive=True))
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
    return params
