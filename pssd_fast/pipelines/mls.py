"""The MLS-projection baseline of the paper (Section 5; docs/ALGORITHM.md)."""
from .. import core
from .records import fit_record


def step(points, nrm, graph, lam, params, clock, last=True):
    """Every point moves to its projection onto its local MLS cubic (unless that lies beyond
    its list's radius)."""
    h = core.default_h(graph, params["h"])
    proj, _, degree, _ = clock.run("mls", core.mls_fit, points, nrm, graph, h)
    moved, held = core.hold_unsupported(points, proj, graph.list_radius())
    record = fit_record(clock.times, h, degree)
    record["held_points"] = int(held.sum())
    return moved, nrm, None, record, held
