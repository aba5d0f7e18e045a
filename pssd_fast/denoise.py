"""`denoise`: resolves the parameters, then runs the iterations of the chosen pipeline."""
import time

import numpy as np

from . import classes as lidar
from . import core, duplicates, executor, interop
from . import plan as planning
from ._threads import threads
from ._validation import (
    as_normals, as_points, auto, check_k, check_orient_estimated, check_precision, check_size,
)
from .graph import bounds
from .parameters import (
    BY_NAME, DEFAULT_ONLY, METHOD_DEFAULTS, METHODS, PAPER_ONLY, PARAMETERS, check,
)
from .plan import PRESETS
from .run import (
    Input, Iterated, Request, check_distinct, iterate, outlier_scores, result, stats,
)
from .store import Memory

# Declared in pssd_fast.parameters; imported from here too.
__all__ = ["DEFAULT_ONLY", "METHOD_DEFAULTS", "METHODS", "PAPER_ONLY", "checked_options",
           "denoise", "run"]
#: :func:`denoise`'s own keywords that :func:`checked_options` checks (the classes are
#: checked with the points, :mod:`pssd_fast.classes`).
_COMMON = tuple(p.name for p in PARAMETERS
                if not p.method and p.name not in ("classification", "classes"))


def denoise(points, normals=None, *, method="robust", iterations="auto", k="auto", lam=None,
            preset="default", rebuild_graph="auto", orient=None, remove_outliers=False,
            extras=False, duplicate_tolerance=0.0, classification=None, classes=None,
            n_jobs=None, progress=None, **method_params):
    """Denoise a point-sampled surface while keeping its sharp features.

    Each ``"auto"`` is chosen from the cloud (README, "Automatic choices": every choice and
    its threshold); ``stats["plan"]`` says what a run chose.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Noisy coordinates, float32 or float64 (other real dtypes as float64), never modified;
        the result has their dtype. Or an Open3D or trimesh cloud, or a structured array with
        fields ``X``, ``Y``, ``Z`` (:mod:`pssd_fast.interop`).
    normals : array_like, shape (n, 3), optional
        Normals for the first iteration (every one with ``keep_normals=True``), else
        estimated by PCA; only their local sign consistency matters.
    method : {"robust", "bilateral", "mls"}, default "robust"
        ``"robust"``: the paper's method (preset "paper") or the feature-aware refinement of
        it (the other presets, Notes); the other two are the paper's baselines
        (docs/ALGORITHM.md, "The baselines").
    iterations : int or "auto", default "auto"
        ``"auto"``: 2 (the default method's on its cell means, under "default" and "fast";
        "paper"); the baselines 4 under "default", else 2. ``stats["n_iterations"]`` says how
        many ran.
    k : int or "auto", default "auto"
        Neighbours including the point itself, 10 to ``n - 1``: under "default" and "fast" the
        list length on the cell means, else of every point's list. ``"auto"``: 25 ("paper");
        the default method's from the noise its probe measures (80 to 160,
        ``stats["plan"]``); the baselines' from the same probe (``stats["auto_k"]``).
    lam : float, optional
        ``lambda`` in [0, 1] (Section 4.2), the likelihood term's weight. Preset "paper" only
        (default 0.5).
    preset : {"default", "fast", "paper"}, default "default"
        ``"default"``: the default method: the feature-aware fit iterated on the means of grid
        cells sized by the noise, every point moved onto the fits, and the points the fits
        fail to explain fitted again on their own (docs/ALGORITHM.md, "The default method" and
        "Presets"). ``"fast"``: the same without that refinement. ``"paper"``: the paper's
        formulation (k = 25, lambda = 0.5, 2 iterations).
    rebuild_graph : bool or "auto", default "auto"
        The paper's pipeline and the baselines: query the neighbours anew in each iteration
        (``True``) or keep the first lists, re-sorted (``False``; docs/DECISIONS.md, "Graph and
        scheduling"). The default method queries its lists in every step and refuses it.
    orient : {"outward", "up"} or array_like of shape (3,), optional
        Sign of the estimated normals, as in :func:`pssd_fast.estimate_normals`; ``None``:
        away from the centroid. Not with ``normals``. The positions do not depend on it.
    extras : bool, default False
        Compute the likelihood and the feature intensity during the run under presets
        "default" and "fast", whose moves use neither (docs/ALGORITHM.md, "The default
        method"); else each is computed when the result's field is first read, to the same
        values (:class:`DenoiseResult`). The paper's pipeline always returns them, the
        baselines never.
    remove_outliers : bool, default False
        Drop the points whose :func:`pssd_fast.outlier_score` exceeds 1 first (the result's
        ``kept`` and ``outlier_score``).
    duplicate_tolerance : float, default 0.0
        Rows at one position are denoised as one point: 0, equal coordinates; ``t > 0``, one
        cube of edge ``t`` (docs/ALGORITHM.md, "Before any iteration: duplicates").
    classification : array_like of int, shape (n,), optional
        A class code per point (LAS classification). Each class denoised is a run of its
        own; the other points keep their coordinates. By default the surface classes present
        (2 ground, 6 building, 9 water, 10 rail, 11 road, 17 bridge deck); 0 and 1 alone are
        no classification (docs/DECISIONS.md, "LiDAR classes").
    classes : iterable of int, "each" or "all", optional
        Which classes to denoise, each on its own: these codes, or ``"each"`` (every class
        present); ``"all"``: every point as one cloud. ``stats["classes"]`` says what ran.
        Codes that no point is of are warned of (:class:`DenoiseWarning`); ValueError where
        none named is present.
    n_jobs : int or None, default None
        Threads; ``None`` or -1: every thread numba may use. The output does not depend on it.
    progress : bool or callable, optional
        ``True``: a line per stage on stderr; a callable gets ``(iteration, iterations,
        stage, seconds)`` (iteration from 1; a stage run again within an iteration, as the
        refinement's are, is reported again under its name).
    **method_params
        The method's own (docs/ALGORITHM.md, "Constants"); one its pipeline does not use
        raises ValueError. The paper's: ``h`` ("auto"), ``radius_factor`` (10), ``delta``,
        ``alpha``, ``beta`` (0.2, 0.3, 0.3), ``likelihood`` ("exp", "ratio", "residual").
        The default method's: ``sigma_n`` (0.05), ``shift_normals`` (True). ``"mls"``:
        ``h``; ``"bilateral"``: ``sigma_c``, ``sigma_s`` ("auto"). All: ``keep_normals``
        (False).

    Returns
    -------
    DenoiseResult

    Raises
    ------
    TypeError
        Non-numeric points, a masked array with masked values, non-integer ``k``,
        ``iterations`` or ``n_jobs``, unknown keywords.
    ValueError
        Wrong shapes, NaN or Inf, coordinates beyond 1e100 or a cloud less than 1e-100 across
        (squared distances would overflow or vanish: rescale it), fewer than 11 points or
        ``k + 1``, values out of range, unused parameters, no surface class in
        ``classification`` by default.

    Warns
    -----
    DenoiseWarning
        float32 ``points`` so far from the origin that their step exceeds 1% of the spacing
        (docs/DECISIONS.md, "float32 coordinates far from the origin"); default classes too
        small to denoise; class codes named that no point is of; a cloud so small that each
        fit reads more than a quarter of it (docs/DECISIONS.md, "Small clouds").

    Notes
    -----
    docs/ALGORITHM.md describes the method as implemented, docs/benchmarks.md its accuracy
    and its seconds ("How long will it take"). The feature-aware iteration fits a quadratic
    weighted by normal agreement, so that a point near a crease fits its own face
    (docs/DECISIONS.md, "Beyond the paper"). No point moves beyond its neighbour list's radius
    (``held``).

    Examples
    --------
    >>> import pssd_fast
    >>> from pssd_fast import datasets
    >>> cloud = datasets.make("cube", n_points=2000, noise=0.005, seed=0)
    >>> result = pssd_fast.denoise(cloud.points)
    >>> result.points.shape, result.points.dtype
    ((2000, 3), dtype('float64'))
    >>> result.stats["plan"]["method"], result.stats["k"], result.stats["n_iterations"]
    ('default', 80, 2)
    >>> def error(points):  # mean distance to the true cube, in 1e-4 of its diagonal
    ...     return f"{1e4 * cloud.surface_distance(points).mean() / cloud.diagonal:.0f}"
    >>> error(cloud.points), error(result.points)
    ('40', '13')
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
    number of tiles and their most points."""
    store = Memory() if store is None else store
    tiles = executor.group(current, given, plan, store, tile_points)
    _, records = executor.run(plan, request, tiles, store, runner)
    out = executor.collect(store, tiles, current.shape[0])
    if request.extras:
        extra = (out["likelihood"], out["feature"])
    else:  # computed when the result's fields are first read
        extra = executor.deferred_extras(store, tiles, [("fits", i) for i in range(len(tiles))],
                                         plan, current.shape[0])
    return (Iterated(out["xyz"], out["normals"], extra, records, out["held"]),
            (len(tiles), max(tile.points for tile in tiles)))


def checked_options(options):
    """:func:`denoise`'s keyword arguments ``options`` checked as :mod:`pssd_fast.parameters`
    declares them, as far as they can be without the points (TypeError or ValueError naming
    what is wrong): a dict of the run's ``method``, ``preset``, ``pipeline``, ``params`` (the
    method's), ``lam``, ``k`` and ``iterations`` (None: the run chooses), ``rebuild_graph``,
    ``orient``, ``remove_outliers``, ``extras``, ``duplicate_tolerance``, ``n_jobs`` and
    ``report``."""
    options = dict(options)
    o = {name: options.pop(name, BY_NAME[name].default) for name in _COMMON}
    method, preset = check("method", o["method"]), check("preset", o["preset"])
    setting = PRESETS[preset]
    pipeline = setting["pipeline"] if method == "robust" else method
    explicit = {name for name, value in options.items() if auto(value) is not None}
    rebuild_graph = check("rebuild_graph", o["rebuild_graph"])
    params = _method_params(method, options)
    lam = o["lam"]
    _check_pipeline_params(method, preset, pipeline, explicit, lam, rebuild_graph)
    lam = setting.get("lam") if lam is None else lam
    remove_outliers = check("remove_outliers", o["remove_outliers"])
    extras = check("extras", o["extras"])
    return {"method": method, "preset": preset, "pipeline": pipeline, "params": params,
            "lam": check("lam", lam), "k": check("k", o["k"]),
            "iterations": check("iterations", o["iterations"]),
            "rebuild_graph": rebuild_graph, "orient": check("orient", o["orient"]),
            "remove_outliers": remove_outliers, "extras": extras,
            "duplicate_tolerance": check("duplicate_tolerance", o["duplicate_tolerance"]),
            "n_jobs": check("n_jobs", o["n_jobs"]), "report": check("progress", o["progress"])}


def _run(points, normals, runner, tile_points, store, **options):
    """:func:`run` of a cloud without classes."""
    o = checked_options(options)
    method, preset, pipeline, params, lam = (o["method"], o["preset"], o["pipeline"],
                                             o["params"], o["lam"])
    k, iterations, orient, n_jobs = o["k"], o["iterations"], o["orient"], o["n_jobs"]
    pts, dtype = as_points(points)
    check_precision(pts, dtype)
    n = pts.shape[0]
    if k is None:
        # The caller chose no k: the message is about the cloud's size, not about k (the
        # plan resolves k).
        check_size(n)
        paper = PRESETS[preset]["k"] if preset == "paper" else None
        if paper is not None and n < paper + 1:
            raise ValueError(f"the cloud has {n} points; preset {preset!r} uses k = {paper} "
                             f"neighbours and needs at least {paper + 1}; pass a smaller k")
    k = None if k is None else check_k(k, n)
    given = None if normals is None else as_normals(normals, n)
    if params["keep_normals"] and given is None:
        raise ValueError("keep_normals=True needs normals; pass normals=... or drop keep_normals")
    check_orient_estimated(orient, given is not None)
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
    tiles = None
    with threads(n_jobs) as n_threads:
        plan = planning.make(current, preset, pipeline, distinct=distinct, low=low - centre,
                             k=k, iterations=iterations, rebuild_graph=rebuild_graph)
        if pipeline == "default":
            done, (count, most) = _default(current, given, plan, request, runner, tile_points,
                                           store)
        else:
            done, count, most = iterate(current, given, plan, request), 1, distinct
        if runner is not None:
            tiles = {"count": count, "most_points": most, "scheduler": runner.name,
                     "threads": runner.threads}
    return result(Input(pts, dtype, order, groups), done, centre, kept,
                  None if score is None else score.astype(dtype, copy=False),
                  stats(request, plan, n, distinct, n_threads, done.records,
                        int(done.held.sum()), outliers=outliers, tiles=tiles))


def _by_class(points, normals, classification, classes, options, runner, tile_points, store):
    """:func:`denoise` of each class that ``classification`` and ``classes`` choose on its
    own, the other points kept as they are (see its ``classification``)."""
    started = time.perf_counter()
    pts, dtype = as_points(points)
    check_precision(pts, dtype)
    return lidar.denoise_each(pts, dtype, normals, classification, classes, options,
                              lambda part, given: _run(part, given, runner, tile_points, store,
                                                       **options), started)


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
        # A parameter of another method: name that method, not the whole list.
        owners = [m for m in METHOD_DEFAULTS if m != method and set(unknown) <= set(
            METHOD_DEFAULTS[m])]
        hint = (f"method {owners[0]!r} takes {'it' if len(unknown) == 1 else 'them'}: pass "
                f"method={owners[0]!r}" if owners else f"valid: {', '.join(defaults)}")
        raise TypeError(f"unknown parameter(s) {', '.join(unknown)} for method {method!r}; "
                        f"{hint}")
    params = {**defaults, **method_params}
    return {name: check(name, value) for name, value in params.items()}
