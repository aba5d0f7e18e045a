"""Real scanner noise: raw range views of the Stanford bunny against the surface fused from all
its views.

Usage::

    python -m benchmarks.rawscans                  # the three shared views
    python -m benchmarks.rawscans --views bun000   # one of them

Each view (the ``realscans/`` folder of ``PSSD_DATA``, or ``--data``) is read as a user would
read it (``pssd_fast.io.read``), denoised in its own frame with no normals and no reference,
moved into the model frame with ``bun.conf`` (``p_model = p_scan @ R + t``, ``R`` the rotation
matrix of the quaternion ``(qx, qy, qz, qw)``), and scored as the folder's ``SOURCES.md``
says: each point's unsigned distance to the reference triangles (``bun_zipper``, fused from
all views), divided by the reference's bounding-box diagonal, leaving out the points whose
nearest reference vertex lies on a boundary edge (the holes in the base); the mean and the
median over the view, x1e4. *Over the views*: the mean of the three views' values. The raw
view is the "noisy" row. The reference fuses registered views, so registration error sets a
floor under every method: a difference of a few percent is real only where it holds on every
view.

Rows: the library's presets and baselines at their defaults, CGAL jet (k 24/48/96 x 1-2
passes) and Open3D ``smooth_mls`` (the same settings), each setting on its own row; times in
seconds and as a ratio to pykdtree's k=25 kNN query of the same view in the same process.
Results: ``benchmarks/results/rawscans.md`` and ``.json``.
"""
import argparse
import time
from pathlib import Path

import numpy as np
from pykdtree.kdtree import KDTree

import pssd_fast
from pssd_fast import io

from . import meshes, peers, versus
from .metrics import surface_distance
from .models import data_folder
from .stages import add_output, machine, positive, save_rows

VIEWS = ("bun000", "bun180", "top3")
REFERENCE = "bun_zipper.obj.gz"
UNIT = 1e4
#: The library's rows: (name, keyword arguments of ``pssd_fast.denoise``).
OURS = (("default", {}), ("fast", {"preset": "fast"}), ("paper", {"preset": "paper"}),
        ("bilateral", {"method": "bilateral"}), ("mls", {"method": "mls"}))
#: The peer families run, each setting a row of its own.
FAMILIES = ("jet", "o3d_mls")


def registration(path):
    """``bun.conf``: view name (file name without ``.ply``) -> ``(R, t)`` with
    ``p_model = p_scan @ R + t``."""
    out = {}
    for line in Path(path).read_text().splitlines():
        words = line.split()
        if not words or words[0] != "bmesh":
            continue
        t = np.array(words[2:5], np.float64)
        out[words[1].removesuffix(".ply")] = (rotation(*map(float, words[5:9])), t)
    return out


def rotation(qx, qy, qz, qw):
    """The rotation matrix of the unit quaternion ``(qx, qy, qz, qw)``."""
    q = np.array([qx, qy, qz, qw]) / np.linalg.norm([qx, qy, qz, qw])
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def boundary_vertices(faces, n_vertices):
    """The mask of the vertices on an edge that only one triangle uses."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]),
                    axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    mask = np.zeros(n_vertices, np.bool_)
    mask[unique[counts == 1].ravel()] = True
    return mask


class Reference:
    """The fused surface: its triangles, diagonal and boundary vertices."""

    def __init__(self, path):
        self.vertices, self.faces = meshes.read_obj(path)
        self.diagonal = float(np.linalg.norm(np.ptp(self.vertices, axis=0)))
        self.boundary = boundary_vertices(self.faces, self.vertices.shape[0])
        self.tree = KDTree(self.vertices)

    def score(self, points, frame):
        """(mean, median) x1e4 of the distances of ``points`` (a view's frame; ``frame`` =
        ``(R, t)``) to the surface over its diagonal, the points nearest a boundary vertex
        left out."""
        rotation_matrix, shift = frame
        moved = np.ascontiguousarray(np.asarray(points, np.float64) @ rotation_matrix + shift)
        _, nearest = self.tree.query(moved, k=1)
        inside = ~self.boundary[np.asarray(nearest, np.int64)]
        distance = surface_distance(moved[inside], self.vertices, self.faces) / self.diagonal
        return UNIT * float(distance.mean()), UNIT * float(np.median(distance))


def measure(name, points, frame, reference, log, families=FAMILIES):
    """One view's rows: the raw view, the library's rows and every setting of the peer
    ``families``."""
    row = {"view": name, "points": int(points.shape[0]),
           "knn_seconds": versus.knn_reference(points), "rows": {}}
    mean, median = reference.score(points, frame)
    row["rows"]["raw view"] = {"mean": mean, "median": median}
    runs = [(label, lambda o=options: pssd_fast.denoise(points, **o)) for label, options in OURS]
    runs += [(f"{versus.PEER_NAMES[family]} ({label})",
              lambda c=getattr(peers, versus.PEER_CALLS[family]), k=kwargs: c(points, **k))
             for family in families for label, kwargs in versus.PEER_SETTINGS[family].items()]
    for label, run in runs:
        started = time.perf_counter()
        result = run()
        seconds = time.perf_counter() - started
        if isinstance(result, peers.PeerResult):
            seconds = result.seconds
        mean, median = reference.score(result.points, frame)
        entry = {"mean": mean, "median": median, "seconds": seconds}
        if not isinstance(result, peers.PeerResult):
            plan = result.stats["plan"]
            entry["route"] = f"{plan['method']}, k={plan['k']}"
        row["rows"][label] = entry
        log(f"  {label:28s} {mean:6.3f} {median:6.3f} {seconds:7.2f} s")
    return row


def markdown(rows, compile_seconds):
    """The table: per view and over the views, mean / median, then seconds (x kNN)."""
    labels = list(rows[0]["rows"])
    head = ("| method | " + " | ".join(r["view"] for r in rows)
            + " | over the views | seconds (x kNN) |")
    out = [f"Machine: {machine()}. JIT compilation before timing: {compile_seconds:.1f} s.", "",
           "Distance to the fused reconstruction, x1e4 of its bounding-box diagonal, mean / "
           "median over each view's points (points nearest a hole of the reference left out); "
           "*over the views*: the mean of the views' values. Seconds: mean over the views, "
           "with the mean ratio to the k=25 kNN query of the same view.", "", head,
           "|---|" + "---|" * (len(rows) + 2)]
    for label in labels:
        entries = [r["rows"][label] for r in rows]
        cells = [f"{e['mean']:.3f} / {e['median']:.3f}" for e in entries]
        over = (f"{np.mean([e['mean'] for e in entries]):.3f} / "
                f"{np.mean([e['median'] for e in entries]):.3f}")
        if "seconds" in entries[0]:
            ratio = np.mean([e["seconds"] / r["knn_seconds"] for e, r in zip(entries, rows)])
            cost = f"{np.mean([e['seconds'] for e in entries]):.2f} ({ratio:.0f})"
        else:
            cost = "-"
        name = f"**{label}**" if label == "default" else label
        out.append(f"| {name} | " + " | ".join(cells) + f" | {over} | {cost} |")
    out += ["", "Routes of the default: " + "; ".join(
        f"{r['view']} {r['rows']['default']['route']}" for r in rows) + ".",
        "", _standing(rows)]
    return "\n".join(out) + "\n"


def _standing(rows):
    """Per view, whether the default is closer (mean) than the best CGAL jet setting."""
    if not any(label.startswith("CGAL jet") for label in rows[0]["rows"]):
        return "CGAL jet was not run."
    parts = []
    for r in rows:
        jets = {k: v["mean"] for k, v in r["rows"].items() if k.startswith("CGAL jet")}
        best = min(jets, key=jets.get)
        ours = r["rows"]["default"]["mean"]
        parts.append(f"{r['view']}: default {ours:.3f}, best jet {jets[best]:.3f} "
                     f"{best.removeprefix('CGAL jet ')}, "
                     + ("closer" if ours < jets[best] else "farther"))
    return "Default against the best jet setting of each view (mean): " + "; ".join(parts) + "."


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--views", nargs="+", default=list(VIEWS), choices=VIEWS)
    parser.add_argument("--data", type=Path, default=data_folder("realscans"),
                        help="the folder of the views, bun.conf and the reference")
    parser.add_argument("--peers", nargs="*", default=list(FAMILIES), choices=FAMILIES,
                        help="the peer families to run (default both; none: the library only)")
    parser.add_argument("--every", type=positive(int), default=1,
                        help="keep every N-th point of each view (a quick run; default 1)")
    add_output(parser, "rawscans")
    args = parser.parse_args(argv)
    versus.check_inputs(parser, args, "the raw scans",
                        [f"{v}.ply.gz" for v in args.views] + ["bun.conf", REFERENCE])
    return args


def main(argv=None):
    args = parse_args(argv)
    log = (lambda line: None) if args.quiet else print
    compile_seconds = pssd_fast.warmup()
    frames = registration(args.data / "bun.conf")
    reference = Reference(args.data / REFERENCE)
    rows = []
    for view in args.views:
        points = np.ascontiguousarray(io.read(args.data / f"{view}.ply.gz").points[::args.every])
        log(f"{view} ({points.shape[0]} points)")
        rows.append(measure(view, points, frames[view], reference, log, args.peers))
    return save_rows(args, markdown(rows, compile_seconds), rows, compile_seconds, log)


if __name__ == "__main__":
    main()
