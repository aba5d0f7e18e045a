"""`denoise`: resolves the parameters, then runs the iterations of the chosen pipeline."""
import time

import numpy as np

from . import classes as lidar
from . import core, duplicates, interop
from ._threads import threads
from ._validation import (
    as_normals, as_points, auto, check_choice, check_flag, check_float, check_int, check_k,
    check_orient, check_precision, check_size,
)
from .graph import bounds
from .progress import Clock, reporter
from .routes import coarse, edges
from .routes import plan as planning
from .routes.plan import PRESETS
from .run import (
    DenoiseResult, Input, Request, check_distinct, iterate, outlier_scores, result, stats,
)

#: Parameters of each method beyond the common ones, with their defaults.
METHOD_DEFAULTS = {
    "robust": {"h": "auto", **core.FEATURE_DEFAULTS, "likelihood": "exp", "sigma_n": 0.05,
               "shift_normals": True, "select_scales": "auto", "keep_normals": False},
    "bilateral": {"sigma_c": "auto", "sigma_s": "auto", "keep_normals": False},
    "mls": {"h": "auto", "keep_normals": False},
}
#: Methods :func:`denoise` offers.
METHODS = tuple(METHOD_DEFAULTS)
#: Robust-method parameters that only the paper's pipeline uses, and those only the
#: feature-aware pipeline uses.
PAPER_ONLY = ("h", "radius_factor", "delta", "alpha", "beta", "likelihood")
AWARE_ONLY = ("sigma_n", "shift_normals", "select_scales")


def denoise(points, normals=None, *, method="robust", iterations="auto", k="auto", lam=None,
            preset="default", rebuild_graph="auto", orient=None, remove_outliers=False,
            duplicate_tolerance=0.0, classification=None, classes=None, n_jobs=None,
            progress=None, **method_params):
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
        ``"auto"``: 4 ("default"; 2 where it takes "fast"'s cells), 2 ("fast", "paper").
        ``stats["n_iterations"]`` says how many ran.
    k : int or "auto", default "auto"
        Neighbours including the point itself, 10 to ``n - 1``. ``"auto"``: 25 ("paper"),
        else from the noise a probe measures (``stats["auto_k"]``). Given, the iterations run
        on the input points.
    lam : float, optional
        ``lambda`` in [0, 1] (Section 4.2), the likelihood term's weight. Preset "paper" only
        (default 0.5).
    preset : {"default", "fast", "paper"}, default "default"
        ``"default"``: the feature-aware pipeline on the points, or on grid cell means where
        the noise is large against the spacing, or above 50,000 points at low noise on
        "fast"'s cells and then the points near features (docs/ALGORITHM.md, "Routes" and
        "Presets"). ``"fast"``: the same, always on cell means. ``"paper"``: the paper's
        formulation (k = 25, lambda = 0.5, 2 iterations).
    rebuild_graph : bool or "auto", default "auto"
        Query the neighbours anew in each iteration (``True``) or keep the first lists,
        re-sorted (``False``; docs/DECISIONS.md, "Graph and scheduling").
    orient : {"outward", "up"} or array_like of shape (3,), optional
        Sign of the estimated normals, as in :func:`pssd_fast.estimate_normals`; ``None``:
        away from the centroid. Not with ``normals``. The positions do not depend on it.
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
    n_jobs : int or None, default None
        Threads; ``None`` or -1: every thread numba may use. The output does not depend on it.
    progress : bool or callable, optional
        ``True``: a line per stage on stderr; a callable gets ``(iteration, iterations,
        stage, seconds)``.
    **method_params
        The method's own (docs/ALGORITHM.md, "Constants"); one its pipeline does not use
        raises ValueError. The paper's: ``h`` ("auto"), ``radius_factor`` (10), ``delta``,
        ``alpha``, ``beta`` (0.2, 0.3, 0.3), ``likelihood`` ("exp", "ratio", "residual").
        Feature-aware: ``sigma_n`` (0.05), ``shift_normals`` (True), ``select_scales``
        ("auto": on the points of at most 50,000; docs/ALGORITHM.md, "A scale per point").
        ``"mls"``: ``h``; ``"bilateral"``: ``sigma_c``, ``sigma_s`` ("auto"). All:
        ``keep_normals`` (False).

    Returns
    -------
    DenoiseResult

    Raises
    ------
    TypeError
        Non-numeric points, non-integer ``k``, ``iterations`` or ``n_jobs``, unknown keywords.
    ValueError
        Wrong shapes, NaN or Inf, fewer than 11 points or ``k + 1``, values out of range,
        unused parameters, no surface class in ``classification`` by default.

    Warns
    -----
    DenoiseWarning
        float32 ``points`` so far from the origin that their step exceeds 1% of the spacing
        (docs/DECISIONS.md, "float32 coordinates far from the origin"); default classes too
        small to denoise.

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
    >>> result.stats["plan"]["route"], result.stats["k"], result.stats["n_iterations"]
    ('walks', 64, 4)
    >>> def error(points):  # mean distance to the true cube, in 1e-4 of its diagonal
    ...     return f"{1e4 * cloud.surface_distance(points).mean() / cloud.diagonal:.0f}"
    >>> error(cloud.points), error(result.points)
    ('40', '12')
    """
    points = interop.coordinates(points)  # Open3D, trimesh and structured arrays
    if classes is not None or classification is not None:
        return _by_class(points, normals, classification, classes, {
            "method": method, "iterations": iterations, "k": k, "lam": lam, "preset": preset,
            "rebuild_graph": rebuild_graph, "orient": orient, "remove_outliers": remove_outliers,
            "duplicate_tolerance": duplicate_tolerance, "n_jobs": n_jobs, "progress": progress,
            **method_params})
    check_choice(method, "method", METHODS)
    check_choice(preset, "preset", tuple(PRESETS))
    setting = PRESETS[preset]
    pipeline = setting["pipeline"] if method == "robust" else "paper"
    explicit = {name for name, value in method_params.items() if auto(value) is not None}
    rebuild_graph = check_flag(rebuild_graph, "rebuild_graph")
    params = _method_params(method, method_params)
    _check_pipeline_params(method, preset, pipeline, explicit, lam)
    if pipeline != "aware":
        # The paper's pipeline keeps its PCA normals and its fits.
        params.pop("shift_normals", None)
        params.pop("select_scales", None)
    report = reporter(progress)
    pts, dtype = as_points(points)
    check_precision(pts, dtype)
    n = pts.shape[0]
    iterations = auto(iterations, lambda v: check_int(v, "iterations", minimum=1))
    k = auto(k)
    from_noise = k is None and setting["k"] is None
    if k is None:
        # The caller chose no k: the message is about the cloud's size, not about k.
        check_size(n)
        k = setting["k"]
        if not from_noise and n < k + 1:
            raise ValueError(f"the cloud has {n} points; preset {preset!r} uses k = {k} "
                             f"neighbours and needs at least {k + 1}; pass a smaller k")
    k = None if from_noise else check_k(k, n)
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
    duplicate_tolerance = duplicates.check_tolerance(duplicate_tolerance)

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
    centre = 0.5 * np.add(*bounds(pts))
    current = core.relative_rows(pts, order, centre)
    given = None if given is None else given[order]
    request = Request(method, preset, pipeline, lam, params, orient, centre, report, started)
    with threads(n_jobs) as n_threads:
        plan = planning.make(
            current, given, preset, distinct=distinct, k=None if from_noise else k,
            iterations=iterations, layout=lambda noise, key: coarse.layout(current, noise, key),
            aware_pipeline="select_scales" in params, rebuild_graph=rebuild_graph,
            select_scales=params.get("select_scales"), sigma_n=params.get("sigma_n"),
            shift_normals=params.get("shift_normals"))
        if "select_scales" in params:
            params["select_scales"] = plan.select_scales
        if plan.cells is None:
            done = iterate(current, given, plan, request)
        else:
            # Iterate on the cell means; the input points are projected onto them last.
            done = _cells_route(current, given, plan, request, order)
    return result(Input(pts, dtype, order, groups), done, centre, kept,
                  None if score is None else score.astype(dtype, copy=False),
                  stats(request, plan, n, distinct, n_threads, done.records,
                        int(done.held.sum()), outliers=outliers))


def _cells_route(fine, fine_given, plan, request, order):
    """The coarse-to-fine route (``plan.cells``) on the distinct positions ``fine`` (Morton
    ``order`` of the input rows): the iterations on the cell means, then every point moved
    onto their fits (and, on the edges route, the points near features on their own)."""
    cells = coarse.cells_of(fine, fine_given, plan.layout, plan.cells)
    done = iterate(cells.points, cells.normals, plan, request, cells.counts)
    iterations, sigma_n = plan.iterations, request.params["sigma_n"]
    clock = Clock(request.report, iterations - 1, iterations)
    surface, surface_normals, extra = coarse.collapse(cells, done.points, done.normals,
                                                      done.extra)
    current, out_normals, nearest, fit, held = coarse.refine(
        fine, surface, surface_normals, cells.surface_k, sigma_n, clock)
    if plan.edges is not None:
        edges.finish(plan.edges, fine, current, out_normals, held, nearest,
                     edges.zones(surface, extra[1], plan.edges["radius"]), order,
                     fine_given, request.params["keep_normals"], sigma_n, clock)
    done.records[-1]["times"].update(clock.times)
    plan.probe["coarse"] = coarse.describe(plan.noise, cells.edge, cells.counts, surface,
                                           cells.surface_k, fit)
    return done._replace(points=current, normals=out_normals,
                         extra=tuple(x[nearest] for x in extra), held=held)


def _by_class(points, normals, classification, classes, options):
    """:func:`denoise` of each class that ``classification`` and ``classes`` choose on its
    own, the other points kept as they are (see its ``classification``)."""
    started = time.perf_counter()
    pts, dtype = as_points(points)
    check_precision(pts, dtype, stacklevel=4)
    return lidar.denoise_each(pts, dtype, normals, classification, classes, options,
                              lambda part, given: denoise(part, given, **options), started,
                              stacklevel=3)


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
    if "select_scales" in params:
        params["select_scales"] = check_flag(params["select_scales"], "select_scales")
    return params
