"""Feature intensity on Fandisk against its known feature curves (reference meshes: see
``data_file`` in conftest.py).

Measured rates (30,000 area-uniform samples, unit diagonal, k = 25, defaults of eq. (3)):
clean samples: mean s = 0.22 within 1% of the diagonal of a feature curve, 0.001 farther than
3%; s > 0.3 for 28% of the points near curves and none on faces. With Gaussian noise of 0.25%
of the diagonal: mean 0.45 near against 0.05 on faces; s > 0.3 for 50% near, 2% on faces.
"""
import numpy as np
import pytest

import pssd_fast
from benchmarks import meshes

from .conftest import data_file


@pytest.fixture(scope="module")
def fandisk():
    vertices, faces = meshes.read_obj(data_file("meshes", "fandisk.obj.gz"))
    vertices, scale, offset = meshes.normalize_to_unit_diagonal(vertices)
    curves = [(c - offset) * scale
              for c in meshes.read_feat(data_file("meshes", "fandisk.feat.gz"))]
    points, _, _ = meshes.sample_surface(vertices, faces, 30_000, seed=0)
    a = np.vstack([c[:-1] for c in curves])
    b = np.vstack([c[1:] for c in curves])
    return points, meshes.segment_distance(points, a, b)


@pytest.mark.parametrize("noise, near_mean, near_rate, face_mean, face_rate", [
    (0.0, 0.15, 0.2, 0.01, 0.005),
    (0.0025, 0.35, 0.4, 0.08, 0.04),
])
def test_feature_intensity_follows_the_feature_curves(fandisk, noise, near_mean, near_rate,
                                                      face_mean, face_rate):
    points, curve_distance = fandisk
    noisy = points + np.random.default_rng(1).normal(0, noise, points.shape)
    s = pssd_fast.feature_intensity(noisy)
    near, face = curve_distance < 0.01, curve_distance > 0.03
    assert s[near].mean() > near_mean and (s[near] > 0.3).mean() > near_rate
    assert s[face].mean() < face_mean and (s[face] > 0.3).mean() < face_rate
    assert s[near].mean() > 5 * s[face].mean()
