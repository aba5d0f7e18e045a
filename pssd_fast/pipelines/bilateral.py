"""The bilateral (BIL) baseline of the paper (Section 5; docs/ALGORITHM.md)."""
from .. import core


def step(points, nrm, graph, lam, params, clock, last=True):
    """Every point moves along its normal by the bilateral mean height of its neighbours
    (unless that lies beyond its list's radius)."""
    moved = clock.run("bilateral", core.filter_points, points, nrm, graph,
                      params["sigma_c"] or 0.0, params["sigma_s"] or 0.0)
    moved, held = core.hold_unsupported(points, moved, graph.list_radius())
    return moved, nrm, None, {"times": clock.times, "held_points": int(held.sum())}, held
