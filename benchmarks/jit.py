"""JIT cost: what a new user waits for, and the compile time of each kernel.

Usage::

    python -m benchmarks.jit

Each measurement runs in a fresh process; "empty cache" points ``PSSD_FAST_CACHE_DIR`` at a new
temporary folder, so every kernel it needs compiles, and "warm" runs again on that folder.

- The README's first command, ``python -m pssd_fast``: its wall time (interpreter start, import,
  compiling what the run needs, denoising, errors), from an empty cache and then warm.
- ``pssd_fast.warmup()``, which compiles every kernel signature: the stages are first called
  one at a time on a small cloud (each first call's time is its kernel's compile time), then
  ``warmup()`` compiles the rest. Then the import and ``warmup()`` times of a warm process.

Writes ``benchmarks/results/jit.md`` and ``.json``.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from .stages import RESULTS, machine, write_results

#: Stage (as timed by the child) -> the kernel(s) its first call compiles.
KERNELS = {
    "neighbors": "graph.put_self_first",
    "normals": "normals.pca_normals",
    "mls": "mls.mls_fit",
    "likelihood": "likelihood.sampling_likelihood",
    "feature": "feature.feature_intensity",
    "filter": "bilateral.filter_normals",
    "update": "update.move_points",
    "bilateral (BIL)": "bilateral.filter_points",
    "aware fit (default preset)": "mls.aware_fit",
}


def cold_child():
    """First call of each stage on a small cloud, in pipeline order (all compile)."""
    import pssd_fast
    from pssd_fast import core, datasets
    from pssd_fast.graph import knn_graph
    # A writable copy: read-only arrays (the dataset's) are a separate numba specialisation.
    points = datasets.sphere(n_points=500, seed=0).points.copy()
    times = {}

    def timed(name, func, *args):
        started = time.perf_counter()
        out = func(*args)
        times[name] = time.perf_counter() - started
        return out

    graph = timed("neighbors", knn_graph, points, 25, False)
    nrm, _ = timed("normals", core.pca_normals, points, graph, core.outward_hints(points))
    h = core.default_h(graph)
    proj, resid, _, _ = timed("mls", core.mls_fit, points, nrm, graph, h)
    lik, _ = timed("likelihood", core.sampling_likelihood, resid, "exp")
    radius = 10 * core.mean_spacing(graph)
    feat, _ = timed("feature", core.feature_intensity, points, nrm, graph, radius, 0.2, 0.3, 0.3)
    filtered = timed("filter", core.filter_normals, points, nrm, graph)
    timed("update", core.move, points, proj, filtered, lik, feat, 0.5)
    timed("bilateral (BIL)", core.filter_points, points, nrm, graph, 0.0, 0.0)
    timed("aware fit (default preset)", core.aware_fit, points, filtered, graph, 0.05, None,
          True)
    started = time.perf_counter()
    pssd_fast.warmup()
    rest = time.perf_counter() - started
    print(json.dumps({"kernels": times, "rest_of_warmup": rest}))


def warm_child():
    """``warmup()`` with every kernel in the cache."""
    import pssd_fast
    print(json.dumps({"warmup": pssd_fast.warmup()}))


#: A new interpreter's import of pssd_fast (the benchmarks package imports it first).
IMPORT = ("import time; started = time.perf_counter(); import pssd_fast; "
          "print(time.perf_counter() - started)")


def _import_seconds():
    out = subprocess.run([sys.executable, "-c", IMPORT], capture_output=True, text=True,
                         check=True)
    return float(out.stdout)


def _demo(cache):
    """Wall time of ``python -m pssd_fast`` on ``cache``, and the line saying what it compiled."""
    env = dict(os.environ, PSSD_FAST_CACHE_DIR=cache)
    started = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "pssd_fast"], env=env, capture_output=True,
                         text=True, check=True)
    seconds = time.perf_counter() - started
    line, = (line for line in out.stdout.splitlines() if line.startswith("denoised in"))
    return {"seconds": seconds, "report": line}


def _run(role, cache):
    env = dict(os.environ, PSSD_FAST_CACHE_DIR=cache)
    out = subprocess.run([sys.executable, "-m", "benchmarks.jit", "--child", role], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--child", choices=("cold", "warm"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        cold_child() if args.child == "cold" else warm_child()
        return
    with tempfile.TemporaryDirectory() as cache:
        demo = {"cold": _demo(cache), "warm": _demo(cache)}
    with tempfile.TemporaryDirectory() as cache:
        cold = _run("cold", cache)
        warm = _run("warm", cache)
    warm["import"] = _import_seconds()
    stages = sum(cold["kernels"].values())
    runs = [("`python -m pssd_fast`, empty cache", demo["cold"]["seconds"], "60"),
            ("`python -m pssd_fast`, again", demo["warm"]["seconds"], "3"),
            ("`pssd_fast.warmup()`, empty cache", stages + cold["rest_of_warmup"], "120"),
            ("`pssd_fast.warmup()`, warm cache", warm["warmup"], ""),
            ("`import pssd_fast`", warm["import"], "")]
    lines = ["| run | seconds | at most |", "|---|---|---|"]
    lines += [f"| {run} | {seconds:.2f} | {target} |" for run, seconds, target in runs]
    kernels = ["| stage | kernel | compile (s) |", "|---|---|---|"]
    kernels += [f"| {stage} | `{KERNELS[stage]}` | {seconds:.2f} |"
                for stage, seconds in cold["kernels"].items()]
    text = (f"Machine: {machine()}\n\nWall times of new processes:\n\n" + "\n".join(lines)
            + f"\n\nThe demo's own report, empty cache: {demo['cold']['report']}\n"
            f"Warm: {demo['warm']['report']}\n\nEmpty cache, each stage's first call (its "
            f"kernel and the helpers it calls):\n\n" + "\n".join(kernels)
            + f"\n| all | | {stages:.2f} |\n\nThe rest of `warmup()` (the other kernels and "
            f"specialisations): {cold['rest_of_warmup']:.2f} s.\n")
    print(text)
    write_results(RESULTS, "jit", text, {"demo": demo, "cold": cold, "warm": warm})


if __name__ == "__main__":
    main()
