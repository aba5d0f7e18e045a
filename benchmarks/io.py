"""PLY files against denoising: each raw range view read, written back and denoised.

Usage::

    python -m benchmarks.io                 # every raw view
    python -m benchmarks.io --repeats 5

Each ``*.ply.gz`` of the ``realscans/`` folder of ``PSSD_DATA`` (or ``--data``), an ASCII PLY of
a scanner's points and its ``range_grid`` (a list per pixel, 204,800 rows), is read with
``pssd_fast.io.read``; written with ``pssd_fast.io.write`` as it came (ASCII ``.ply.gz``), as
ASCII ``.ply`` and as binary ``.ply`` (the same file, little-endian), which is read back too;
and its points are denoised with ``pssd_fast.denoise`` at its defaults, after
``pssd_fast.warmup()``, in the same process. File times are the best of ``--repeats``, the
denoising is run once. *Round trip / denoise*: (read + write as it came) over the denoising.
plyfile's own ``PlyData.read`` and ``PlyData.write`` of the same (ungzipped) text, once, show
what reading and writing cost before numpy took over the bodies. Sizes in KB: the input and
the ASCII output, gzipped as the file came and ungzipped.

Results: ``benchmarks/results/io.md`` and ``.json``.
"""
import argparse
import copy
import dataclasses
import gzip
import io
import tempfile
import time
import warnings
from pathlib import Path

import plyfile

import pssd_fast
from pssd_fast import io as pio

from .models import data_folder, missing
from .stages import add_output, machine, write_results


def as_binary(cloud):
    """``cloud`` with its PLY source turned binary little-endian, the rest of the file kept."""
    ply = copy.copy(cloud.source.ply)
    ply.text, ply.byte_order = False, "<"
    return dataclasses.replace(cloud, source=dataclasses.replace(cloud.source, ply=ply))


def best(call, repeats):
    """The fewest seconds ``call()`` took in ``repeats`` runs."""
    seconds = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - started)
    return min(seconds)


def plyfile_seconds(text):
    """(read, write) seconds of plyfile's own reader and writer on a PLY's ungzipped bytes."""
    with warnings.catch_warnings():  # its loadtxt warns of every empty list of a range grid
        warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
        started = time.perf_counter()
        ply = plyfile.PlyData.read(io.BytesIO(text))
        read = time.perf_counter() - started
    started = time.perf_counter()
    ply.write(io.BytesIO())
    return read, time.perf_counter() - started


def measure(path, folder, repeats, log):
    """One view's row: seconds, sizes in bytes and the ratio of the round trip to denoising."""
    name = path.name.removesuffix(".ply.gz")
    cloud = pio.read(path)
    binary = as_binary(cloud)
    out = {"ascii_gz": folder / f"{name}.ply.gz", "ascii": folder / f"{name}.ply",
           "binary": folder / f"{name}.binary.ply"}
    row = {"view": name, "points": len(cloud), "read": best(lambda: pio.read(path), repeats)}
    for kind, source in (("ascii_gz", cloud), ("ascii", cloud), ("binary", binary)):
        row[f"write_{kind}"] = best(lambda t=out[kind], c=source: pio.write(t, c, overwrite=True),
                                    repeats)
    row["read_binary"] = best(lambda: pio.read(out["binary"]), repeats)
    started = time.perf_counter()
    pssd_fast.denoise(cloud.points)
    row["denoise"] = time.perf_counter() - started
    row["round_trip_over_denoise"] = (row["read"] + row["write_ascii_gz"]) / row["denoise"]
    text = gzip.decompress(path.read_bytes())
    row["plyfile_read"], row["plyfile_write"] = plyfile_seconds(text)
    row["bytes"] = {"in_gz": path.stat().st_size, "out_gz": out["ascii_gz"].stat().st_size,
                    "in": len(text), "out": out["ascii"].stat().st_size,
                    "binary": out["binary"].stat().st_size}
    log(f"{name}: read {row['read']:.3f} s, write {row['write_ascii_gz']:.3f} s, denoise "
        f"{row['denoise']:.2f} s, round trip / denoise {row['round_trip_over_denoise']:.3f}")
    return row


def markdown(rows, compile_seconds, repeats):
    head = ("| view | points | read (s) | write .ply.gz (s) | write .ply (s) | write binary (s) "
            "| read binary (s) | denoise (s) | round trip / denoise | plyfile read / write (s) "
            "| .ply.gz in / out (KB) | out / in | .ply in / out (KB) | out / in |")
    lines = [(f"Machine: {machine()}. JIT compilation before timing: {compile_seconds:.1f} s. "
              f"File times: best of {repeats}."), "", head, "|---" * head.count(" | ") + "|---|"]
    for r in rows:
        size = r["bytes"]
        lines.append(
            f"| {r['view']} | {r['points']:,} | {r['read']:.3f} | {r['write_ascii_gz']:.3f} | "
            f"{r['write_ascii']:.3f} | {r['write_binary']:.3f} | {r['read_binary']:.3f} | "
            f"{r['denoise']:.2f} | {r['round_trip_over_denoise']:.3f} | "
            f"{r['plyfile_read']:.2f} / {r['plyfile_write']:.2f} | "
            f"{size['in_gz'] / 1e3:.0f} / {size['out_gz'] / 1e3:.0f} | "
            f"{size['out_gz'] / size['in_gz']:.3f} | {size['in'] / 1e3:.0f} / "
            f"{size['out'] / 1e3:.0f} | {size['out'] / size['in']:.3f} |")
    return "\n".join(lines) + (
        "\n\nRound trip: reading the view and writing it back as it came (ASCII .ply.gz). "
        "plyfile: its own reader and writer on the ungzipped text, once.\n")


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=data_folder("realscans"),
                        help="the folder of the raw views (*.ply.gz)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="runs of each read and write; the best is kept (default 3)")
    add_output(parser, "io")
    args = parser.parse_args(argv)
    args.views = sorted(args.data.glob("*.ply.gz")) if args.data.is_dir() else []
    if not args.views:
        parser.exit(0, f"skipped: {missing('realscans', ['*.ply.gz'])}\n")
    return args


def main(argv=None):
    args = parse_args(argv)
    log = (lambda line: None) if args.quiet else print
    compile_seconds = pssd_fast.warmup()
    with tempfile.TemporaryDirectory() as folder:
        rows = [measure(path, Path(folder), args.repeats, log) for path in args.views]
    text = markdown(rows, compile_seconds, args.repeats)
    write_results(args.out, args.stem, text, {"compile_seconds": compile_seconds,
                                              "repeats": args.repeats, "rows": rows}, indent=1)
    log(text)
    return rows


if __name__ == "__main__":
    main()
