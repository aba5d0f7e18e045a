"""The ``pssd`` command: denoise files, run the demo, describe and render clouds.

Every failure prints one line, ``pssd: error: ...``, and exits with status 1 (2 for a bad
command line); no traceback reaches the user.
"""
import argparse
import os
import re
import shutil
import signal
import sys
import threading
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from . import __version__, atomic
from ._validation import STRAY, check_precision
from .parameters import BY_NAME, PARAMETERS
from .plan import PRESETS
from .progress import Names, STAGE_WIDTH, TimeLeft, describe, label

#: Per-method options of ``pssd denoise`` that take a value: option dest -> (methods that take
#: it, help), as :mod:`pssd_fast.parameters` declares them.
METHOD_OPTIONS = {p.name: (p.methods, p.help) for p in PARAMETERS
                  if p.method and p.kind != "bool"}
#: What ``pssd render --color`` offers (``pssd_fast.pictures.COLOR_FIELDS``).
COLORS = ("height", "classification", "intensity", "rgb", "likelihood", "feature", "curvature",
          "displacement")
#: Stems of the files ``pssd demo`` writes (point clouds and the paper's figure set).
DEMO_FILES = ("noisy", "denoised", "curvature", "likelihood", "feature", "denoised_curvature",
              "denoised_displacement")
STAGE_COUNT = {"robust": 7, "mls": 3, "bilateral": 3}
#: What ``pssd denoise --fields`` may add (none by default; ``all``: each the method computes
#: and the output format can hold).
RESULT_FIELDS = ("likelihood", "feature_intensity", "displacement", "outlier_score", "normals",
                 "held")


class CommandError(Exception):
    """A failure explained by its message alone."""


def _orient_estimated(orient, has_normals, inp):
    """:func:`pssd_fast._validation.check_orient_estimated` as a command's error."""
    from ._validation import check_orient_estimated
    try:
        check_orient_estimated(orient, has_normals, f"the normals of {inp}", "drop --orient")
    except ValueError as exc:
        raise CommandError(f"--{exc}") from None


class Terminated(BaseException):
    """SIGTERM, raised where the process is, like KeyboardInterrupt for Ctrl-C, so that every
    cleanup (temporary files included) runs before the process exits."""


def _terminate(signum, frame):
    raise Terminated


def main(argv=None):
    """Entry point of the ``pssd`` console script; returns the exit status.

    Ctrl-C returns 130 and SIGTERM 143 (128 + the signal number, as the shell reports a process
    killed by it), each after one line on stderr and with no temporary file left behind.
    """
    parser = _parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        # The usage of the command they were given to, not the top level's.
        getattr(args, "parser", parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    if not hasattr(args, "run"):
        parser.print_help()
        return 2
    # Signal handlers can only be set from the main thread; elsewhere SIGTERM keeps its own.
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if in_main else None
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _note
            return args.run(args) or 0
    except BrokenPipeError:
        # The reader of stdout went away (``pssd info f | head -1``): nothing left to say, and
        # nothing more written to the closed pipe when Python flushes stdout at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print("pssd: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("pssd: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except (CommandError, OSError, ValueError, TypeError, ImportError) as exc:
        print(f"pssd: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)


def _note(message, category, filename, lineno, file=None, line=None):
    """Warnings reach the user as one line on stderr, without the source line."""
    print(f"pssd: note: {_one_line(message)}", file=sys.stderr)


def _one_line(exc):
    text = str(exc).strip().splitlines()
    message = text[0] if text else type(exc).__name__
    if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in message:
        message = f"{exc.filename}: {message}"
    return _as_flags(message)


#: The keywords of :func:`pssd_fast.denoise` that the library's messages name and that a
#: command line spells as options (not the one-letter ``k`` and ``h``, words such as
#: ``method`` that messages use in their own sense, nor ``shift_normals``, whose option is
#: ``--no-shift-normals``).
_SPELLED = tuple(sorted((p.name for p in PARAMETERS if p.name != "shift_normals" and (
    "_" in p.name or p.name in ("lam", "delta", "alpha", "beta"))), key=len, reverse=True))


def _as_flags(message):
    """A library message as the command line reads it: its keywords as options."""
    message = re.sub(r"\bpreset='(\w+)'", r"--preset \1", message)
    message = re.sub(r"^([kh]) ", r"--\1 ", message)  # "k must be at least 10"
    message = message.replace("a positive integer, -1 or None (all cores)",
                              "a positive integer or -1 (all cores)")
    return re.sub(r"(?<![\w'-])(" + "|".join(_SPELLED) + r")(?![\w'-])",
                  lambda m: "--" + m.group(1).replace("_", "-"), message)


def _parser():
    parser = argparse.ArgumentParser(
        prog="pssd", description="Feature-preserving denoising of point-sampled surfaces.")
    parser.add_argument("--version", action="version", version=f"pssd_fast {__version__}")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")

    den = sub.add_parser(
        "denoise", help="denoise point cloud files",
        usage="pssd denoise [options] IN OUT\n       pssd denoise [options] IN [IN ...] -o FOLDER",
        description="Denoise IN and write OUT, or each IN into FOLDER under its own name. "
                    "Formats follow the extensions: .ply, .xyz, .pts, .txt, .csv, .obj (text, "
                    "PLY and OBJ also gzipped, e.g. .ply.gz), .npy, .npz, .las, .laz; '-' is "
                    "standard input or output, in the format --format names. OUT has the "
                    "input's attributes and nothing more: every one written back unchanged, "
                    "the coordinates and (where IN has them) the normals denoised; --fields "
                    "adds others. A classified file (a classification field, as LAS/LAZ "
                    "files have) keeps its classes apart: by default each surface class "
                    "(2 ground, 6 building, 9 water, 10 rail, 11 road surface, 17 bridge "
                    "deck) is denoised on its own and the other points are kept as they are "
                    "(see --classes).")
    den.add_argument("paths", metavar="PATH", nargs="+",
                     help="IN OUT, or with -o the inputs; '-' reads stdin or writes stdout")
    den.add_argument("-o", "--output-dir", type=Path, default=None, metavar="FOLDER",
                     help="write each input into FOLDER (created if missing) under its name")
    den.add_argument("--format", default=None, metavar="FMT",
                     help="format of '-' (stdin/stdout) as an extension: xyz, csv, ply, "
                          "ply.gz, las...")
    _add_columns(den)
    den.add_argument("--fields", default=None, metavar="LIST",
                     help=f"comma-separated fields to add, in any case: "
                          f"{', '.join(RESULT_FIELDS)}; all "
                          f"(each the method computes that the output format can hold), or "
                          f"none (default: none, so that OUT has the input's attributes only; "
                          f"an input's own normals are always updated, and normals are added "
                          f"only when named)")
    add_parameter(den, "method")
    _add_common(den)
    for dest in METHOD_OPTIONS:
        # No choices for --likelihood: pssd_fast.denoise names a bad one.
        add_parameter(den, dest, choices=None, more=_applies(BY_NAME[dest]))
    add_parameter(den, "keep_normals", more=" (the file's normals)")
    add_parameter(den, "shift_normals", "--no-shift-normals", more="; this option keeps its own")
    add_parameter(den, "orient", type=_orientation, metavar="HOW",
                  more="; a viewpoint as X,Y,Z; for .las/.laz input by default up")
    add_parameter(den, "remove_outliers", more=" (--fields outlier_score writes the score)")
    add_parameter(den, "classes", type=_classes, metavar="LIST",
                  more=", by the input's classification field: codes such as 2,6 (ground, "
                       "buildings), each (every class present), or all (every point as one "
                       "cloud, classes ignored); the points of other classes keep their "
                       "records and are no point's neighbours (by default the surface classes "
                       "2, 6, 9, 10, 11 and 17 present; a file of classes 0 and 1 only, never "
                       "classified or unclassified, as one cloud)")
    den.add_argument("--tile-points", type=_tile_points, default=None, metavar="N",
                     help="run in tiles of at most N points on Dask (the dask extra: pip "
                          "install '.[dask]'), with the same result; presets default and fast, "
                          "where they work on cell means; a classified input keeps its "
                          "classes apart as without it (see --classes)")
    den.add_argument("--scheduler", default=None, metavar="WHERE", type=_scheduler,
                     help="where the tiles run: threads (default), processes, sync, or a Dask "
                          "scheduler's address")
    den.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    _add_verbosity(den)
    den.set_defaults(run=_denoise, parser=den)

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
    _add_size(demo)
    demo.add_argument("--force", action="store_true", help="overwrite files in the folder")
    _add_verbosity(demo)
    demo.set_defaults(run=_demo, method="robust", parser=demo)

    info = sub.add_parser("info", help="describe a point cloud file",
                          description="Print point count, bounds, average spacing and the "
                                      "attributes FILE holds, with a PLY file's other "
                                      "elements (faces...) and a LAS file's version, point "
                                      "format, scale and offset.")
    info.add_argument("file", metavar="FILE", type=Path)
    info.add_argument("--format", default=None, metavar="FMT",
                      help="format of '-' (stdin) as an extension: xyz, csv, ply, las...")
    _add_columns(info)
    info.set_defaults(run=_info, parser=info)

    render = sub.add_parser("render", help="draw a point cloud as a picture", description=(
        "Draw FILE coloured by a per-point field, fitted to the picture. "
        "classification (ASPRS colours, a legend naming the classes present), "
        "intensity (grey, 2nd to 98th percentile) and rgb (red, green, blue of 8 or "
        "16 bits) are FILE's own; displacement too (as pssd denoise --fields "
        "displacement writes it), in FILE's units (named where a LAS file's "
        "coordinate system says them), 0 to its 98th percentile. likelihood and "
        "feature are taken from FILE when it holds them (as pssd denoise --fields "
        "writes them), else computed by the same denoise run, so they equal what "
        "pssd denoise with the same options would store; curvature is the mean "
        "curvature of FILE's points (k=25 MLS fits) times the bounding-box diagonal; "
        "height is the coordinate along the up axis. Files without normals are "
        "shaded with estimated ones."))
    render.add_argument("file", metavar="FILE", type=Path)
    render.add_argument("--format", default=None, metavar="FMT",
                        help="format of '-' (stdin) as an extension: xyz, csv, ply, las...")
    render.add_argument("-o", "--output", type=Path, required=True,
                        help="picture to write; the format follows the extension: "
                             ".png, .jpg, .jpeg, .tif, .tiff, .webp")
    _add_columns(render)
    render.add_argument("--color", choices=COLORS, default="height",
                        help="what to colour by (height); a field FILE lacks is refused with "
                             "the list of those it has")
    render.add_argument("--view", type=float, nargs=2, default=None,
                        metavar=("ELEV", "AZIM"),
                        help="view elevation and azimuth in degrees about the up axis "
                             "(default: a flat scene, whose extent along the up axis is under "
                             "a third of its length, from 50 degrees with its long side across "
                             "the picture; anything else 30 -60)")
    render.add_argument("--up", choices=("auto", "x", "y", "z"), default="auto",
                        help="axis drawn upwards; auto: z for LAS/LAZ, the axis of least "
                             "extent for a flat cloud (under a third of the largest), else y "
                             "(auto)")
    _add_common(render)
    add_parameter(render, "classes", type=_classes, metavar="LIST",
                  more=": the classes pssd denoise denoised (as its --classes); likelihood and "
                       "feature are computed as it computes them, and the points of other "
                       "classes, which it kept in place, are drawn grey in pictures of "
                       "likelihood, feature and displacement")
    _add_size(render)
    render.add_argument("--force", action="store_true", help="overwrite the picture if it "
                                                             "exists")
    render.add_argument("--quiet", action="store_true", help="print nothing but errors")
    render.set_defaults(run=_render, method="robust", parser=render)
    return parser


def _classes(text):
    """``--classes``: ``all``, ``each`` or comma-separated class codes."""
    if text.strip() in ("all", "each"):
        return text.strip()
    try:
        codes = tuple(int(c) for c in text.split(",") if c.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"want comma-separated class numbers such as 2,6, each or all; got {text!r}"
        ) from None
    if not codes:
        raise argparse.ArgumentTypeError("want at least one class number, such as 2")
    return codes


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
    for name in ("iterations", "preset", "k", "lam", "rebuild_graph"):
        add_parameter(parser, name)
    add_parameter(parser, "n_jobs", "--n-jobs", "--threads")
    add_parameter(parser, "duplicate_tolerance", metavar="D",
                  more="; in the file's units, cubes from the bounding box's low corner")


def add_parameter(parser, name, *flags, more="", **settings):
    """Add the option of :func:`pssd_fast.denoise`'s parameter ``name`` to ``parser``, as
    :mod:`pssd_fast.parameters` declares it.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        Where the option goes.
    name : str
        The parameter, which is the option's ``dest``.
    *flags : str
        The option's flags (default ``--name``, underscores as hyphens).
    more : str
        Said after the declared help.
    **settings
        ``add_argument``'s keywords, over those of the declaration: the type (``int`` or
        ``float``), a flag's action (``store_true``, ``store_false``, or ``--x``/``--no-x``
        for ``"auto"``), the choices and the default (None where the library chooses, and
        for a method parameter not given).
    """
    declared = BY_NAME[name]
    option = {"dest": name, "help": declared.help + more}
    if declared.kind == "bool":
        option["action"] = (argparse.BooleanOptionalAction if declared.auto
                            else "store_false" if declared.default else "store_true")
    elif declared.kind in ("int", "float"):
        option["type"] = int if declared.kind == "int" else float
    if declared.kind == "choice":
        option["choices"] = declared.choices
    option["default"] = (None if declared.auto or (declared.method and declared.kind != "bool")
                         else declared.default)
    option.update(settings)
    parser.add_argument(*(flags or ["--" + name.replace("_", "-")]), **option)


def _applies(declared):
    """Where a method parameter applies, for its option's help: its default, its choices,
    and its methods (``method robust (preset paper) or mls``)."""
    text = f": {', '.join(declared.choices)}" if declared.kind == "choice" else ""
    if not declared.auto:
        text += f" ({declared.default:g})" if declared.kind == "float" else (
            f" ({declared.default})")
    methods = []
    for method in declared.methods:
        presets = [name for name, setting in PRESETS.items()
                   if setting["pipeline"] in declared.pipelines]
        if method == "robust" and declared.pipelines and len(presets) < len(PRESETS):
            method += f" (preset{'s' * (len(presets) > 1)} {' and '.join(presets)})"
        methods.append(method)
    return f"{text}; method {' or '.join(methods)}"


def _add_columns(parser):
    parser.add_argument("--columns", default=None, metavar="LIST",
                        help="text input: the names of its columns, comma-separated, e.g. "
                             "x,y,z,red,green,blue (instead of its header line; without one, "
                             "columns 4-6 of six are colours when integers, else normals when "
                             "unit vectors)")


def _add_size(parser):
    parser.add_argument("--size", type=int, nargs="+", default=[1000], metavar="PX",
                        help="picture WIDTH [HEIGHT] in pixels (default 1000 wide, as high as "
                             "the drawing of the cloud needs at that width)")


def _size(args):
    """``--size``: ``(width, height)``, the height None where not given."""
    if len(args.size) > 2:
        raise CommandError(f"--size takes WIDTH [HEIGHT]; got {len(args.size)} numbers")
    return (args.size[0], args.size[1] if len(args.size) == 2 else None)


def _add_verbosity(parser):
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--quiet", action="store_true", help="print nothing but errors")
    group.add_argument("--verbose", action="store_true",
                       help="print k (and the estimated noise it was chosen from), the "
                            "threads and per-stage times")


class _Progress:
    """A one-line bar on a terminal's stderr, updated after each stage; silent elsewhere.

    The bar fills by iterations: within one, by the method's stages (``total`` an iteration,
    one short of the next iteration until it starts); a tile's round (``"name i/n"``) and a
    pass over a file before the plan move it by nothing."""

    def __init__(self, total, enabled):
        self.total = total
        self.enabled = enabled and sys.stderr.isatty()
        self.clock = TimeLeft()
        self.names = Names()
        self.stages = {}
        # One column short of the terminal's width: a line that wrapped would not be redrawn.
        self.width = shutil.get_terminal_size().columns - 1

    def __call__(self, iteration, iterations, stage, seconds):
        times = describe(*self.clock(iteration, iterations, seconds))
        if self.enabled:
            text = f"{self.line(iteration, iterations, stage)} {times}"[:self.width]
            sys.stderr.write(f"\r{text:<{self.width}s}")
            sys.stderr.flush()

    def line(self, iteration, iterations, stage):
        """The bar, the iteration and the stage (numbered from its second run in one
        iteration)."""
        if not stage[-1].isdigit():
            self.stages[iteration] = self.stages.get(iteration, 0) + 1
        done = 0.0
        if iteration:
            done = (iteration - 1 + min(self.stages.get(iteration, 0), self.total - 1)
                    / self.total) / iterations
        filled = int(30 * done)
        bar = "#" * filled + "." * (30 - filled)
        return (f"[{bar}] {label(iteration, iterations)} "
                f"{self.names(iteration, stage):<{STAGE_WIDTH}s}")

    def close(self):
        if self.enabled:
            sys.stderr.write("\r" + " " * self.width + "\r")
            sys.stderr.flush()


def _common_options(args):
    """The options of :func:`pssd_fast.denoise` that ``_add_common`` offers."""
    return {"iterations": args.iterations, "k": args.k, "lam": args.lam, "preset": args.preset,
            "rebuild_graph": args.rebuild_graph, "n_jobs": args.n_jobs,
            "duplicate_tolerance": args.duplicate_tolerance}


def _scheduler(value):
    """``--scheduler``: a local scheduler's name or a scheduler's address."""
    from .tiled.scheduler import check_client

    try:
        return check_client(value, "")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _tile_points(value):
    """``--tile-points``: an int of at least :data:`pssd_fast.tiled.runner.MIN_TILE_POINTS`."""
    from .tiled.runner import check_tile_points

    try:
        return check_tile_points(int(value))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc) if value.strip().lstrip("+-").isdigit()
                                         else f"an integer, not {value!r}") from None


def _run_denoise(points, normals, args, method_params, **options):
    from .denoise import denoise

    progress = _Progress(STAGE_COUNT[args.method], not args.quiet)
    started = time.perf_counter()
    try:
        if getattr(args, "tile_points", None) is not None:
            result = _run_tiled(points, normals, args, method_params, progress, **options)
        else:
            if getattr(args, "scheduler", None) is not None:
                raise CommandError("--scheduler runs the tiles of --tile-points; give both")
            result = denoise(points, normals, method=args.method, progress=progress,
                             **_common_options(args), **options, **method_params)
    finally:
        progress.close()
    return result, time.perf_counter() - started


def _details(stats, say):
    """What ``--verbose`` adds: the sizes the run chose, its threads and each iteration's
    stage times (from a file out of core, the passes over it before and after them too)."""
    threads = stats["n_jobs"]
    print(f"k = {stats['k']}{_chosen(stats)}; {threads} thread{'s' * (threads != 1)}",
          file=say)
    passes = stats.get("tiles") or {}
    for name, times in [("the file before", passes.get("before")),
                        *[(f"iteration {i}", record["times"])
                          for i, record in enumerate(stats["iterations"], 1)],
                        ("the file after", passes.get("after"))]:
        if times:
            listed = ", ".join(f"{s} {t:.3f}" for s, t in times.items())
            print(f"{name}: {listed} (s)", file=say)
    if stats["outliers"] is not None:
        print(f"outlier score: {stats['outliers']['seconds']:.3f} s", file=say)


def _method(args):
    """The summary's method, with the preset where the method has presets (the preset is what
    ``stats["plan"]["method"]`` names)."""
    if args.method == "robust":
        return f"method robust, preset {args.preset}"
    return f"method {args.method}"


def _chosen(stats):
    """What ``--verbose`` says after ``k``: where the run's sizes came from."""
    plan, probe = stats["plan"], stats["auto_k"]
    if plan["method"] == "default":
        noise = plan["noise"]
        chosen = (f" cell means within {plan['bound']:.4g}, from the probe's noise "
                  f"{noise['sigma']:.4g} and spacing {noise['spacing']:.4g} (cells of edge "
                  f"{plan['cell_edge']:.4g})")
        if plan["refine"] is not None:
            chosen += (f"; the points that fail the test refit over {plan['refine']['k']} "
                       f"points within {plan['refine']['bound']:.4g}")
        return chosen
    if probe is None:
        return ""
    return (f" chosen from the probe's noise {probe['noise']:.4g} and spacing "
            f"{probe['spacing']:.4g} (ratio {probe['ratio']:.3f})")


def _check_output(path, force):
    """Refuse an output that cannot be written before the long work, not after it (the writer
    checks again when it renames)."""
    if path.exists() and not force:
        raise CommandError(f"{path} exists; pass --force to overwrite it")
    if not path.parent.is_dir():
        state = "is not a folder" if path.parent.exists() else "does not exist"
        raise CommandError(f"output folder {path.parent} {state}")
    try:
        atomic.check_folder(path)
    except OSError as exc:
        raise CommandError(f"{exc.strerror}; choose another output") from None


@contextmanager
def _appeared(path):
    """An output that appeared at ``path`` during the run is refused as one before it is
    (:func:`_check_output`), naming the option rather than the Python keyword."""
    try:
        yield
    except FileExistsError:
        raise CommandError(f"{path} exists; pass --force to overwrite it") from None


def _is_stdio(path):
    return str(path) == "-"


def _is_zarr(path):
    """Whether ``path`` names a Zarr array (a folder, so a trailing slash is allowed)."""
    return Path(path).suffix.lower() == ".zarr"


def _jobs(args):
    """The (input, output) pairs of ``pssd denoise``, checked before any work."""
    from . import io

    if args.output_dir is None:
        if len(args.paths) != 2:
            raise CommandError(f"expected IN OUT, or IN [IN ...] -o FOLDER; got "
                               f"{len(args.paths)} path(s) without -o")
        jobs = [tuple(p if _is_stdio(p) else Path(p) for p in args.paths)]
    else:
        if any(_is_stdio(p) for p in args.paths):
            raise CommandError("'-' (stdin) cannot be one of several inputs of -o FOLDER")
        if args.output_dir.exists() and not args.output_dir.is_dir():
            raise CommandError(f"{args.output_dir} exists and is not a folder")
        jobs = [(Path(p), args.output_dir / Path(p).name) for p in args.paths]
        names = [out.name for _, out in jobs]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise CommandError(f"several inputs would be written to {args.output_dir} as "
                               f"{', '.join(twice)}")
    uses_stdio = any(_is_stdio(p) for job in jobs for p in job)
    if uses_stdio and args.format is None:
        raise CommandError("'-' needs --format to name its format (e.g. --format xyz)")
    if args.format is not None and not uses_stdio:
        raise CommandError("--format names the format of '-' (stdin or stdout) only; a file's "
                           "format is its extension")
    for inp, out in jobs:
        fmt = args.format if _is_stdio(out) else None
        zarr = [path for path in (inp, out) if _is_zarr(path)]
        if zarr and args.tile_points is None:
            raise CommandError(f"{zarr[0]}: Zarr arrays are read and written out of core only: "
                               f"pass --tile-points (e.g. --tile-points 2000000)")
        if not _is_zarr(out):
            io.storable(out, [], format=fmt)  # an unknown format fails now, not after the work
        if _is_stdio(out):
            continue
        # Before the --force check: --force does not make replacing the input possible.
        if not _is_stdio(inp) and out.resolve() == inp.resolve():
            raise CommandError(f"{out} is the input file; choose another output (the input is "
                               "never modified)")
        if args.output_dir is None:  # else checked once the folder exists
            _check_output(out, args.force)
    return jobs


def _added_fields(args, result, cloud, runs, out, say):
    """The fields ``--fields`` asks for (float32; ``held`` uint8) and whether to write the new
    normals. Any method's points have an outlier score, computed only when asked for
    (docs/DECISIONS.md, "The outlier score on request")."""
    from . import io
    from .run import stored

    # What the run has or computes when read (the likelihood and feature intensity of the
    # default method), read only for the fields asked for.
    computes = {name for name in RESULT_FIELDS if stored(result, name) is not None}
    computes.add("outlier_score")
    fmt = args.format if _is_stdio(out) else None
    names = _field_names(args)
    normals_held = io.holds_normals(out, cloud, format=fmt)
    if names == "all":
        scalars = [n for n in RESULT_FIELDS if n != "normals" and n in computes]
        names = [*io.storable(out, scalars, format=fmt), *["normals"] * normals_held]
    else:
        unknown = [n for n in names if n not in RESULT_FIELDS]
        if unknown:
            raise CommandError(f"--fields: unknown field(s) {', '.join(unknown)}; choose from "
                               f"{', '.join(RESULT_FIELDS)}, all or none")
        missing = [n for n in names if n not in computes]
        if missing:
            raise CommandError(f"--fields: method {args.method!r} computes no "
                               f"{', '.join(missing)}")
        scalars = [n for n in names if n != "normals"]
        refused = sorted(set(scalars) - set(io.storable(out, scalars, format=fmt)))
        refused += ["normals"] * ("normals" in names and not normals_held)
        if refused:
            raise CommandError(f"--fields: {out} cannot hold {', '.join(refused)} (use .npz, "
                               f".ply, .las or text)")
    have = {name: getattr(result, name) for name in names if name != "normals"}
    if "outlier_score" in names and have["outlier_score"] is None:
        have["outlier_score"] = _outlier_score(args, cloud, runs, say)
    # ``held`` is a flag (0 or 1), the others are float32.
    fields = {n: np.asarray(have[n], dtype=np.uint8 if n == "held" else np.float32)
              for n in names if n != "normals"}
    return fields, "normals" in names or cloud.normals is not None


def _field_names(args):
    """The names ``--fields`` gives (none by default, in any case), or ``"all"``."""
    names = [] if args.fields is None else [n.strip().lower() for n in args.fields.split(",")
                                            if n.strip()]
    if len(names) > 1 and {"all", "none"} & set(names):
        raise CommandError(f"--fields: all and none stand alone; got {args.fields!r}")
    return "all" if names == ["all"] else [n for n in names if n != "none"]


def _outlier_score(args, cloud, runs, say):
    """:func:`pssd_fast.outlier_score` of ``cloud``'s points; of a classified cloud, of each
    class denoised (``runs``: their rows) among its own points, as the run saw them (NaN
    elsewhere, and in a class of too few points to score)."""
    from .core import OUTLIER_K
    from .stages import outlier_score

    started = time.perf_counter()
    if runs is None:
        score = outlier_score(cloud.points, n_jobs=args.n_jobs)
    else:
        score = np.full(len(cloud), np.nan)
        for rows in runs:
            if len(rows) > OUTLIER_K:
                score[rows] = outlier_score(cloud.points[rows], n_jobs=args.n_jobs)
    if args.verbose:
        print(f"outlier score: {time.perf_counter() - started:.3f} s", file=say)
    return score


def _run_tiled(points, normals, args, method_params, progress, orient, remove_outliers,
               **options):
    """``--tile-points``: :func:`pssd_fast.tiled.denoise` with the options it shares
    (``options``: ``extras`` and the classes, as :func:`pssd_fast.denoise` takes them)."""
    from . import tiled

    _check_tiled(args, method_params)
    return tiled.denoise(points, normals, tile_points=args.tile_points, client=args.scheduler,
                         preset=args.preset, iterations=args.iterations, orient=orient,
                         duplicate_tolerance=args.duplicate_tolerance, n_jobs=args.n_jobs,
                         progress=progress, remove_outliers=remove_outliers, **options,
                         **method_params)


def _flag(dest):
    """The option that sets method parameter ``dest``."""
    return "--no-shift-normals" if dest == "shift_normals" else f"--{dest.replace('_', '-')}"


def _check_tiled(args, method_params):
    """Refuse the options that ``--tile-points`` does not take."""
    unused = [name for name, given in (
        ("--method", args.method != "robust"), ("--k", args.k is not None),
        ("--lam", args.lam is not None), ("--rebuild-graph", args.rebuild_graph is not None),
        *((_flag(dest), True) for dest in method_params
          if dest != "sigma_n"))
        if given]
    if args.preset == "paper":
        unused.append("--preset paper")
    if unused:
        raise CommandError(f"--tile-points runs the feature-aware pipeline of the presets "
                           f"default and fast; it does not take {', '.join(unused)}")


def _on_disk(args, inp, out):
    """Whether ``--tile-points`` runs out of core (:func:`pssd_fast.tiled.denoise_file`): an
    ``.npy`` (n, 3), Zarr or LAS/LAZ input into a file of its kind, with fields that such a
    run writes."""
    if args.tile_points is None or _is_stdio(inp) or _is_stdio(out) or args.columns:
        return False  # io.read refuses --columns for these formats
    from .tiled import ondisk
    from .tiled import FILE_KINDS

    kind = FILE_KINDS.get(Path(inp).suffix.lower())
    if kind is None or kind != FILE_KINDS.get(Path(out).suffix.lower()):
        return False
    names = _field_names(args)
    if kind == "zarr":
        return True
    if names != "all" and set(names) - set(ondisk.RESULT_FIELDS if kind == "las" else ()):
        return False
    try:
        ondisk.NpyFile(inp) if kind == "npy" else ondisk.LasFile(inp)
    except (ValueError, TypeError, OSError):
        return False  # the in-memory reader names the problem, or reads what this one cannot
    return True


def _denoise_on_disk(args, params, inp, out, say):
    """``--tile-points`` out of core: :func:`pssd_fast.tiled.denoise_file`."""
    from . import tiled
    from .tiled import ondisk
    from .tiled import FILE_KINDS

    _check_tiled(args, params)
    if args.remove_outliers:
        raise CommandError("--remove-outliers drops rows, which a run out of core (--tile-points "
                           "from .npy, Zarr or LAS/LAZ into a file of its kind) does not do: "
                           "drop --tile-points to denoise in memory")
    las = FILE_KINDS[Path(inp).suffix.lower()] == "las"
    if not las and args.classes not in (None, "all"):
        raise CommandError(f"--classes: {inp} has no classification field")
    names = _field_names(args)
    fields = (ondisk.RESULT_FIELDS if las else ()) if names == "all" else tuple(names)
    if fields and not las:
        raise CommandError(f"--fields: {out} cannot hold {', '.join(fields)} (use .las/.laz, "
                           f"or .npz, .ply or text without --tile-points)")
    has_normals = las and ondisk.LasFile(inp).has_normals
    _orient_estimated(args.orient, has_normals, inp)
    orient = "up" if args.orient is None and las and not has_normals else args.orient
    progress = _Progress(STAGE_COUNT[args.method], not args.quiet)
    try:
        stats = tiled.denoise_file(inp, out, tile_points=args.tile_points,
                                   client=args.scheduler, preset=args.preset,
                                   iterations=args.iterations, orient=orient, fields=fields,
                                   extras=bool({"likelihood", "feature_intensity"} & set(fields)),
                                   duplicate_tolerance=args.duplicate_tolerance,
                                   n_jobs=args.n_jobs, progress=progress, overwrite=args.force,
                                   classes=args.classes if las else None, **params)
    finally:
        progress.close()
    if not args.quiet:
        # With classes, n_points counts the points denoised.
        total = stats["n_points"] + stats.get("classes", {}).get("untouched", 0)
        moved = stats["displacement"]
        print(f"{inp} -> {out}: {total:,} points, {_method(args)}, "
              f"{_iterations(stats)}, {stats['total_seconds']:.2f} s; "
              f"{_tiles(stats, 'out of core')}displacement max "
              f"{moved['max']:.4g}, mean {moved['mean']:.4g}{_rounded(out, None)}"
              f"{_copies(stats)}{_classes_done(stats)}", file=say)
    if args.verbose:
        _details(stats, say)


def _tiles(stats, where):
    """What the summary line says of a tiled run's tiles (nothing for an untiled run)."""
    tiles = stats.get("tiles")
    if tiles is None:
        return ""
    return (f"{tiles['count']} tile{'s' * (tiles['count'] != 1)} of at most "
            f"{tiles['most_points']:,} points, {where}; ")


def _rounded(out, fmt):
    """What the summary line adds to the displacement of a LAS or LAZ output (``fmt``: the
    format of ``-``), in memory as out of core."""
    ext = str(fmt if _is_stdio(out) else Path(out).suffix).lower().lstrip(".")
    return " (before the format rounds the coordinates to its scale)" if ext in (
        "las", "laz") else ""


def _iterations(stats):
    """``"2 iterations"`` (``"1 iteration"``)."""
    n = stats["n_iterations"]
    return f"{n} iteration{'s' * (n != 1)}"


def _copies(stats):
    """The rows at another row's position, which take that row's result."""
    copies = stats.get("duplicates", 0)
    return f" ({copies:,} rows at another row's position, denoised with it)" if copies else ""


def _denoise(args):
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
    if not args.shift_normals:
        params["shift_normals"] = False
    jobs = _jobs(args)
    # Data on stdout: every message goes to stderr.
    say = sys.stderr if any(_is_stdio(out) for _, out in jobs) else sys.stdout
    failed = 0

    def report(inp, exc):
        message = _one_line(exc)
        prefix = "" if str(inp) in message else f"{inp}: "
        print(f"pssd: error: {prefix}{message}", file=sys.stderr)

    if args.output_dir is not None:
        args.output_dir.mkdir(parents=True, exist_ok=True)
        # Every output that cannot be written is named before any work; the others are.
        ready = []
        for inp, out in jobs:
            try:
                _check_output(out, args.force)
                ready.append((inp, out))
            except CommandError as exc:
                report(inp, exc)
                failed += 1
        jobs = ready
    for inp, out in jobs:
        try:
            _denoise_file(args, params, inp, out, say)
        except (CommandError, OSError, ValueError, TypeError) as exc:
            report(inp, exc)
            failed += 1
    return 1 if failed else 0


def _denoise_file(args, params, inp, out, say):
    from . import io

    if _on_disk(args, inp, out):
        _denoise_on_disk(args, params, inp, out, say)
        return
    fmt = args.format
    cloud = _read(inp, args, fmt if _is_stdio(inp) else None)
    if cloud.source is not None:
        # The file's float32 coordinates, read as float64, warn as float32 arrays do.
        check_precision(cloud.points, cloud.source.coordinates_dtype())
    labels, runs = _labels(args, cloud, inp)
    chosen = None
    if runs is not None:
        chosen = np.zeros(len(cloud), np.bool_)
        for rows in runs:
            chosen[rows] = True
    given = _given_normals(cloud, inp, chosen)
    if given is None and cloud.normals is not None and params.get("keep_normals"):
        raise CommandError(f"--keep-normals needs a normal on every point to denoise; {inp} "
                           f"has points without one")
    orient = args.orient
    if orient is None and cloud.format == "las" and given is None:
        orient = "up"  # aerial and terrestrial LiDAR: the ground's normals point to the sky
    _orient_estimated(orient, given is not None, inp)
    # The default method computes the likelihood and the feature intensity on request only.
    names = _field_names(args)
    extras = names == "all" or bool({"likelihood", "feature_intensity"} & set(names))
    result, seconds = _run_denoise(cloud.points, given, args, params, orient=orient,
                                   remove_outliers=args.remove_outliers, extras=extras,
                                   **labels)
    if args.remove_outliers:
        cloud = io.select(cloud, result.kept)
    if chosen is not None and args.remove_outliers:
        # The rows kept (the run gave their outlier scores, so the runs' rows serve no more).
        chosen = chosen[result.kept]
    fields, with_normals = _added_fields(args, result, cloud, runs, out, say)
    normals = result.normals.astype(np.float64) if with_normals else None
    if given is None and chosen is not None and cloud.normals is not None:
        # The points outside the classes keep the file's normals, as they keep their records.
        normals[~chosen] = cloud.normals[~chosen]
    points = result.points.astype(np.float64)
    with _appeared(out):
        io.write(out, cloud, points=points, normals=normals, fields=fields,
                 overwrite=args.force, format=fmt if _is_stdio(out) else None)
    if not args.quiet:
        # The method's moves, as out of core reports them (LAS then rounds to its scale).
        disp = np.linalg.norm(points - cloud.points, axis=1)
        removed = (f" ({result.stats['outliers']['removed']:,} outliers removed)"
                   if args.remove_outliers else "")
        print(f"{inp} -> {out}: {len(disp):,} points{removed}, {_method(args)}, "
              f"{_iterations(result.stats)}, {seconds:.2f} s; {_tiles(result.stats, 'in memory')}"
              f"displacement max {disp.max():.4g}, mean {disp.mean():.4g}"
              f"{_rounded(out, fmt)}{_copies(result.stats)}"
              f"{_classes_done(result.stats)}", file=say)
    if args.verbose:
        _details(result.stats, say)


def _labels(args, cloud, name):
    """The ``classification`` and ``classes`` that :func:`pssd_fast.denoise` takes for
    ``cloud`` (none where every point is denoised as one cloud), and the rows of each class it
    denoises on its own (None: one cloud)."""
    from .classes import select

    classification = cloud.fields.get("classification")
    if classification is None:
        if args.classes not in (None, "all"):
            raise CommandError(f"--classes: {name} has no classification field (LAS/LAZ "
                               "files have one; other formats need a 'classification' column)")
        return {}, None
    if args.classes == "all":
        return {}, None
    try:
        runs, *_ = select(classification, args.classes, len(cloud),
                          {"k": args.k, "preset": args.preset})
    except (TypeError, ValueError) as exc:
        raise CommandError(f"{name}: {_one_line(exc)}") from None
    if runs[0][0] is None:
        return {}, None  # the file's classes are 0 and 1 only: no classification
    return {"classification": classification, "classes": args.classes}, [r for _, r in runs]


def _classes_done(stats):
    """What a classified run denoised, for the line ``pssd denoise`` prints."""
    done = stats.get("classes")
    if done is None or done["classes"] == "all":
        return ""
    codes = done["classes"]
    return (f"; class{'es' * (len(codes) > 1)} {', '.join(map(str, codes))} denoised"
            f"{' each on its own' * (len(codes) > 1)}, {done['untouched']:,} points of other "
            f"classes kept")


def _read(path, args, fmt=None):
    """:func:`pssd_fast.io.read` of ``path``, with the column names of ``--columns``."""
    from . import io

    return io.read(path, format=fmt, columns=args.columns)


def _given_normals(cloud, name, rows=None):
    """The normals of ``cloud`` for a run on its ``rows`` (a mask; default every point), or
    None for a run that estimates them: where the file has none, or where some of those points
    have none (a row of NaN, Inf or zeros, as ``--classes`` writes for the points outside its
    classes), with a note (docs/DECISIONS.md, "No normal")."""
    normals = cloud.normals
    if normals is None:
        return None
    used = normals if rows is None else normals[rows]
    missing = ~(np.isfinite(used).all(axis=1) & (np.abs(used).max(axis=1) > 0.0))
    if not missing.any():
        return normals
    which = "" if rows is None else " to denoise"
    print(f"pssd: note: {name}: {int(missing.sum()):,} of the {len(used):,} points{which} "
          f"have no normal (NaN or zeros); every normal is estimated, none read from the file",
          file=sys.stderr)
    return None


def _demo(args):
    from . import datasets
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
    result, seconds = _run_denoise(cloud.points, None, args, {}, extras=True)
    written = _demo_files(args, cloud.points, result)
    try:
        from .pictures import figure_set
    except ImportError:
        figure_set = None
    pictures = []
    if figure_set is not None:
        try:
            # The generated part is z-up, as choose_up finds for it (it is flat).
            pictures = figure_set(
                args.out, cloud.points, result.points, likelihood=result.likelihood,
                feature=result.feature_intensity, displacement=result.displacement,
                normals_denoised=result.normals, up="z", size=_size(args))
        except ImportError as exc:
            print(f"pssd: no pictures: {_one_line(exc)}", file=sys.stderr)
    if args.quiet:
        return 0
    before, after, disp, edge = cloud.errors(result)
    print(f"pssd demo: built-in CAD part, {len(disp):,} points, noise {args.noise:.2%} of the "
          f"diagonal, seed {args.seed}; kernels ready in {compile_seconds:.1f} s")
    # The paper's Table 1 calls the displacement "error"; the true error is beside it here.
    print("| Method | Iters. | Max. displacement (1e-4) | Ave. displacement (1e-4) | Exec time | "
          "mean dist. noisy -> denoised | near edges |")
    print("|---|---|---|---|---|---|---|")
    print(f"| Robust ({args.preset}) | {result.stats['n_iterations']} | {disp.max():.1f} | "
          f"{disp.mean():.1f} | "
          f"{seconds:.2f}s | {before.mean():.1f} -> {after.mean():.1f} | "
          f"{before[edge].mean():.1f} -> {after[edge].mean():.1f} |")
    if args.verbose:
        _details(result.stats, sys.stdout)
    for path in written + pictures:
        print(f"wrote {path}")
    return 0


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
        with _appeared(path):
            io.write(path, source, overwrite=args.force, **kwargs)
        written.append(path)
    return written


def _info(args):
    from ._threads import kdtree

    from . import io

    if _is_zarr(args.file):
        raise CommandError(f"{args.file}: pssd info reads point-cloud files; a Zarr array is "
                           "read by pssd denoise --tile-points")
    cloud = _read(args.file, args, args.format if _is_stdio(args.file) else None)
    points = cloud.points
    low, high = points.min(axis=0), points.max(axis=0)
    diagonal = np.linalg.norm(high - low)
    # Fixed point, to a millionth of the diagonal or so: georeferenced coordinates (4e6 m)
    # keep their metres and millimetres, where significant digits would round them away.
    decimals = int(np.clip(5 - np.floor(np.log10(diagonal)), 0, 15)) if diagonal > 0 else 6
    print(f"{args.file}: {cloud.format}, {len(points):,} points")
    print(f"bounds: min {_vec(low, decimals)}, max {_vec(high, decimals)}, diagonal "
          f"{diagonal:.{decimals}f}")
    if len(points) > 1:
        dist, _ = kdtree(points).query(points, k=2)
        nearest = dist[:, 1]
        # Copies are 0 apart: the median of the others decides which points are stray.
        apart = nearest[nearest > 0]
        stray = nearest > STRAY * (np.median(apart) if apart.size else np.inf)
        count = int(stray.sum())
        left_out = (f"; {count:,} point{'s' * (count > 1)} farther than {STRAY:g} times the "
                    f"median from every other left out (stray?)") if count else ""
        print(f"average spacing (mean distance to the nearest other point): "
              f"{nearest[~stray].mean():.6g}{left_out}")
    attributes = (["normals"] if cloud.normals is not None else []) + [
        f"{name} ({values.dtype})" for name, values in cloud.fields.items()]
    print("attributes: " + (", ".join(attributes) if attributes else "none"))
    for line in io.describe(cloud):
        print(line)
    return 0


def _vec(v, decimals):
    return "(" + ", ".join(f"{x:.{decimals}f}" for x in v) + ")"


#: The pictures of what ``pssd denoise`` moves or computes for the classes it denoises.
MOVED = ("likelihood", "feature", "displacement")


def _render(args):
    from .pictures import draw, view
    from .pictures.fields import FROM_CLOUD, field_values, units
    from .stages import estimate_normals

    _check_output(args.output, args.force)
    draw.image_format(args.output)  # refuse an unknown format before the long work
    size = _size(args)
    cloud = _read(args.file, args, args.format if _is_stdio(args.file) else None)
    points = cloud.points
    given = _given_normals(cloud, args.file)
    up = view.choose_up(points, cloud.format == "las") if args.up == "auto" else args.up
    # The classes pssd denoise denoised (by default the surface classes present).
    labels, runs = _labels(args, cloud, args.file) if args.color in MOVED else ({}, None)
    if args.color == "height":
        values = view.height(points, up)
    elif args.color in FROM_CLOUD:
        try:
            values = field_values(args.color, points, stored=cloud.fields)
        except ValueError as exc:  # a field FILE lacks or holds wrongly
            raise CommandError(f"{args.file}: {exc}") from None
    else:
        progress = _Progress(STAGE_COUNT["robust"], not args.quiet)
        try:
            values = field_values(args.color, points, given, cloud.fields,
                                  progress=progress, **_common_options(args), **labels)
        finally:
            progress.close()
    missing = None
    if runs is not None:
        kept = np.ones(len(cloud), np.bool_)
        for rows in runs:
            kept[rows] = False
        values = np.where(kept, np.nan, values)
        missing = "kept in place\n(other classes)"
    normals = estimate_normals(points, n_jobs=args.n_jobs) if given is None else given
    seen_from = view.choose_view(points, up) if args.view is None else tuple(args.view)
    draw.render(points, values, args.output, field=None if args.color == "rgb" else args.color,
                view=seen_from, up=up, normals=normals, units=units(cloud),
                title=args.file.name, size=size, missing=missing)
    if not args.quiet:
        print(f"wrote {args.output} (up axis {up}, view {seen_from[0]:g} {seen_from[1]:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
