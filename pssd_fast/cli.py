"""The ``pssd`` command: denoise files, run the demo, describe and render clouds.

Every failure prints one line, ``pssd: error: ...``, and exits with status 1 (2 for a bad
command line); no traceback reaches the user.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__

#: Per-method options of ``pssd denoise``: option dest -> (methods that take it, help).
METHOD_OPTIONS = {
    "h": (("robust", "mls"), "MLS Gaussian width (default: mean distance to the k-th "
                             "neighbour)"),
    "radius_factor": (("robust",), "R = radius_factor * mean spacing for the region-grown "
                                   "neighbourhood (10)"),
    "delta": (("robust",), "feature threshold delta of eq. (3) (0.2)"),
    "alpha": (("robust",), "feature threshold alpha of eq. (3) (0.3)"),
    "beta": (("robust",), "feature threshold beta of eq. (3) (0.3)"),
    "likelihood": (("robust",), "sampling likelihood form: exp, ratio or residual (exp)"),
    "sigma_c": (("bilateral",), "BIL spatial width (default: half the list radius)"),
    "sigma_s": (("bilateral",), "BIL height width (default: std of the heights)"),
}
COLORS = ("likelihood", "feature", "curvature", "displacement", "height")
#: Stems of the files ``pssd demo`` writes (point clouds and the paper's figure set).
DEMO_FILES = ("noisy", "denoised", "curvature", "likelihood", "feature", "denoised_curvature",
              "denoised_displacement")
STAGE_COUNT = {"robust": 7, "mls": 3, "bilateral": 3}


class CommandError(Exception):
    """A failure explained by its message alone."""


def main(argv=None):
    """Entry point of the ``pssd`` console script; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "run"):
        parser.print_help()
        return 2
    try:
        return args.run(args) or 0
    except KeyboardInterrupt:
        print("pssd: interrupted", file=sys.stderr)
        return 130
    except (CommandError, OSError, ValueError, TypeError, ImportError) as exc:
        print(f"pssd: error: {_one_line(exc)}", file=sys.stderr)
        return 1


def _one_line(exc):
    text = str(exc).strip().splitlines()
    message = text[0] if text else type(exc).__name__
    if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in message:
        message = f"{exc.filename}: {message}"
    return message


def _parser():
    parser = argparse.ArgumentParser(
        prog="pssd", description="Feature-preserving denoising of point-sampled surfaces.")
    parser.add_argument("--version", action="version", version=f"pssd_fast {__version__}")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")

    den = sub.add_parser(
        "denoise", help="denoise a point cloud file",
        description="Denoise IN and write OUT (format from OUT's extension: .ply, .xyz, .pts, "
                    ".txt, .npy, .npz, .las, .laz). Every attribute of the input is written back "
                    "unchanged; likelihood, feature_intensity, displacement and outlier_score "
                    "are added as new per-point properties where the format can hold them.")
    den.add_argument("input", metavar="IN", type=Path, help="input point cloud")
    den.add_argument("output", metavar="OUT", type=Path, help="output file")
    den.add_argument("--method", choices=("robust", "bilateral", "mls"), default="robust",
                     help="robust (the paper's method), bilateral (BIL) or mls (default robust)")
    _add_common(den)
    for dest, (methods, text) in METHOD_OPTIONS.items():
        kind = str if dest == "likelihood" else float
        den.add_argument("--" + dest.replace("_", "-"), dest=dest, type=kind, default=None,
                         help=f"{text}; method {' or '.join(methods)}")
    den.add_argument("--keep-normals", action="store_true",
                     help="use the file's normals in every iteration instead of re-estimating")
    den.add_argument("--orient", type=_orientation, default=None, metavar="HOW",
                     help="sign of the estimated normals: outward, up, or a viewpoint X,Y,Z "
                          "(normals towards it), made consistent over the neighbour graph "
                          "(default: up for .las/.laz input, else each normal away from the "
                          "centroid)")
    den.add_argument("--remove-outliers", action="store_true",
                     help="drop the points whose outlier score exceeds 1 before denoising "
                          "(the score is written as outlier_score either way)")
    den.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    _add_verbosity(den)
    den.set_defaults(run=_denoise)

    demo = sub.add_parser(
        "demo", help="denoise the built-in CAD part and draw the figure set",
        description="Generate the library's noisy CAD part, denoise it, write the input, the "
                    "result and the paper's figure set (noisy input, mean curvature, sampling "
                    "likelihood, feature intensity, result by curvature and by displacement) into "
                    "a folder, and print the Table-1-style line.")
    demo.add_argument("--out", type=Path, default=Path("pssd_demo"),
                      help="folder for the files and pictures (pssd_demo)")
    demo.add_argument("--points", type=int, default=100_000, help="points (100000)")
    demo.add_argument("--noise", type=float, default=0.0025,
                      help="noise sigma, fraction of the bounding-box diagonal (0.0025)")
    demo.add_argument("--seed", type=int, default=0, help="seed of the generated input (0)")
    _add_common(demo)
    demo.add_argument("--force", action="store_true", help="overwrite files in the folder")
    _add_verbosity(demo)
    demo.set_defaults(run=_demo, method="robust")

    info = sub.add_parser("info", help="describe a point cloud file",
                          description="Print point count, bounds, average spacing and the "
                                      "attributes FILE holds.")
    info.add_argument("file", metavar="FILE", type=Path)
    info.set_defaults(run=_info)

    render = sub.add_parser(
        "render", help="draw a point cloud as a PNG",
        description="Draw FILE coloured by a per-point field. likelihood, feature and curvature "
                    "are taken from FILE when it holds them (as pssd denoise writes them), else "
                    "computed; displacement must be in FILE; height is the vertical "
                    "coordinate of the view.")
    render.add_argument("file", metavar="FILE", type=Path)
    render.add_argument("-o", "--output", type=Path, required=True, help="PNG to write")
    render.add_argument("--color", choices=COLORS, default="height",
                        help="field to colour by (height)")
    render.add_argument("--view", type=float, nargs=2, default=(30.0, -60.0),
                        metavar=("ELEV", "AZIM"), help="view elevation and azimuth in degrees")
    render.add_argument("--k", type=int, default=25, help="neighbours for computed fields (25)")
    render.add_argument("--force", action="store_true", help="overwrite the PNG if it exists")
    render.set_defaults(run=_render)
    return parser


def _orientation(text):
    """``--orient``: a named orientation or a viewpoint ``X,Y,Z``."""
    if text in ("outward", "up"):
        return text
    try:
        view = [float(v) for v in text.split(",")]
    except ValueError:
        view = []
    if len(view) != 3 or not all(np.isfinite(view)):
        raise argparse.ArgumentTypeError(f"expected outward, up or a viewpoint X,Y,Z; got "
                                          f"{text!r}")
    return view


def _add_common(parser):
    parser.add_argument("--iterations", type=int, default=None,
                        help="iterations (preset: 4 default, 2 fast, 2 paper)")
    parser.add_argument("--preset", choices=("default", "fast", "paper"), default="default",
                        help="default: feature-aware fit, k from the estimated noise, 4 "
                             "iterations; fast: the same with k=48, 2 iterations; paper: the "
                             "paper's method (k=25, lam=0.5, 2 iterations)")
    parser.add_argument("--k", type=int, default=None, help="neighbours per point (preset)")
    parser.add_argument("--lam", type=float, default=None,
                        help="lambda, weight of the likelihood term (preset)")
    parser.add_argument("--rebuild-graph", action=argparse.BooleanOptionalAction, default=None,
                        help="find the neighbours anew in every iteration (preset: yes for "
                             "default and paper, no for fast)")
    parser.add_argument("--n-jobs", type=int, default=None,
                        help="threads (default: all cores); the result does not depend on it")


def _add_verbosity(parser):
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--quiet", action="store_true", help="print nothing but errors")
    group.add_argument("--verbose", action="store_true", help="print per-stage times")


class _Progress:
    """A one-line bar on a terminal's stderr, updated after each stage; silent elsewhere."""

    def __init__(self, total, enabled):
        self.total = total
        self.done = 0
        self.enabled = enabled and sys.stderr.isatty()

    def __call__(self, iteration, iterations, stage, seconds):
        self.done += 1
        if self.enabled:
            filled = int(30 * self.done / (self.total * iterations))
            sys.stderr.write(f"\r[{'#' * filled}{'.' * (30 - filled)}] iteration "
                             f"{iteration}/{iterations} {stage:<10s}")
            sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write("\r" + " " * 70 + "\r")
            sys.stderr.flush()


def _run_denoise(points, normals, args, method_params, orient=None, remove_outliers=False):
    from .denoise import denoise

    progress = _Progress(STAGE_COUNT[args.method], not args.quiet)
    started = time.perf_counter()
    try:
        result = denoise(points, normals, method=args.method, iterations=args.iterations,
                         k=args.k, lam=args.lam, preset=args.preset,
                         rebuild_graph=args.rebuild_graph, orient=orient,
                         remove_outliers=remove_outliers, n_jobs=args.n_jobs,
                         progress=progress, **method_params)
    finally:
        progress.close()
    seconds = time.perf_counter() - started
    if args.verbose:
        for i, record in enumerate(result.stats["iterations"], 1):
            times = ", ".join(f"{s} {t:.3f}" for s, t in record["times"].items())
            print(f"iteration {i}: {times} (s)")
    return result, seconds


def _check_output(path, force):
    """Refuse an output that cannot be written before the long work, not after it (the writer
    checks again when it renames)."""
    if path.exists() and not force:
        raise CommandError(f"{path} exists; pass --force to overwrite it")
    if not path.parent.is_dir():
        state = "is not a folder" if path.parent.exists() else "does not exist"
        raise CommandError(f"output folder {path.parent} {state}")


def _denoise(args):
    from . import io

    params = {}
    for dest, (methods, _) in METHOD_OPTIONS.items():
        value = getattr(args, dest)
        if value is None:
            continue
        if args.method not in methods:
            raise CommandError(f"--{dest.replace('_', '-')} is not a parameter of method "
                               f"{args.method!r}")
        params[dest] = value
    if args.keep_normals:
        params["keep_normals"] = True
    _check_output(args.output, args.force)
    if args.output.resolve() == args.input.resolve():
        raise CommandError("OUT is the input file; write elsewhere (the input is never "
                           "modified)")
    cloud = io.read(args.input)
    orient = args.orient
    if orient is None and cloud.format == "las" and cloud.normals is None:
        orient = "up"  # aerial and terrestrial LiDAR: the ground's normals point to the sky
    if orient is not None and cloud.normals is not None:
        raise CommandError(f"--orient applies to estimated normals; {args.input} has normals, "
                           "whose signs are kept")
    result, seconds = _run_denoise(cloud.points, cloud.normals, args, params, orient,
                                   args.remove_outliers)
    if args.remove_outliers:
        cloud = io.select(cloud, result.kept)
    fields = {"displacement": result.displacement.astype(np.float64),
              "outlier_score": result.outlier_score.astype(np.float32)}
    if result.likelihood is not None:
        fields["likelihood"] = result.likelihood.astype(np.float64)
        fields["feature_intensity"] = result.feature_intensity.astype(np.float64)
    io.write(args.output, cloud, points=result.points.astype(np.float64),
             normals=result.normals.astype(np.float64), fields=fields, overwrite=args.force)
    if not args.quiet:
        disp = result.displacement
        removed = (f" ({result.stats['outliers']['removed']:,} outliers removed)"
                   if args.remove_outliers else "")
        print(f"{args.input} -> {args.output}: {len(disp):,} points{removed}, method "
              f"{args.method}, "
              f"{result.stats['n_iterations']} iterations, {seconds:.2f} s; displacement max "
              f"{disp.max():.4g}"
              f", mean {disp.mean():.4g}")
    return 0


def _demo(args):
    from . import datasets, stages
    from .warmup import warmup

    if args.out.exists() and not args.out.is_dir():
        raise CommandError(f"{args.out} exists and is not a folder")
    taken = [p.name for p in args.out.glob("*") if p.stem in DEMO_FILES] if args.out.exists() \
        else []
    if taken and not args.force:
        raise CommandError(f"{args.out} already holds {', '.join(sorted(taken))}; pass --force "
                           "to replace them")
    args.out.mkdir(parents=True, exist_ok=True)
    cloud = datasets.cad_part(n_points=args.points, noise=args.noise, seed=args.seed)
    compile_seconds = warmup()
    result, seconds = _run_denoise(cloud.points, None, args, {})
    written = _demo_files(args, cloud.points, result)
    try:
        from . import render
    except ImportError:
        render = None
    pictures = []
    if render is not None:
        try:
            k = result.stats["k"]
            curvature_noisy = stages.mls_fit(cloud.points, k=k).curvature
            curvature_out = stages.mls_fit(result.points, result.normals, k=k).curvature
            pictures = render.figure_set(
                args.out, cloud.points, result.points, curvature=curvature_noisy,
                likelihood=result.likelihood, feature=result.feature_intensity,
                displacement=result.displacement / cloud.diagonal, curvature_denoised=curvature_out,
                normals_denoised=result.normals)
        except ImportError as exc:
            print(f"pssd: no pictures: {_one_line(exc)}", file=sys.stderr)
    if args.quiet:
        return 0
    before, after, disp, edge = truth_errors(cloud, result)
    print(f"pssd demo: built-in CAD part, {len(disp):,} points, noise {args.noise:.2%} of the "
          f"diagonal, seed {args.seed}; kernels ready in {compile_seconds:.1f} s")
    print("| Method | Iters. | Max. error (1e-4) | Ave. error (1e-4) | Exec time | "
          "mean dist. noisy -> denoised | near edges |")
    print("|---|---|---|---|---|---|---|")
    print(f"| Robust ({args.preset}) | {result.stats['n_iterations']} | {disp.max():.1f} | "
          f"{disp.mean():.1f} | "
          f"{seconds:.2f}s | {before.mean():.1f} -> {after.mean():.1f} | "
          f"{before[edge].mean():.1f} -> {after[edge].mean():.1f} |")
    for path in written + pictures:
        print(f"wrote {path}")
    return 0


def truth_errors(cloud, result):
    """Errors of a run on a generated cloud, in the paper's unit (1e-4 of the diagonal).

    Returns the distance to the true surface before and after, the displacement, and the mask of
    points within 1% of the diagonal of a sharp edge.
    """
    unit = 1e-4 * cloud.diagonal
    return (cloud.surface_distance(cloud.points) / unit,
            cloud.surface_distance(result.points) / unit,
            result.displacement / unit,
            cloud.edge_distance < 0.01 * cloud.diagonal)


def _demo_files(args, noisy, result):
    """Write the input and the result, as PLY when plyfile is there, else as NPZ."""
    from . import io

    try:
        import plyfile  # noqa: F401 (only probing for the optional dependency)
        suffix = ".ply"
    except ImportError:
        suffix = ".npz"
    written = []
    source = io.PointCloud(points=noisy)
    fields = {"likelihood": result.likelihood, "feature_intensity": result.feature_intensity,
              "displacement": result.displacement}
    for name, kwargs in (("noisy", {}), ("denoised", {"points": result.points,
                                                      "normals": result.normals,
                                                      "fields": fields})):
        path = args.out / (name + suffix)
        io.write(path, source, overwrite=args.force, **kwargs)
        written.append(path)
    return written


def _info(args):
    from pykdtree.kdtree import KDTree

    from . import io

    cloud = io.read(args.file)
    points = cloud.points
    low, high = points.min(axis=0), points.max(axis=0)
    print(f"{args.file}: {cloud.format}, {len(points):,} points")
    print(f"bounds: min {_vec(low)}, max {_vec(high)}, diagonal {np.linalg.norm(high - low):.6g}")
    if len(points) > 1:
        dist, _ = KDTree(points).query(points, k=2)
        print(f"average spacing (mean distance to the nearest other point): "
              f"{dist[:, 1].mean():.6g}")
    attributes = (["normals"] if cloud.normals is not None else []) + [
        f"{name} ({values.dtype})" for name, values in cloud.fields.items()]
    print("attributes: " + (", ".join(attributes) if attributes else "none"))
    return 0


def _vec(v):
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"


def _render(args):
    from . import io, render, stages

    _check_output(args.output, args.force)
    cloud = io.read(args.file)
    points = cloud.points
    stored = {"feature": "feature_intensity"}.get(args.color, args.color)
    if args.color == "height":
        values = render.height(points, tuple(args.view))
    elif stored in cloud.fields:
        values = np.asarray(cloud.fields[stored], np.float64)
    elif args.color == "displacement":
        raise CommandError(f"{args.file} holds no displacement; render the output of "
                           "pssd denoise, which stores it")
    elif args.color == "likelihood":
        values = stages.sampling_likelihood(points, cloud.normals, k=args.k)
    elif args.color == "feature":
        values = stages.feature_intensity(points, cloud.normals, k=args.k)
    else:
        values = stages.mls_fit(points, cloud.normals, k=args.k).curvature
    render.render(points, values, args.output, view=tuple(args.view), normals=cloud.normals,
                  label=args.color, title=args.file.name)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
