"""Scores of a denoised cloud: the paper's displacement columns and errors against the truth.

Distances to the clean mesh are exact closest-point queries of point-cloud-utils (the ``bench``
extra), never nearest-vertex shortcuts: Fandisk has large flat triangles.
All lengths are reported in units of 1e-4 of the bounding-box diagonal (which is 1).
"""
import numpy as np

from .models import EDGE_BAND

UNIT = 1e-4


def _pcu():
    try:
        import point_cloud_utils
    except ImportError:
        raise ImportError("the Table 1 metrics need point-cloud-utils: "
                          "pip install -e '.[bench]'") from None
    return point_cloud_utils


def surface_distance(points, vertices, faces):
    """Exact distance from each point to the triangle mesh."""
    dist, _, _ = _pcu().closest_points_on_mesh(np.ascontiguousarray(points, np.float64),
                                               vertices, faces)
    return dist


def score(model, noisy, denoised, normals=None, dense=None):
    """All Table 1 columns for one run.

    Parameters
    ----------
    model : benchmarks.models.Model
    noisy, denoised : (n, 3) arrays
        Input and output of the denoiser, point for point.
    normals : (n, 3) array, optional
        Output normals; their angle to the true normals at the clean points is scored.
    dense : (m, 3) array, optional
        Dense clean sample for the Chamfer distance (default: the clean points themselves).

    Returns
    -------
    dict
        ``max_disp``, ``ave_disp`` (the paper's Max/Ave "error", ``|p_noisy - p_denoised|``);
        ``mean_dist``, ``max_dist`` (point-to-mesh); ``edge_dist`` (mean point-to-mesh over points
        whose clean position is within 1% of the diagonal of a sharp edge); ``chamfer`` (mean
        nearest distance output->clean plus clean->output); ``normal_deg`` (mean unsigned angle
        error of the normals, degrees, or None). Lengths in 1e-4 of the diagonal.
    """
    disp = np.linalg.norm(np.asarray(denoised, np.float64) - noisy, axis=1)
    dist = surface_distance(denoised, model.vertices, model.faces)
    near = model.edge_distance < EDGE_BAND
    dense = model.clean if dense is None else dense
    chamfer = _pcu().chamfer_distance(np.ascontiguousarray(denoised, np.float64),
                                      np.ascontiguousarray(dense, np.float64))
    angle = None
    if normals is not None:
        cos = np.abs((normals * model.normals).sum(axis=1))
        cos /= np.linalg.norm(normals, axis=1)
        angle = float(np.degrees(np.arccos(np.clip(cos, 0.0, 1.0))).mean())
    return {
        "max_disp": float(disp.max() / UNIT),
        "ave_disp": float(disp.mean() / UNIT),
        "mean_dist": float(dist.mean() / UNIT),
        "max_dist": float(dist.max() / UNIT),
        "edge_dist": float(dist[near].mean() / UNIT) if near.any() else None,
        "chamfer": float(chamfer / UNIT),
        "normal_deg": angle,
    }
