"""``python -m pssd_fast``: denoise the built-in CAD part and report the error against the truth."""
import argparse
import time

import numpy as np

from . import __version__, datasets
from .cli import add_parameter
from .denoise import denoise
from .jit import cache
from .warmup import compile_ahead


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="python -m pssd_fast",
        description="Denoise the library's generated CAD part (sharp edges and a curved patch) "
                    "with the robust method and compare with the true surface.")
    parser.add_argument("--points", type=int, default=60_000, help="points sampled (60000)")
    parser.add_argument("--noise", type=float, default=0.0025,
                        help="Gaussian noise sigma as a fraction of the diagonal (0.0025)")
    for name in ("iterations", "preset", "k", "lam"):
        add_parameter(parser, name)
    parser.add_argument("--seed", type=int, default=0, help="random seed (0)")
    add_parameter(parser, "n_jobs", "--n-jobs")
    args = parser.parse_args(argv)

    # A first run compiles the longest kernel beside it (pssd_fast.warmup.compile_ahead).
    ahead = compile_ahead() if args.preset != "paper" else None
    try:
        cloud = datasets.cad_part(n_points=args.points, noise=args.noise, seed=args.seed)
        started = time.perf_counter()
        result = denoise(cloud.points, iterations=args.iterations, k=args.k, lam=args.lam,
                         preset=args.preset, n_jobs=args.n_jobs)
        seconds = time.perf_counter() - started
    except BaseException:
        if ahead is not None:
            ahead.kill()
        raise
    finally:
        if ahead is not None:
            ahead.wait()

    before, after, moved, edge = cloud.errors(result)
    print(f"pssd_fast {__version__}: robust denoising of the built-in CAD part")
    lam = "" if result.stats["lam"] is None else f", lambda={result.stats['lam']}"
    print(f"{len(cloud.points):,} points, noise sigma {args.noise:.2%} of the diagonal, "
          f"preset {args.preset!r}: {result.stats['n_iterations']} iterations, "
          f"k={result.stats['k']}{lam}, {result.stats['n_jobs']} threads")
    kernels = cache.stats()
    print(f"denoised in {seconds:.2f} s, {kernels['seconds']:.2f} s of it to compile "
          f"{kernels['compiled']} kernel signatures and load {kernels['loaded']} from the cache")
    print(f"\n{'distance to the true surface (1e-4 diag)':44s}{'noisy':>9s}{'denoised':>10s}")
    rows = (("all points, mean", slice(None)), ("within 1% of a sharp edge, mean", edge),
            ("all points, max", None))
    for label, mask in rows:
        if mask is None:
            print(f"{label:44s}{before.max():9.1f}{after.max():10.1f}")
        else:
            print(f"{label:44s}{before[mask].mean():9.1f}{after[mask].mean():10.1f}")
    print(f"displacement |p_noisy - p_denoised| (1e-4 diag): max {moved.max():.1f}, "
          f"mean {moved.mean():.1f}")
    times = {}
    for record in result.stats["iterations"]:
        for stage, t in record["times"].items():
            times[stage] = times.get(stage, 0.0) + t
    print("time per stage (s): " + ", ".join(f"{s} {t:.2f}" for s, t in times.items()))
    return 0 if np.isfinite(result.points).all() else 1


if __name__ == "__main__":
    raise SystemExit(main())
