"""The learned denoisers' benchmark: PU-Net's test meshes, as ScoreDenoise, IterativePFN and
P2P-Bridge report on them, against this library and the classical peers.

Usage::

    python -m benchmarks.punet                         # 8 meshes x 10,000 / 50,000 x 1-3%
    python -m benchmarks.punet --sizes 10000 --noise 0.01 --meshes casting
    python -m benchmarks.punet --refresh-peers         # re-run the peers (about an hour)

The protocol of ``shared/data/punet/SOURCES.md``, on its 8 meshes (the ``punet/`` folder of
``PSSD_DATA``, or ``--data``):

1. **Sample.** Poisson-disk samples of the clean mesh (point-cloud-utils'
   ``sample_mesh_poisson_disk``, the ``bench`` extra, as those papers' data), exactly ``N`` of
   them, reproducibly: point-cloud-utils returns about 1.4 ``N`` points for ``N`` asked (it
   ignores its tolerance) and seeds from the clock at ``random_seed=0``. So the sampler is
   called with a fixed non-zero seed per mesh and size, and its sample is thinned to ``N`` by
   removing, one at a time, the point nearest to another (lower row first on a tie), which
   keeps the blue-noise spacing (:func:`thin`).
2. **Normalise** the clean sample to the unit sphere (centre of its bounding box, largest
   distance from it), the mesh with the same translation and scale.
3. **Noise**: isotropic Gaussian, standard deviation 1%, 2% or 3% of that unit radius, a fixed
   seed per cell.
4. **Denoise** the noisy cloud alone (no normals, no mesh).
5. **Score** x1e4 in that frame: CD, the mean squared distance from the denoised points to the
   nearest clean point plus the reverse; P2M, the mean squared distance from the denoised
   points to the mesh plus the mean over every triangle of its squared distance to the
   nearest denoised point (``benchmarks.metrics``).

Rows: the noisy input; the library's presets (default, fast, paper) and baselines (bilateral,
mls) at their defaults; the peers as ``benchmarks.versus`` tunes them (CGAL jet k 24/48/96 x
1-2 passes, CGAL bilateral k 60/120, Open3D ``smooth_mls`` k 24/48/96 x 1-2 passes,
``smooth_bilateral`` 12 settings), each family's best setting per cell and column; every time
as seconds and as a ratio to pykdtree's k=25 kNN query of the same cloud in the same process.
Beside them, the learned methods' published averages (:data:`PUBLISHED`). Peer scores are
cached in ``benchmarks/results/punet_peers.json`` (``--refresh-peers`` recomputes them).
Results: ``benchmarks/results/punet.md`` and ``.json``.
"""
import argparse
import heapq
import time
import zlib
from pathlib import Path

import numpy as np
from pykdtree.kdtree import KDTree

import pssd_fast

from . import meshes, versus
from .metrics import chamfer_squared, point_to_mesh_squared
from .models import data_folder
from .stages import add_output, machine, positive, save_rows

RESULTS = Path(__file__).resolve().parent / "results"
PEER_CACHE = RESULTS / "punet_peers.json"
MESHES = ("camel", "casting", "chair", "cow", "duck", "elephant", "fandisk", "kitten")
SIZES = (10_000, 50_000)
NOISE_LEVELS = (0.01, 0.02, 0.03)
#: The library's rows: (name, keyword arguments of ``pssd_fast.denoise``).
OURS = (("default", {}), ("fast", {"preset": "fast"}), ("paper", {"preset": "paper"}),
        ("bilateral", {"method": "bilateral"}), ("mls", {"method": "mls"}))
COLUMNS = ("cd", "p2m")
#: The learned methods' published CD / P2M x1e4, averages over the protocol's 20 test
#: meshes, by (points, noise), as P2P-Bridge's comparison table gives them (the bilateral
#: row is that table's classical baseline).
PUBLISHED = {
    "bilateral (as published)": ((3.65, 1.34), (5.01, 2.02), (7.00, 3.56),
                                 (0.88, 0.23), (2.38, 1.39), (6.30, 4.73)),
    "ScoreDenoise (ICCV 2021)": ((2.52, 0.46), (3.69, 1.07), (4.71, 1.94),
                                 (0.72, 0.15), (1.29, 0.57), (1.93, 1.04)),
    "IterativePFN (CVPR 2023)": ((2.31, 0.37), (3.43, 0.90), (5.24, 2.50),
                                 (0.66, 0.12), (1.05, 0.43), (2.54, 1.65)),
    "P2P-Bridge (ECCV 2024)": ((2.28, 0.39), (3.20, 0.81), (3.99, 1.42),
                               (0.59, 0.09), (0.90, 0.32), (1.56, 0.84)),
}
UNIT = 1e4


def thin(points, n, neighbours=16):
    """The rows of ``points`` kept when removing, one at a time, the point nearest to another
    until ``n`` remain (ties: the lower row goes first); sorted.

    Each point knows its ``neighbours`` nearest; a point whose nearest remaining one is gone
    looks further down its list (past the list, it is never the nearest pair again).
    """
    m = points.shape[0]
    if n > m:
        raise ValueError(f"cannot thin {m} points to {n}")
    count = min(neighbours + 1, m)
    distance, rows = KDTree(points).query(points, k=count)
    distance = np.asarray(distance, np.float64).reshape(m, count)[:, 1:]
    rows = np.asarray(rows, np.int64).reshape(m, count)[:, 1:]
    owners = [[] for _ in range(m)]
    for i in range(m):
        for j in rows[i]:
            owners[j].append(i)
    alive = np.ones(m, np.bool_)
    at = np.zeros(m, np.int64)  # the position of each point's nearest remaining neighbour
    gap = distance[:, 0].tolist()
    heap = [(d, i) for i, d in enumerate(gap)]
    heapq.heapify(heap)
    for _ in range(m - n):
        while True:
            d, i = heapq.heappop(heap)
            if alive[i] and d == gap[i]:
                break
        alive[i] = False
        for o in owners[i]:
            if not alive[o] or rows[o, at[o]] != i:
                continue
            while at[o] < rows.shape[1] and not alive[rows[o, at[o]]]:
                at[o] += 1
            gap[o] = distance[o, at[o]] if at[o] < rows.shape[1] else np.inf
            heapq.heappush(heap, (gap[o], o))
    return np.flatnonzero(alive)


def poisson_sample(vertices, faces, n, seed):
    """Exactly ``n`` Poisson-disk samples of the mesh (point-cloud-utils, thinned by
    :func:`thin`); ``seed`` must not be 0 (point-cloud-utils seeds from the clock at 0)."""
    import point_cloud_utils as pcu
    if seed == 0:
        raise ValueError("seed 0 makes point-cloud-utils seed from the clock")
    faces32 = np.ascontiguousarray(faces, np.int32)
    f_idx, bary = pcu.sample_mesh_poisson_disk(vertices, faces32, n, random_seed=seed)
    points = pcu.interpolate_barycentric_coords(faces32, f_idx, bary, vertices)
    if points.shape[0] < n:
        raise RuntimeError(f"point-cloud-utils returned {points.shape[0]} samples for {n}")
    return np.ascontiguousarray(points[thin(points, n)], np.float64)


def normalise(clean, vertices):
    """The clean sample in the unit sphere (bounding-box centre, largest distance from it)
    and the mesh's vertices moved and scaled alike."""
    centre = 0.5 * (clean.min(axis=0) + clean.max(axis=0))
    scale = np.linalg.norm(clean - centre, axis=1).max()
    return (clean - centre) / scale, (vertices - centre) / scale


def seed_of(*parts):
    """A fixed, non-zero seed for a cell (the same in every run and on every machine)."""
    return 1 + zlib.crc32("|".join(map(str, parts)).encode()) % (2**31 - 2)


class Cell:
    """One cell of the protocol: a mesh sampled at ``n`` points with Gaussian ``noise``."""

    def __init__(self, name, vertices, faces, clean, noise):
        self.name, self.vertices, self.faces, self.clean, self.noise = (name, vertices, faces,
                                                                       clean, noise)
        rng = np.random.default_rng(seed_of(name, clean.shape[0], noise))
        self.points = clean + rng.normal(0.0, noise, clean.shape)
        self.columns = COLUMNS

    def score(self, denoised):
        """(CD, P2M) x1e4 of a denoised cloud."""
        return (UNIT * chamfer_squared(denoised, self.clean),
                UNIT * point_to_mesh_squared(denoised, self.vertices, self.faces))


def load_mesh(name, n, data):
    """The normalised clean sample of mesh ``name`` at ``n`` points and its mesh."""
    vertices, faces = meshes.read_off(Path(data) / f"{name}.off.gz")
    clean = poisson_sample(vertices, faces, n, seed_of(name, n))
    clean, vertices = normalise(clean, vertices)
    return vertices, faces, clean


def run_ours(cell, options):
    """One of the library's rows on a cell: scores, seconds and the route it took."""
    started = time.perf_counter()
    result = pssd_fast.denoise(cell.points, **options)
    seconds = time.perf_counter() - started
    cd, p2m = cell.score(result.points)
    plan = result.stats["plan"]
    return {"cd": cd, "p2m": p2m, "seconds": seconds,
            "route": f"{plan['method']}, k={plan['k']}"}


def measure(cell, peers, log):
    """A cell's row: the noisy input, the library's rows and each peer family's minima
    (``peers``: family -> setting -> scores, as ``benchmarks.versus.peer_cell`` gives them)."""
    cd, p2m = cell.score(cell.points)
    row = {"mesh": cell.name, "points": cell.points.shape[0], "noise": cell.noise,
           "noisy": {"cd": cd, "p2m": p2m}, "knn_seconds": versus.knn_reference(cell.points),
           "ours": {}, "peers": {family: versus.best_entry(settings, COLUMNS)
                                 for family, settings in peers.items()}}
    for name, options in OURS:
        ours = row["ours"][name] = run_ours(cell, options)
        log(f"  ours {name:10s} {ours['cd']:7.2f} {ours['p2m']:7.2f} {ours['seconds']:7.2f} s"
            f"  {ours['route']}")
    return row


#: The rows of the tables: (where in a cell's row, the key there, the name in the table).
ROWS = (("noisy", None, "noisy input"), ("ours", "default", "**default**"),
        ("ours", "fast", "fast"), ("ours", "paper", "paper"),
        ("ours", "bilateral", "bilateral (ours)"), ("ours", "mls", "mls (ours)"),
        ("peers", "jet", "best CGAL jet"), ("peers", "bilateral", "best CGAL bilateral"),
        ("peers", "o3d_mls", "best Open3D MLS"),
        ("peers", "o3d_bilateral", "best Open3D bilateral"))


def _present(rows):
    """The specs of :data:`ROWS` that ``rows`` hold (the peers run)."""
    return [spec for spec in ROWS if spec[0] != "peers" or spec[1] in rows[0]["peers"]]


def _entry(row, spec):
    """A cell's scores for the table row ``spec`` (of :data:`ROWS`)."""
    where, key, _ = spec
    return row["noisy"] if where == "noisy" else row[where][key]


def _columns(rows):
    """The (points, noise) of the table's columns, in order."""
    return sorted({(r["points"], r["noise"]) for r in rows})


def _mean(rows, spec, column):
    return float(np.mean([_entry(r, spec)[column] for r in rows]))


def summary(rows):
    """The headline table: each row's CD / P2M averaged over the meshes of each column,
    the published learned numbers beneath, then the times."""
    columns = _columns(rows)
    head = "| method | " + " | ".join(f"{n // 1000}K {100 * s:g}%" for n, s in columns) + " |"
    rule = "|---|" + "---|" * len(columns)
    out = [head, rule]
    for spec in _present(rows):
        cells = []
        for n, s in columns:
            here = [r for r in rows if (r["points"], r["noise"]) == (n, s)]
            cells.append(f"{_mean(here, spec, 'cd'):.2f} / {_mean(here, spec, 'p2m'):.2f}")
        name = spec[2]
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    order = [(n, s) for n in SIZES for s in NOISE_LEVELS]
    for name, values in PUBLISHED.items():
        cells = [(f"{values[order.index(c)][0]:.2f} / {values[order.index(c)][1]:.2f}"
                  if c in order else "-") for c in columns]
        out.append(f"| {name}, published | " + " | ".join(cells) + " |")
    out += ["", "Time, seconds (ratio to the k=25 kNN query of the same cloud), mean over the "
            "meshes:", "", head, rule]
    for spec in _present(rows)[1:]:
        cells = []
        for n, s in columns:
            here = [r for r in rows if (r["points"], r["noise"]) == (n, s)]
            ratio = float(np.mean([_entry(r, spec)["seconds"] / r["knn_seconds"]
                                   for r in here]))
            cells.append(f"{_mean(here, spec, 'seconds'):.2f} ({ratio:.0f})")
        out.append(f"| {spec[2]} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def _standing(rows):
    """Where the default stands, cell by cell: how many meshes it beats the best classical
    peer on (per column), and where it is farther from the truth than the noisy input."""
    out = []
    peers = [spec for spec in _present(rows) if spec[0] == "peers"]
    for n, s in _columns(rows) if peers else ():
        here = [r for r in rows if (r["points"], r["noise"]) == (n, s)]
        for column in COLUMNS:
            won = sum(r["ours"]["default"][column]
                      < min(_entry(r, spec)[column] for spec in peers) for r in here)
            out.append(f"{n // 1000}K {100 * s:g}% {column.upper()}: default below every peer "
                       f"on {won} of {len(here)} meshes")
    worse = [f"{r['mesh']} {r['points'] // 1000}K {100 * r['noise']:g}% {key}"
             for r in rows for key in ("default", "fast")
             for column in COLUMNS if r["ours"][key][column] > r["noisy"][column]]
    out.append("Farther from the truth than the noisy input: "
               + (", ".join(sorted(set(worse))) if worse else "none"))
    return out


def cells_table(rows):
    """Every cell: CD / P2M of each row, the route the default took and its time ratio."""
    specs = _present(rows)
    head = ("| mesh | N | noise | " + " | ".join(spec[2] for spec in specs)
            + " | default route | default / kNN |")
    out = [head, "|---|---|---|" + "---|" * (len(specs) + 2)]
    for r in rows:
        cells = [f"{_entry(r, spec)['cd']:.2f} / {_entry(r, spec)['p2m']:.2f}"
                 for spec in specs]
        default = r["ours"]["default"]
        out.append(f"| {r['mesh']} | {r['points'] // 1000}K | {100 * r['noise']:g}% | "
                   + " | ".join(cells) + f" | {default['route']} | "
                   f"{default['seconds'] / r['knn_seconds']:.0f} |")
    return "\n".join(out)


def markdown(rows, compile_seconds):
    """The results file: the headline table, the standing, every cell."""
    text = [f"Machine: {machine()}. JIT compilation before timing: {compile_seconds:.1f} s.",
            "",
            "CD / P2M x1e4 (squared distances, both directions), mean over the meshes "
            f"({', '.join(sorted({r['mesh'] for r in rows}))}). *Best*: each peer family's "
            "best setting per cell and column (tuned on the truth, as in `benchmarks.versus`). "
            "The published rows are averages over the protocol's 20 meshes, of which these are "
            "8: a guide, not a like-for-like comparison.", "", summary(rows), "",
            *[f"- {line}" for line in _standing(rows)], "", "Every cell:", "",
            cells_table(rows)]
    return "\n".join(text) + "\n"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", nargs="+", default=list(MESHES), choices=MESHES)
    parser.add_argument("--sizes", type=positive(int), nargs="+", default=list(SIZES))
    parser.add_argument("--noise", type=positive(float), nargs="+", default=list(NOISE_LEVELS))
    parser.add_argument("--data", type=Path, default=data_folder("punet"),
                        help="the folder of the PU-Net meshes (*.off.gz)")
    parser.add_argument("--peers", nargs="*", default=list(versus.FAMILIES),
                        choices=versus.FAMILIES,
                        help="the peer families to run (default all; none: the library only)")
    parser.add_argument("--refresh-peers", action="store_true")
    add_output(parser, "punet")
    args = parser.parse_args(argv)
    versus.check_inputs(parser, args, "the PU-Net meshes",
                        [f"{m}.off.gz" for m in args.meshes])
    return args


def main(argv=None):
    args = parse_args(argv)
    log = (lambda line: None) if args.quiet else print
    compile_seconds = pssd_fast.warmup()
    cache = args.out / PEER_CACHE.name
    rows = []
    for name in args.meshes:
        for n in args.sizes:
            vertices, faces, clean = load_mesh(name, n, args.data)
            for noise in args.noise:
                cell = Cell(name, vertices, faces, clean, noise)
                log(f"{name} {n} {noise:.0%}")
                peers = versus.peer_cell(cell, f"{name}|{n}|{noise:g}", cache,
                                         args.refresh_peers, log, args.peers)
                rows.append(measure(cell, {f: peers[f] for f in args.peers}, log))
    return save_rows(args, markdown(rows, compile_seconds), rows, compile_seconds, log)


if __name__ == "__main__":
    main()
