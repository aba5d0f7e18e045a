"""The MLS-projection baseline of the paper (Section 5; docs/ALGORITHM.md)."""
from .. import core
from .records import fit_record


def step(points, nrm, graph, lam, params, clock, last=True):
    """Every point moves to its projection onto its local MLS cubic."""
    h = core.default_h(graph, params["h"])
    proj, _, degree, _ = clock.run("mls", core.mls_fit, points, nrm, graph, h)
    return proj, nrm, None, fit_record(clock.times, h, degree)
