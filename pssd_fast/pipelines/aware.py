"""The feature-aware fit of the default method's points (docs/ALGORITHM.md, "The feature-aware
fit"; docs/DECISIONS.md, "Beyond the paper"), the paper's voting that the default method gives
on request."""
from .. import core


def fit_and_move(points, nrm, graph, sigma_n, clock, mass=None):
    """One feature-aware move: the normals ``nrm`` filtered (eq. (4)), a quadratic fitted in
    the frame of each point and its filtered normal, its neighbours weighted by distance and
    normal agreement (``sigma_n``; times ``mass`` if given), with the robust alternative that
    keeps a thin wall's sides apart (not where ``mass`` is given: cell means have averaged the
    sides already, and there it only costs accuracy; docs/DECISIONS.md, "Thin walls"), and the
    projection along the filtered normal. Returns the moved points, the filtered normals, the
    fit's RMS residual and degree, and the points held in place (their step was not finite, or
    longer than the radius of the list it was fitted over)."""
    filtered = clock.run("filter", core.filter_normals, points, nrm, graph)
    height, rms, degree = clock.run("mls", core.aware_fit, points, filtered, graph, sigma_n,
                                    mass, mass is None)
    moved, held = clock.run("update", core.project, points, filtered, height,
                            graph.list_radius())
    return moved, filtered, rms, degree, held


def region_radius(spacing):
    """``R`` of the paper's voting, from the mean spacing ``|E|``, at the paper's constant."""
    return core.FEATURE_DEFAULTS["radius_factor"] * spacing


def voted_feature(points, nrm, graph, radius):
    """Feature intensity by the paper's voting at the paper's thresholds over ``N_R``."""
    paper = core.FEATURE_DEFAULTS
    return core.feature_intensity(points, nrm, graph, radius, paper["delta"], paper["alpha"],
                                  paper["beta"])[0]


def step_record(times, held, rms_sum, n, degree_counts):
    """An iteration's record for ``stats``, from its counts and sums."""
    return {"times": times, "held_points": int(held), "mean_residual": float(rms_sum / n),
            "fit_degree": {name: int(degree_counts[code])
                           for name, code in core.AWARE_FIT_DEGREES.items()}}
