"""The one executor of the default method: its steps run as rounds of tile tasks with halos,
in memory or from files, and a run in one tile is the in-core run (docs/ALGORITHM.md,
"Tiles").

Every step reads a radius the plan fixed before the run (:class:`pssd_fast.plan.Plan`): a
tile's task gets its own items first, then every other item within ``hops`` radii of the
boxes of its own (:func:`pssd_fast.store.gather`), with their places in the whole cloud, which
order tied neighbours. The lists of the items it keeps are then the whole cloud's, and so are
its results, bit for bit, whatever the tiles (:func:`pssd_fast.graph.nearest_within`).

The rounds: the iterations on the cell means (in one tile a task an iteration; in several a
round a step, each over a halo of one list bound, reading the step before's results from the
tiles that own them: :func:`_exchanged`); every point onto the last fits of its nearest means
(one bound); where the plan says so, each point's own noise from its own fit (three bounds of
the refinement's lists); the test of each cell (one bound); the failing points' own iterations
(the points within four bounds of their lists of the failing ones, then three). The cells
themselves come first
(:func:`group`, or :mod:`pssd_fast.tiled.ondisk` out of core): each tile holds whole cells,
consecutive along their Morton curve, and its points grouped by cell.
"""
from typing import NamedTuple

import numpy as np

from . import core, method, regions
from ._threads import threads
from .graph import ListScales, bounded_graph, cell_keys, knn_graph
from .pipelines import aware
from .progress import Clock
from .store import gather, gather_again, gather_halo

class Tile(NamedTuple):
    """A tile: its first cell ``c0`` and its cells ``cells``, its ``points``, and the boxes of
    its points and of its cell means (:func:`pssd_fast.regions.boxes`)."""

    c0: int
    cells: int
    points: int
    point_boxes: np.ndarray
    cell_boxes: np.ndarray


class Local:
    """Runs a round's tasks here, one after another, with every thread: the in-core run, and
    the tiled runs' ``"sync"``. :class:`pssd_fast.tiled.scheduler.Runner` runs them on Dask."""

    name = "in-core"
    threads = None

    def __init__(self, n_jobs=None):
        self.n_jobs = n_jobs

    def map(self, stage, iteration, iterations, func, argsets):
        return [func(*args, self.n_jobs) for args in argsets]


def group(current, given, plan, store, tile_points=None):
    """The cells of the points ``current`` (Morton order; the caller's normals ``given`` or
    None) put into ``store`` tile by tile (``("points", i)``: the tile's points grouped by
    cell, their places ``gid`` in ``current`` and their cell ``cell``; ``("cells", i, 0)``:
    its cell means, the points they hold and their places), in tiles of at most
    ``tile_points`` points (None: one tile) cut as out of core: between bins of the first bits
    of the cells' codes (:func:`pssd_fast.regions.parts`). Returns the :class:`Tile` list."""
    cells = method.cells_of(current, given, plan.edge, plan.low)
    ends = np.concatenate(([0], np.cumsum(cells.counts)))
    tiles = []
    cut = _cuts(current, cells, plan, tile_points)
    for c0, c1 in zip(cut[:-1].tolist(), cut[1:].tolist()):
        rows = cells.order[ends[c0]:ends[c1]]
        i = len(tiles)
        points = {"xyz": current[rows], "gid": rows, "cell": cells.owner[rows]}
        means = {"xyz": cells.points[c0:c1], "mass": cells.counts[c0:c1].astype(np.float64),
                 "gid": np.arange(c0, c1)}
        if given is not None:
            points["given"] = given[rows]
            means["normals"] = cells.normals[c0:c1]
        store.put(("points", i), points)
        store.put(("cells", i, 0), means)
        tiles.append(Tile(c0, c1 - c0, rows.shape[0], regions.boxes(points["xyz"]),
                          regions.boxes(means["xyz"])))
    return tiles


def _cuts(current, cells, plan, tile_points):
    """The first cell of each tile of :func:`group`, and the number of cells."""
    m = cells.counts.shape[0]
    if tile_points is None:
        return np.array([0, m])
    shift, prefix = regions.code_shifts(current.max(axis=0), plan.low, plan.edge)
    codes = cell_keys(current[cells.order[cells.starts[:-1]]], plan.low, plan.edge, shift)[0]
    found, inverse = np.unique(codes >> np.uint64(prefix), return_inverse=True)
    firsts = regions.parts(regions.histogram(
        [(found, np.bincount(inverse, cells.counts, found.shape[0]).astype(np.int64))]),
        prefix, tile_points, lambda split: [regions.binned(codes, split, cells.counts)])
    # The cells are in the order of their codes: each tile's are consecutive.
    return np.searchsorted(regions.part_of(firsts, codes), np.arange(firsts.shape[0] + 1))


def run(plan, request, tiles, store, runner=None):
    """The default method's rounds over the ``tiles`` in ``store`` (:func:`group`), their
    tasks run by ``runner`` (None: here). Returns each tile's final entry key (``("out", i)``:
    its points' ``xyz``, ``normals`` and ``held``, with ``gid``, and the likelihood and feature
    intensity where ``request.extras``), one record per iteration on the means, and the keys
    of the last iteration's means. Each round's stages are timed (the tasks' own stages summed
    over the tiles) and reported to ``request.report`` once the round is done."""
    runner = Local() if runner is None else runner
    params = request.params
    sigma_n, keep, shift = params["sigma_n"], params["keep_normals"], params["shift_normals"]
    whole = len(tiles) == 1
    given = "normals" in store.get(("cells", 0, 0))
    boxes = [tile.cell_boxes for tile in tiles]
    records = []
    for t in range(plan.iterations):
        clock = Clock(request.report, t, plan.iterations)
        own_given = given and (t == 0 or keep)
        first = None if own_given else t == 0
        keys = [("cells", i, t) for i in range(len(tiles))]
        if whole:
            out = runner.map("tile_iteration", t, plan.iterations, _iteration, [
                (store, keys, boxes, 0, None, own_given, first, plan, sigma_n,
                 t == plan.iterations - 1, shift)])
        else:
            out = _exchanged(runner, store, keys, boxes, own_given, first, plan, sigma_n,
                             t, shift)
        _tally(clock, [o[4] for o in out])
        if t > 0:  # read by this iteration only; the first means are the test's
            _drop(store, keys)
        origins, boxes = boxes, [o[0] for o in out]
        records.append(aware.step_record(clock.times, sum(o[1] for o in out),
                                         sum(o[2] for o in out),
                                         sum(tile.cells for tile in tiles),
                                         np.sum([o[3] for o in out], axis=0)))
    fits = [("fits", i) for i in range(len(tiles))]
    clock.run("project", runner.map, "tile_project", plan.iterations - 1, plan.iterations,
              _project, [(store, fits, origins, i, None if whole else regions.widened(
                  tiles[i].point_boxes, plan.bound), plan) for i in range(len(tiles))])
    records[-1]["cells"] = sum(tile.cells for tile in tiles)
    refined = False
    if plan.refine is not None:
        if plan.own_noise:
            # The own fits read the points within three of their lists' bounds: the lists,
            # the members' PCA normals and their filtered normals.
            _tally(clock, runner.map("tile_noise", plan.iterations - 1, plan.iterations, _noise, [
                (store, [("own", j) for j in range(len(tiles))],
                 [t.point_boxes for t in tiles], i, None if whole else regions.widened(
                     tiles[i].point_boxes, 3 * plan.refine.bound), plan, sigma_n)
                for i in range(len(tiles))]))
            _drop(store, [("own", i) for i in range(len(tiles))])
        keys = [("test", i) for i in range(len(tiles))]
        flagged = clock.run("test", runner.map, "tile_test", plan.iterations - 1,
                            plan.iterations, _test, [
                                (store, keys, [t.cell_boxes for t in tiles], i, None if whole
                                 else regions.widened(tiles[i].cell_boxes, plan.bound), plan)
                                for i in range(len(tiles))])
        _drop(store, keys)
        records[-1]["refined"] = int(sum(flagged))
        if sum(flagged):
            _refine(plan, tiles, store, runner, sigma_n, keep, whole, given, shift, clock)
            refined = True
    if not refined:
        runner.map("tile_out", plan.iterations - 1, plan.iterations, _placed_out,
                   [(store, i) for i in range(len(tiles))])
    _drop(store, [("placed", i) for i in range(len(tiles))])
    if request.extras:
        clock.run("extras", extras, store, tiles, fits, plan)
    if request.orient is not None:
        clock.run("orient", orient, store, tiles, request.orient, request.centre, whole)
    records[-1]["times"] = clock.times
    return [("out", i) for i in range(len(tiles))], records


def _drop(store, keys):
    """The entries ``keys``, read by no later round, removed from ``store``: a run holds only
    what its next rounds read."""
    for key in keys:
        store.drop(key)


def _tally(clock, times):
    """The tasks' stage ``times`` of a round (one dict per tile) summed into ``clock``, each
    stage reported in the order the tasks ran them."""
    total = {}
    for own in times:
        for stage, seconds in own.items():
            total[stage] = total.get(stage, 0.0) + seconds
    for stage, seconds in total.items():
        clock.add(stage, seconds)


def _iteration(store, keys, boxes, i, region, own_given, first, plan, sigma_n, last, shift,
               n_jobs):
    """The task of one iteration on the means in one tile (:func:`pssd_fast.method.iteration`
    on all of them): :func:`_next_means`. The first iteration's PCA normals are signed away
    from the cloud's centre (the positions are relative to it)."""
    items = gather(store, keys, i, boxes, region, _iteration_names(own_given, first), "xyz")
    clock = Clock(None, 0, 1)
    with threads(n_jobs):
        fits = method.iteration(items["xyz"], items["mass"], plan.k, plan.bound, sigma_n,
                                _signs(items, own_given, first), clock, first, items["gid"],
                                shift)
    return _next_means(store, keys, i, items, fits, last, clock.times)


def _iteration_names(own_given, first):
    """What an iteration reads of the means: positions, points held, places, and the given
    normals, or the hints of the PCA normals after the first."""
    if own_given:
        return ("xyz", "mass", "gid", "normals")
    return ("xyz", "mass", "gid") if first else ("xyz", "mass", "gid", "hints")


def _signs(items, own_given, first):
    """The given normals, or what signs the PCA normals: away from the cloud's centre in the
    first iteration (whatever the tile), then the previous filtered normals."""
    if own_given:
        return items["normals"]
    return items["xyz"] if first else items["hints"]


def _next_means(store, keys, i, items, fits, last, times):
    """Tile ``i``'s own means after an iteration's ``fits`` (of ``items``, its own first):
    their next entry (positions and filtered normals; in the ``last`` iteration their fits,
    ``("fits", i)``), and the boxes of their new positions, held count, RMS sum, degree
    counts and the stage ``times``."""
    entry = store.get(keys[i])
    n_own = entry["gid"].shape[0]
    own = {name: items[name][:n_own] for name in ("mass", "gid")}
    own.update({"xyz": fits.moved[:n_own], "hints": fits.filtered[:n_own]})
    if "normals" in entry:
        own["normals"] = entry["normals"]
    if not last:
        store.put(keys[i][:2] + (keys[i][2] + 1,), own)
    else:
        store.put(("fits", i), {"xyz": items["xyz"][:n_own], "gid": own["gid"],
                                "coef": fits.coef[:n_own], "filtered": fits.filtered[:n_own],
                                "rms": fits.rms[:n_own]})
    return (regions.boxes(fits.moved[:n_own]), int(fits.held[:n_own].sum()),
            float(fits.rms[:n_own].sum()), np.bincount(fits.degree[:n_own], minlength=7),
            times)


def _exchanged(runner, store, keys, boxes, own_given, first, plan, sigma_n, t, shift):
    """One iteration on the means in several tiles, a round a step
    (:func:`pssd_fast.method.iteration`): each tile lists its own means and computes their
    step, and the next round reads the results of its lists' members from the tiles that own
    them. A round's halo is one list bound, not one for each step the lists' members pass on
    (three or four); each mean's result is the one its own tile computes, so the whole
    cloud's. Returns what :func:`_iteration` returns, for each tile."""
    tiles = range(len(keys))
    stage = (t, plan.iterations)
    halo = [regions.widened(boxes[i], plan.bound) for i in tiles]
    times = runner.map("tile_lists", *stage, _lists_round, [
        (store, keys, boxes, i, halo[i], own_given, first, plan, shift) for i in tiles])
    step = [("normals", i) for i in tiles]
    if first and shift:
        times = _added(times, runner.map("tile_shift", *stage, _shift_round, [
            (store, keys, step, i, plan) for i in tiles]))
        _drop(store, step)
        step = [("shifted", i) for i in tiles]
    times = _added(times, runner.map("tile_filter", *stage, _filter_round, [
        (store, keys, step, i) for i in tiles]))
    _drop(store, step)
    step = [("filtered", i) for i in tiles]
    out = runner.map("tile_fit", *stage, _fit_round, [
        (store, keys, step, i, sigma_n, t == plan.iterations - 1) for i in tiles])
    _drop(store, step + [("lists", i) for i in tiles])
    totals = _added(times, [found[4] for found in out])
    return [(*found[:4], total) for found, total in zip(out, totals)]


def _added(times, more):
    """Each tile's stage ``times`` with those of another round added."""
    return [{**a, **{name: a.get(name, 0.0) + seconds for name, seconds in b.items()}}
            for a, b in zip(times, more)]


def _lists_round(store, keys, boxes, i, region, own_given, first, plan, shift, n_jobs):
    """The first round of :func:`_exchanged`: tile ``i``'s means' lists (``("lists", i)``)
    and PCA normals, with their lists' planes where they are shifted next
    (``("normals", i)``); its stage times."""
    items, picks = gather_halo(store, keys, i, boxes, region,
                               _iteration_names(own_given, first), "xyz")
    n_own = store.get(keys[i], ("gid",))["gid"].shape[0]
    clock = Clock(None, 0, 1)
    with threads(n_jobs):
        lists = method.listed(items["xyz"], plan.k, plan.bound, items["gid"], clock, n_own)
        nrm, planes = method.pca_step(items["xyz"], lists, _signs(items, own_given, first),
                                      first, shift, clock)
    store.put(("lists", i), {**lists._asdict(), "own": n_own, "picks": picks})
    entry = {"normals": nrm[:n_own]}
    if planes is not None:
        entry.update(centres=planes.centres[:n_own], variation=planes.variation[:n_own],
                     spread=planes.spread[:n_own])
    store.put(("normals", i), entry)
    return clock.times


def _shift_round(store, keys, step, i, plan, n_jobs):
    """The first iteration's shifted normals of tile ``i``'s means (``("shifted", i)``), from
    the planes of their lists' members; its stage times."""
    lists, n_own, picks = _own_lists(store, i)
    items = {**gather_again(store, keys, i, picks, ("xyz",)), **gather_again(
        store, step, i, picks, ("normals", "centres", "variation", "spread"))}
    planes = core.ListPlanes(items["centres"], items["normals"], items["variation"],
                             items["spread"])
    clock = Clock(None, 0, 1)
    with threads(n_jobs):
        nrm = method.shift_step(items["xyz"], items["normals"], lists, planes, plan.k, clock)
    store.put(("shifted", i), {"normals": nrm[:n_own]})
    return clock.times


def _filter_round(store, keys, step, i, n_jobs):
    """Tile ``i``'s means' filtered normals (``("filtered", i)``), from the normals of their
    lists' members; its stage times."""
    lists, n_own, picks = _own_lists(store, i)
    items = {**gather_again(store, keys, i, picks, ("xyz",)),
             **gather_again(store, step, i, picks, ("normals",))}
    clock = Clock(None, 0, 1)
    with threads(n_jobs):
        filtered = clock.run("filter", core.filter_normals, items["xyz"], items["normals"],
                             lists)
    store.put(("filtered", i), {"filtered": filtered[:n_own]})
    return clock.times


def _fit_round(store, keys, step, i, sigma_n, last, n_jobs):
    """The last round of :func:`_exchanged`: tile ``i``'s means fitted with the filtered
    normals of their lists' members and moved (:func:`_next_means`)."""
    lists, _, picks = _own_lists(store, i)
    items = gather_again(store, keys, i, picks, ("xyz", "mass", "gid"))
    filtered = gather_again(store, step, i, picks, ("filtered",))["filtered"]
    clock = Clock(None, 0, 1)
    with threads(n_jobs):
        fits = method.fit_step(items["xyz"], items["mass"], filtered, lists, sigma_n, clock)
    return _next_means(store, keys, i, items, fits, last, clock.times)


def _own_lists(store, i):
    """Tile ``i``'s lists of :func:`_exchanged`'s first round, its number of means and the
    rows of the other tiles' entries its halo took (:func:`pssd_fast.store.gather_halo`)."""
    entry = store.get(("lists", i))
    own, picks = entry.pop("own"), entry.pop("picks")
    return ListScales(**entry), own, picks


def _project(store, fits, boxes, i, region, plan, n_jobs):
    """A tile's task of the projection: its points moved onto the fits of their nearest means
    (where the last iteration started), their normals and held mask (``("placed", i)``), and
    its cells' input means with the sums of their points' squared steps (``("test", i)``)."""
    points = store.get(("points", i))
    means = gather(store, fits, i, boxes, region, ("xyz", "gid", "coef", "filtered"), "xyz")
    with threads(n_jobs):
        moved, normals, held = method.project(points["xyz"], means["xyz"], method.Fits(
            None, means["filtered"], means["coef"], None, None, None, None), plan.bound,
            means["gid"])
    step = moved - points["xyz"]
    store.put(("placed", i), {"xyz": moved, "normals": normals, "held": held,
                              "gid": points["gid"]})
    cells = store.get(("cells", i, 0), ("xyz", "mass", "gid"))
    local = points["cell"] - cells["gid"][0]
    sums = np.bincount(local, np.einsum("ij,ij->i", step, step), cells["gid"].shape[0])
    entry = {"xyz": cells["xyz"], "sums": sums, "mass": cells["mass"], "gid": cells["gid"]}
    if plan.own_noise:
        # Each point's own noise comes in the next round (_noise).
        store.put(("own", i), {"xyz": points["xyz"], "hints": normals, "gid": points["gid"]})
    store.put(("test", i), entry)


def _noise(store, keys, boxes, i, region, plan, sigma_n, n_jobs):
    """A tile's task of the points' own noise (:func:`pssd_fast.method.own_noise` on its
    points and their halo, at their input positions): the sums over each of its cells of its
    points' noise variances and of what their own fits leave of them, added to its
    ``("test", i)`` entry."""
    items = gather(store, keys, i, boxes, region, ("xyz", "hints", "gid"), "xyz")
    n_own = store.get(keys[i], ("gid",))["gid"].shape[0]
    clock = Clock(None, 0, 1)
    with threads(n_jobs):
        noise2, spread2 = clock.run("own_noise", method.own_noise, items["xyz"],
                                    items["hints"], plan.refine.k, plan.refine.bound, sigma_n,
                                    items["gid"])
    cell = store.get(("points", i), ("cell",))["cell"]
    entry = store.get(("test", i))
    local, m = cell - entry["gid"][0], entry["gid"].shape[0]
    entry.update(noise=np.bincount(local, noise2[:n_own], m),
                 spread=np.bincount(local, spread2[:n_own], m))
    store.put(("test", i), entry)
    return clock.times


def _test(store, keys, boxes, i, region, plan, n_jobs):
    """A tile's task of the test (:func:`pssd_fast.method.failing`): its points' flags
    (``("flags", i)``), from their cells'; the number flagged."""
    names = ("xyz", "sums", "mass", "gid") + (("noise", "spread") if plan.own_noise else ())
    cells = gather(store, keys, i, boxes, region, names, "xyz")
    n_own = store.get(keys[i], ("gid",))["gid"].shape[0]
    with threads(n_jobs):
        fails = method.failing(cells["xyz"], cells["sums"], cells["mass"], plan.noise.sigma,
                               plan.bound, cells["gid"], (cells["noise"], cells["spread"])
                               if plan.own_noise else None, n_own)[:n_own]
    points = store.get(("points", i), ("cell",))
    flagged = fails[points["cell"] - cells["gid"][0]]
    store.put(("flags", i), {"flagged": flagged})
    return int(flagged.sum())


def _refine(plan, tiles, store, runner, sigma_n, keep, whole, given, shift, clock):
    """The failing points' own iterations, tile by tile (``("refine", i, t)`` entries; the
    last becomes ``("out", i)``), their stages timed on ``clock``."""
    bound = plan.refine.bound
    # Tasks, as every step that reads a tile's points: the calling process holds none.
    found = runner.map("tile_out", plan.iterations - 1, plan.iterations, _refine_entry,
                       [(store, i, given) for i in range(len(tiles))])
    _drop(store, [("flags", i) for i in range(len(tiles))])
    iterations = plan.refine.iterations
    for t in range(iterations):
        use_given = given and (t == 0 or keep)
        width = (3 if use_given or t > 0 or not shift else 4) * bound
        keys = [("refine", i, t) for i in range(len(tiles))]
        # A tile's halo: what its failing points' chain of steps reads, around those points.
        boxes = [everyone for everyone, _ in found]
        # Reported in the run's last iteration, as the rest of the refinement.
        out = runner.map("tile_refine", plan.iterations - 1, plan.iterations, _refine_task, [
            (store, keys, boxes, i, None if whole else regions.widened(found[i][1], width),
             width, use_given, t == 0, plan, sigma_n, shift) for i in range(len(tiles))])
        _tally(clock, [o[1] for o in out])
        _drop(store, keys)
        found = [o[0] for o in out]
    runner.map("tile_out", plan.iterations - 1, plan.iterations, _refined,
               [(store, i, iterations) for i in range(len(tiles))])


def _placed_out(store, i, n_jobs):
    """Tile ``i``'s points as placed: its output, where no point failed the test (a task)."""
    store.put(("out", i), store.get(("placed", i)))


def _refine_entry(store, i, given, n_jobs):
    """Tile ``i``'s first refining entry: its points as placed, the failing ones back at their
    input positions (a task); the boxes of those positions (:func:`_refine_boxes`)."""
    placed = store.get(("placed", i))
    points = store.get(("points", i), ("xyz",) + (("given",) if given else ()))
    flagged = store.get(("flags", i))["flagged"]
    xyz = placed["xyz"].copy()
    xyz[flagged] = points["xyz"][flagged]
    entry = {"xyz": xyz, "normals": placed["normals"], "flagged": flagged,
             "gid": placed["gid"], "held": placed["held"]}
    if given:
        entry["given"] = points["given"]
    store.put(("refine", i, 0), entry)
    return _refine_boxes(xyz, flagged)


def _refine_boxes(xyz, flagged):
    """The boxes of a tile's points (what another tile's halo may meet) and of its failing
    points (what its own halo is around; none where none fails)."""
    return regions.boxes(xyz), (regions.boxes(xyz[flagged]) if flagged.any()
                                else np.empty((0, 2, 3)))


def _refined(store, i, last, n_jobs):
    """Tile ``i``'s output from its last refining entry ``last`` (a task)."""
    entry = store.get(("refine", i, last))
    store.put(("out", i), {"xyz": entry["xyz"], "normals": entry["normals"],
                           "held": entry["held"], "gid": entry["gid"]})
    store.drop(("refine", i, last))


def _refine_task(store, keys, boxes, i, region, width, use_given, first, plan, sigma_n,
                 shift, n_jobs):
    """A tile's task of one refining iteration (:func:`pssd_fast.method.refine_step`) over its
    points and the others' within ``width`` of its failing ones (in the boxes ``region``): its
    own points' next entry; the boxes of their positions (:func:`_refine_boxes`) and the stage
    times."""
    names = ("xyz", "normals", "flagged", "gid") + (("given",) if use_given else ())
    entry = store.get(keys[i])
    # The halo: the points within the chain of steps' reach of the tile's failing points.
    items = gather(store, keys, i, boxes, region, names, "xyz", None if region is None else (
        entry["xyz"][entry["flagged"]], width))
    n_own = entry["gid"].shape[0]
    k, bound = plan.refine.k, plan.refine.bound
    clock = Clock(None, 0, 1)
    # Only the failing points and those within a list's bound of one: the others are in no
    # list and have none, so they change nothing; a step's cost follows the points that fail.
    if entry["flagged"].any():
        rows = np.flatnonzero(regions.near(items["xyz"], items["xyz"][items["flagged"]],
                                           bound))
        at = {name: items[name][rows] for name in names}
        with threads(n_jobs):
            out, normals, held = method.refine_step(
                at["xyz"], at["normals"], at["flagged"], k, bound, sigma_n,
                at["given"] if use_given else None, clock, first, at["gid"], shift)
        own = rows < n_own  # the rows are sorted: the own ones come first
        xyz, nrm = entry["xyz"].copy(), entry["normals"].copy()
        xyz[rows[own]], nrm[rows[own]] = out[own], normals[own]
        held_own = entry["held"].copy()
        held_own[rows[own]] |= held[own]
        entry.update(xyz=xyz, normals=nrm, held=held_own)
    store.put(keys[i][:2] + (keys[i][2] + 1,), entry)
    return _refine_boxes(entry["xyz"], entry["flagged"]), clock.times


def collect(store, tiles, n, names=("xyz", "normals", "held", "likelihood", "feature")):
    """The tiles' final outputs (``("out", i)``) in the order of the points (their ``gid``):
    ``xyz``, ``normals``, ``held`` and, where computed, ``likelihood`` and ``feature``."""
    out = {}
    for i in range(len(tiles)):
        entry = store.get(("out", i))
        for name in names:
            if name not in entry:
                continue
            if name not in out:
                out[name] = np.empty((n,) + entry[name].shape[1:], entry[name].dtype)
            out[name][entry["gid"]] = entry[name]
    return out


def extras(store, tiles, fits, plan):
    """The likelihood and feature intensity of each tile's points (those of their cell's
    mean: :func:`means_likelihood`, :func:`means_feature`), added to its ``("out", i)``."""
    origins, rms, filtered, cells = extras_inputs(store, tiles, fits)
    lik, feat = means_likelihood(rms), means_feature(origins, filtered, plan)
    for i in range(len(tiles)):
        entry = store.get(("out", i))
        entry.update(likelihood=lik[cells[i]], feature=feat[cells[i]])
        store.put(("out", i), entry)


def extras_inputs(store, tiles, fits):
    """What the likelihood and the feature intensity are computed from: the whole cloud's
    means where the last iteration started, their last fits' RMS residuals and filtered
    normals, and each tile's points' cells (one array per tile, in the tile's order). Over the
    whole cloud's means at once: the voting's mean spacing and the likelihood's mean residual
    are the whole cloud's."""
    entries = [store.get(key, ("xyz", "rms", "filtered")) for key in fits]
    origins, rms, filtered = (np.concatenate([e[name] for e in entries])
                              for name in ("xyz", "rms", "filtered"))
    cells = [store.get(("points", i), ("cell",))["cell"] for i in range(len(tiles))]
    return origins, rms, filtered, cells


def means_likelihood(rms):
    """The cell means' likelihood: from their last fits' RMS residual, the ``"exp"`` form."""
    return core.sampling_likelihood(rms, "exp")[0]


def means_feature(origins, filtered, plan):
    """The cell means' feature intensity: the paper's voting at the paper's constants over the
    means where the last iteration started, with their filtered normals."""
    lists = bounded_graph(origins, plan.k, plan.bound)
    return aware.voted_feature(origins, filtered, lists,
                               aware.region_radius(core.mean_spacing(lists)))


def deferred_extras(store, tiles, fits, plan, n):
    """Two functions that give, when called, the likelihood and the feature intensity of the
    ``n`` points (in their order), the values :func:`extras` gives them; until then only what
    they are computed from is held (:func:`extras_inputs`)."""
    origins, rms, filtered, tile_cells = extras_inputs(store, tiles, fits)
    cells = np.empty(n, np.int64)
    for i, own in enumerate(tile_cells):
        cells[store.get(("out", i), ("gid",))["gid"]] = own
    return (lambda: means_likelihood(rms)[cells],
            lambda: means_feature(origins, filtered, plan)[cells])


def orient(store, tiles, how, centre, whole):
    """Each tile's output normals turned ``how`` (``"outward"``, ``"up"`` or a viewpoint,
    given absolute): in one tile made consistent over the points' lists of
    :data:`pssd_fast.core.ORIENT_NEIGHBOURS` first and each connected component turned as a
    whole; in tiles each normal on its own (outward: away from the cloud's centre), as the
    propagation runs over the whole cloud."""
    target = how if isinstance(how, str) else how - centre
    for i in range(len(tiles)):
        entry = store.get(("out", i))
        points, normals = entry["xyz"], entry["normals"].copy()
        if whole:
            lists = knn_graph(points, min(core.ORIENT_NEIGHBOURS, points.shape[0] - 1), False)
            core.orient_normals(points, normals, lists, target)
        else:
            core.orient_pointwise(points, normals, target, np.zeros(3))
        entry["normals"] = normals
        store.put(("out", i), entry)
