"""The paper's pipeline (preset "paper"; docs/ALGORITHM.md steps 1-4)."""
from .. import core
from .records import fit_record


def step(points, nrm, graph, lam, params, clock, last=True):
    """One robust iteration of the paper once the graph and normals exist.

    MLS cubic fit (projection ``q_i``, residual ``d_i``), sampling likelihood ``l_i``, feature
    intensity ``s_i`` over the region-grown ``N_R``, bilateral filter of the normals to ``n*_i``,
    and the move ``p_i + m_i |q_i - p_i| n*_i`` with ``m_i`` from ``l_i``, ``s_i`` and ``lam``.
    Every quantity uses the positions at the start of the iteration.
    """
    h = core.default_h(graph, params["h"])
    proj, resid, degree, _ = clock.run("mls", core.mls_fit, points, nrm, graph, h)
    lik, dbar = clock.run("likelihood", core.sampling_likelihood, resid, params["likelihood"])
    spacing = core.mean_spacing(graph)
    radius = params["radius_factor"] * spacing
    feat, region = clock.run("feature", core.feature_intensity, points, nrm, graph, radius,
                             params["delta"], params["alpha"], params["beta"])
    filtered = clock.run("filter", core.filter_normals, points, nrm, graph)
    moved, held = clock.run("update", core.move, points, proj, filtered, lik, feat, lam)
    moved, held = core.hold_unsupported(points, moved, graph.list_radius(), held)
    record = fit_record(clock.times, h, degree)
    record.update({
        "held_points": int(held.sum()),
        "mean_spacing": spacing,
        "region_radius": radius,
        "mean_residual": dbar,
        "region_size_mean": float(region.mean()),
        "region_size_max": int(region.max()),
    })
    return moved, filtered, (lik, feat), record, held
