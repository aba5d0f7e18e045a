"""The paper's three models, prepared as in Table 1, with the truth needed to score a denoiser.

Each model is scaled so that its bounding-box diagonal is 1, so distances in units of 1e-4 are
the paper's units. The meshes come from the ``meshes/`` folder of ``$PSSD_DATA``, else of
``DEFAULT_DATA_DIR`` (:func:`mesh_dir`).
"""
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks import meshes

#: Model name -> (file, points) as in the paper's Table 1.
MODELS = {"fandisk": ("fandisk.obj.gz", 97_580), "dragon": ("dragon.obj.gz", 100_056),
          "igea": ("igea.obj.gz", 134_345)}
#: The models' files, in the mesh folder.
MESH_FILES = [f for f, _ in MODELS.values()]
#: The data folder when ``PSSD_DATA`` is unset: ``shared/data`` beside the repository
#: (``<repo>/../shared/data``), holding ``meshes/``, ``lidar/``, ``realscans/`` and ``punet/``.
#: This default belongs to the tests and benchmarks only; :func:`benchmarks.meshes.data_dir`
#: reads ``PSSD_DATA`` or an explicit path.
DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2] / "shared" / "data"
#: Noise levels (Gaussian sigma, fraction of the diagonal); the first is the default.
NOISE_LEVELS = (0.005, 0.0025, 0.01)
#: Dihedral angle above which a mesh edge is sharp, and the distance (fraction of the diagonal)
#: within which a point counts as near a sharp edge.
SHARP_ANGLE = 30.0
EDGE_BAND = 0.01
#: The dragon head: faces whose centroid has y >= 0.10 and z >= 0.15 (the crop that the
#: SOURCES.md of the mesh folder describes).
DRAGON_HEAD = (0.10, 0.15)


@dataclass(frozen=True)
class Model:
    """A clean model: mesh, clean samples with their true normals and edge distances."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    clean: np.ndarray
    normals: np.ndarray
    edge_distance: np.ndarray

    def noisy(self, sigma, seed=0):
        """The clean samples plus isotropic Gaussian noise of std ``sigma`` (seeded)."""
        return self.clean + np.random.default_rng(seed).normal(0.0, sigma, self.clean.shape)


def data_folder(kind):
    """The folder of the data of ``kind`` (one of :data:`benchmarks.meshes.KINDS`) in
    ``$PSSD_DATA`` when set, else in ``DEFAULT_DATA_DIR`` (:func:`benchmarks.meshes.data_path`),
    whether or not it exists."""
    return meshes.data_path(os.environ.get("PSSD_DATA") or DEFAULT_DATA_DIR, kind)


def missing(kind, names):
    """What the tests and benchmarks say when the files ``names`` of ``kind`` are not found."""
    return (f"{', '.join(names)} not found in {data_folder(kind)}: set PSSD_DATA to the folder "
            f"holding {', '.join(f'{k}/' for k in meshes.KINDS)} (when PSSD_DATA is unset, "
            f"they are looked for in {DEFAULT_DATA_DIR})")


def mesh_dir():
    """The mesh folder (:func:`data_folder`); None when it does not exist."""
    folder = data_folder("meshes")
    return folder if folder.is_dir() else None


def available(names=None):
    """Whether the mesh folder holds the models ``names`` (None: every model; tests and
    benchmarks skip the models otherwise)."""
    folder = mesh_dir()
    return folder is not None and all((folder / f).exists() for f in files(names))


def files(names=None):
    """The files of the models ``names`` (None: every model)."""
    return [MODELS[name][0] for name in (MODELS if names is None else names)]


def load(name, n_points=None, seed=0):
    """Prepare model ``name`` ("fandisk", "dragon" or "igea").

    Parameters
    ----------
    n_points : int, optional
        Number of samples; default the paper's count. Fandisk and the dragon head are sampled
        uniformly by area; Igea uses its mesh vertices (a seeded subset when fewer are asked).
    seed : int
        Seed of the sampling.
    """
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; choose one of {', '.join(MODELS)}")
    folder = mesh_dir()
    if folder is None:
        raise FileNotFoundError(missing("meshes", MESH_FILES))
    filename, paper_points = MODELS[name]
    n_points = paper_points if n_points is None else n_points
    vertices, faces = meshes.read_obj(folder / filename)
    if name == "dragon":
        vertices, faces = _crop(vertices, faces, *DRAGON_HEAD)
    vertices, _, _ = meshes.normalize_to_unit_diagonal(vertices)
    if name == "igea":
        normals = _vertex_normals(vertices, faces)
        pick = np.arange(len(vertices))
        if n_points < len(vertices):
            pick = np.sort(np.random.default_rng(seed).choice(len(vertices), n_points, False))
        clean, normals = vertices[pick], normals[pick]
    else:
        clean, _, normals = meshes.sample_surface(vertices, faces, n_points, seed=seed)
    edges = meshes.sharp_edges(vertices, faces, SHARP_ANGLE)
    if len(edges):
        edge_distance = meshes.segment_distance(clean, vertices[edges[:, 0]],
                                                vertices[edges[:, 1]])
    else:
        edge_distance = np.full(len(clean), np.inf)
    return Model(name, vertices, faces, clean, normals, edge_distance)


def _crop(vertices, faces, y_min, z_min):
    """Faces whose centroid lies in the box, with unused vertices dropped."""
    centroid = vertices[faces].mean(axis=1)
    faces = faces[(centroid[:, 1] >= y_min) & (centroid[:, 2] >= z_min)]
    used, faces = np.unique(faces, return_inverse=True)
    return vertices[used], faces.reshape(-1, 3)


def _vertex_normals(vertices, faces):
    """Area-weighted vertex normals (the true normals of a scanned model's vertices)."""
    cross = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                     vertices[faces[:, 2]] - vertices[faces[:, 0]])
    normals = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], cross)
    return normals / np.linalg.norm(normals, axis=1)[:, None]
