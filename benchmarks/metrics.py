"""Scores of a denoised cloud: the paper's displacement columns and errors against the truth.

Distances to the clean mesh are exact closest-point queries of point-cloud-utils (the ``bench``
extra), never nearest-vertex shortcuts: Fandisk has large flat triangles.
All lengths are reported in units of 1e-4 of the bounding-box diagonal (which is 1).
"""
import numpy as np
from pykdtree.kdtree import KDTree

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
    points = np.ascontiguousarray(points, np.float64)
    if points.shape[0] == 1:
        # point-cloud-utils 0.34 reads a single point as a column (a wrong distance): ask twice.
        return surface_distance(np.repeat(points, 2, axis=0), vertices, faces)[:1]
    dist, _, _ = _pcu().closest_points_on_mesh(points, vertices, faces)
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


# --------------------------------------------------------------------------------------------
# The learned denoisers' protocol (benchmarks/punet.py): squared distances, both directions.


def chamfer_squared(points, clean):
    """Chamfer distance as the learned denoisers report it: the mean over ``points`` of the
    squared distance to the nearest of ``clean``, plus the mean over ``clean`` of the squared
    distance to the nearest of ``points``."""
    points = np.ascontiguousarray(points, np.float64)
    clean = np.ascontiguousarray(clean, np.float64)
    there, _ = KDTree(clean).query(points, k=1)
    back, _ = KDTree(points).query(clean, k=1)
    return float(np.mean(np.square(there, dtype=np.float64))
                 + np.mean(np.square(back, dtype=np.float64)))


def point_to_mesh_squared(points, vertices, faces):
    """Point-to-mesh distance as the learned denoisers report it: the mean over ``points`` of
    the squared distance to the mesh, plus the mean over every triangle of the squared
    distance from the triangle to its nearest point (no triangle left out, however small)."""
    points = np.ascontiguousarray(points, np.float64)
    to_mesh = surface_distance(points, vertices, faces)
    return float(np.mean(np.square(to_mesh)) + np.mean(faces_to_points(points, vertices,
                                                                        faces)))


def faces_to_points(points, vertices, faces, first=16):
    """The squared distance from each triangle to its nearest point, exactly.

    Each triangle's ``first`` nearest points to its centroid ``c`` are tried; a point beyond
    them lies at least ``|p - c| - R`` from the triangle (``R``: the centroid's distance to the
    farthest corner), so where the farthest of those tried is at least ``R`` plus the best
    distance found farther from ``c``, no other point can be nearer. Triangles where that
    fails are tried again with twice as many points, until every point is tried.
    """
    corners = np.ascontiguousarray(vertices[faces], np.float64)
    centroid = corners.mean(axis=1)
    reach = np.linalg.norm(corners - centroid[:, None], axis=2).max(axis=1)
    tree = KDTree(points)
    best = np.empty(len(faces))
    todo = np.arange(len(faces))
    count = min(first, len(points))
    while todo.size:
        distance, rows = tree.query(centroid[todo], k=count)
        rows = np.asarray(rows, np.int64).reshape(len(todo), count)
        distance = np.asarray(distance, np.float64).reshape(len(todo), count)
        found = _nearest_to_triangles(points, corners[todo], rows)
        best[todo] = found
        exact = (count == len(points)) | (distance[:, -1] - reach[todo] >= np.sqrt(found))
        todo = todo[~exact]
        count = min(2 * count, len(points))
    return best


def _nearest_to_triangles(points, corners, rows):
    """For each triangle ``corners[t]``, the least squared distance to ``points[rows[t]]``."""
    count = rows.shape[1]
    each = [np.repeat(corners[:, i], count, axis=0) for i in range(3)]
    return triangle_distance_squared(points[rows.ravel()], *each).reshape(-1, count).min(axis=1)


def triangle_distance_squared(p, a, b, c):
    """Squared distance from each of ``p`` to the triangle ``abc`` of its row (arrays of
    shape (m, 3), or one point and triangle of shape (3,)): the closest point by its Voronoi
    regions, after Ericson, *Real-Time Collision Detection*, 5.1.5, the regions tried in his
    order; a triangle of zero area is the segment or point it reduces to."""
    p, a, b, c = (np.atleast_2d(np.asarray(x, np.float64)) for x in (p, a, b, c))

    def dot(u, v):
        return np.einsum("ij,ij->i", u, v)

    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), \
        dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        # Every region's point; np.select keeps the first region that holds, as Ericson's.
        options = [a, b, a + (d1 / (d1 - d3))[:, None] * ab, c,
                   a + (d2 / (d2 - d6))[:, None] * ac,
                   b + ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None] * (c - b),
                   a + (vb / (va + vb + vc))[:, None] * ab + (vc / (va + vb + vc))[:, None] * ac]
    regions = [(d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (vc <= 0) & (d1 >= 0) & (d3 <= 0),
               (d6 >= 0) & (d5 <= d6), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
               (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)]
    q = np.empty_like(p)
    for axis in range(3):
        q[:, axis] = np.select(regions, [o[:, axis] for o in options[:-1]], options[-1][:, axis])
    out = dot(p - q, p - q)
    normal = np.cross(ab, ac)
    flat = ~(dot(normal, normal) > 0.0)
    if flat.any():
        # Zero area: the nearest of its three edges (the regions above would divide by zero).
        out[flat] = np.minimum.reduce([_segment_squared(p[flat], s[flat], e[flat])
                                       for s, e in ((a, b), (b, c), (a, c))])
    return out


def _segment_squared(p, a, b):
    """Squared distance from each of ``p`` to the segment ``ab`` of its row."""
    ab = b - a
    length = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(length > 0, np.einsum("ij,ij->i", p - a, ab) / length, 0.0)
    q = a + np.clip(t, 0.0, 1.0)[:, None] * ab
    return np.einsum("ij,ij->i", p - q, p - q)
