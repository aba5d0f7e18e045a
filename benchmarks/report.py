"""The generated parts of ``docs/benchmarks.md``, rebuilt from ``benchmarks/results/``.

The doc marks each generated block with a pair of comments that name its source::

    <!-- begin results/sheets.md#table -->
    ...
    <!-- end results/sheets.md#table -->

``results/NAME`` alone stands for that file's whole text, ``results/NAME#VIEW`` for one of
:data:`VIEWS`: a table taken from the file, or built from it and its ``.json``. The text
outside the blocks is hand-written and kept as it is.

Usage::

    python -m benchmarks.report            # rewrite docs/benchmarks.md
    python -m benchmarks.report --check    # name the blocks out of date, exit 1 if any

Each benchmark script runs :func:`update` after writing its results
(``benchmarks.stages.write_results``).
"""
import argparse
import json
import re
import sys
from pathlib import Path

from pssd_fast.atomic import replacing

RESULTS = Path(__file__).resolve().parent / "results"
DOC = RESULTS.parent.parent / "docs" / "benchmarks.md"
MARKER = re.compile(r"<!-- (begin|end) (results/[^\s#]+(?:#\S+)?) -->")


class Table:
    """A markdown table: ``header``, a list of column names, and ``rows``, lists of cells."""

    def __init__(self, header, rows):
        self.header, self.rows = list(header), [list(row) for row in rows]

    @classmethod
    def first_in(cls, path):
        """The first table of the markdown file ``path``."""
        return cls.nth_in(path, 0)

    @classmethod
    def nth_in(cls, path, n):
        """The ``n``-th table (from 0) of the markdown file ``path``."""
        runs, run = [], []
        for line in Path(path).read_text().splitlines() + [""]:
            if line.startswith("|"):
                run.append([cell.strip() for cell in line.strip().strip("|").split("|")])
            elif run:
                runs, run = runs + [run], []
        if n >= len(runs):
            raise ValueError(f"{path}: no markdown table number {n + 1}")
        return cls(runs[n][0], runs[n][2:])

    def select(self, columns=None, keep=None):
        """Only ``columns`` (all by default), in their order, of the rows whose dict (column
        name to cell) passes ``keep``."""
        columns = columns or self.header
        missing = [c for c in columns if c not in self.header]
        if missing:
            raise KeyError(f"no columns {missing} in {self.header}")
        return Table(columns, [[r[c] for c in columns] for r in self.records()
                               if not keep or keep(r)])

    def records(self):
        """Each row as a dict from column name to cell."""
        return [dict(zip(self.header, row)) for row in self.rows]

    def markdown(self):
        rows = ["| " + " | ".join(cells) + " |" for cells in (self.header, *self.rows)]
        return "\n".join([rows[0], "|" + "---|" * len(self.header), *rows[1:]])


def _cgal(path):
    """The first table without the Open3D columns (the doc gives those in its prose)."""
    table = Table.first_in(path)
    return table.select([c for c in table.header if "o3d" not in c]).markdown()


def _cgal_errors(path):
    """The default's errors against CGAL's, without ``fast``, ``paper`` and the times."""
    table = Table.first_in(path)
    last = table.header.index("W/L bil.")
    return table.select([c for c in table.header[:last + 1] if c != "ours paper"]).markdown()


#: The rows of Table 1 the doc shows: (method, iterations).
PAPER_ROWS = {("noisy input", ""), ("BIL", "2"), ("MLS", "2"), ("Robust (paper)", "2"),
              ("Robust", "2"), ("Robust", "3"), ("CGAL jet (k=48, 2 passes)", ""),
              ("CGAL bilateral (k=60, 3 passes)", ""), ("MeshLab RIMLS (defaults)", "")}


def _paper_rows(path):
    """Table 1 at 0.5% noise: the paper's methods and the default at 2 iterations, the
    default at 3 and one setting of each peer."""
    columns = ["model", "method", "iters", "Max disp.", "Ave disp.", "mean dist.", "edge dist.",
               "normal err. (deg)", "time (s)"]
    return Table.first_in(path).select(columns, lambda r: r["noise"] == "0.50%" and (
        r["method"], r["iters"]) in PAPER_ROWS).markdown()


def _scan_sizes(path):
    """Whole runs: every default run, and ``paper`` at 1 and 10 million points."""
    columns = ["points", "preset", "iterations", "cells (points each)", "k",
               "noisy mean / edge", "denoised mean / edge", "total (s)", "total / kNN",
               "bytes/point"]
    return Table.first_in(path).select(columns, lambda r: r["preset"] == "default" or r[
        "points"] in ("1,000,000", "10,000,000")).markdown()


def _stages(path):
    """The stage times without ``k`` (25 throughout) and the two stages under 1%."""
    table = Table.first_in(path)
    return table.select([c for c in table.header
                         if c not in ("k", "likelihood", "update")]).markdown()


def _fast_vs_jet(path):
    """One row per size, ``fast`` and CGAL jet side by side at each noise level: errors, the
    better on both in bold, then the time over the kNN query."""
    cells = {(c["points"], c["noise"], c["preset"]): c
             for c in json.loads(path.with_suffix(".json").read_text())["cells"]}
    sizes = sorted({c[0] for c in cells})
    noises = sorted({c[1] for c in cells})
    header = ["points"] + [f"{p} {100 * n:g}%" for n in noises for p in ("fast", "jet")]
    rows = []
    for n in sizes:
        row = [f"{n:,}"]
        for noise in noises:
            fast, jet = (cells.get((n, noise, p)) for p in ("fast", "jet"))
            for cell, other in ((fast, jet), (jet, fast)):
                if cell is None:
                    row.append("-")
                    continue
                errors = f"{cell['mean_after']:.1f} / {cell['edge_after']:.1f}"
                if other and all(cell[e] < other[e] for e in ("mean_after", "edge_after")):
                    errors = f"**{errors}**"
                ratio = cell["total"] / cell["knn_query"]
                row.append(f"{errors}, {ratio:.{0 if ratio >= 10 else 1}f}x")
        rows.append(row)
    return Table(header, rows).markdown()


def _bullets(path):
    """The first bulleted list of the file: the standings a script states in words."""
    lines = Path(path).read_text().splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith("- ")), None)
    if start is None:
        raise ValueError(f"{path}: no bulleted list")
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("- ")),
               len(lines))
    return "\n".join(lines[start:end])


#: View name -> function of the results file that returns the block's markdown.
VIEWS = {"table": lambda path: Table.first_in(path).markdown(),
         "times": lambda path: Table.nth_in(path, 1).markdown(), "standings": _bullets,
         "targets": lambda path: Table.nth_in(path, 1).markdown(),
         "frontier": lambda path: Table.nth_in(path, 2).markdown(),
         "cgal": _cgal,
         "cgal-errors": _cgal_errors, "paper-rows": _paper_rows, "scan-sizes": _scan_sizes,
         "stages": _stages, "fast-vs-jet": _fast_vs_jet}


def render(source, results=RESULTS):
    """The markdown of the block named ``source`` (``results/NAME`` or ``results/NAME#VIEW``).

    Raises
    ------
    FileNotFoundError
        No such results file.
    KeyError
        No such view.
    """
    name, _, view = source.removeprefix("results/").partition("#")
    path = Path(results) / name
    if not path.is_file():
        raise FileNotFoundError(f"{source}: no results file {path}")
    if not view:
        return path.read_text().strip()
    if view not in VIEWS:
        raise KeyError(f"{source}: unknown view {view!r} (known: {', '.join(VIEWS)})")
    return VIEWS[view](path)


def regenerate(text, results=RESULTS):
    """``text`` with every block's content rebuilt, and the sources of the blocks it changed.

    Raises
    ------
    ValueError
        A begin marker without its end, an end without its begin, or nested blocks.
    """
    out, stale, source, old = [], [], None, []
    for n, line in enumerate(text.splitlines(keepends=True), 1):
        match = MARKER.fullmatch(line.strip())
        if match is None:
            (old if source else out).append(line)
            continue
        kind, name = match.groups()
        if kind == "begin" and source is None:
            source, old = name, []
            out.append(line)
        elif kind == "end" and name == source:
            new = f"\n{render(source, results)}\n\n"
            stale += [source] if "".join(old) != new else []
            out += [new, line]
            source = None
        else:
            raise ValueError(f"line {n}: {line.strip()} does not pair with "
                             + (f"the open block {source}" if source else "a begin marker"))
    if source:
        raise ValueError(f"block {source} has no end marker")
    return "".join(out), stale


def update(path=DOC, results=RESULTS, check=False):
    """Rebuild the generated blocks of ``path`` from ``results``; return the sources of the
    blocks that were out of date. With ``check`` the file is left as it is."""
    text, stale = regenerate(Path(path).read_text(), results)
    if stale and not check:
        with replacing(path) as fh:
            fh.write(text.encode())
    return stale


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 naming the blocks out of date")
    parser.add_argument("--doc", type=Path, default=DOC)
    args = parser.parse_args(argv)
    stale = update(args.doc, check=args.check)
    for source in stale:
        print(f"{args.doc}: {'out of date' if args.check else 'rewrote'} {source}")
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
