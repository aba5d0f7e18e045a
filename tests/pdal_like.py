"""What PDAL does with a ``filters.python`` stage, for the tests (PDAL is not installed): its
Python plugin's ``plang/Invocation.cpp`` step by step, and a small classified survey with the
dimensions and types PDAL's LAS reader gives."""
import inspect
import json
import sys
import types
from pathlib import Path

import numpy as np

#: PDAL's LAS dimensions of point format 3 and their types, with laspy's names for them.
DIMENSIONS = {"X": ("x", np.float64), "Y": ("y", np.float64), "Z": ("z", np.float64),
              "Intensity": ("intensity", np.uint16), "ReturnNumber": ("return_number", np.uint8),
              "NumberOfReturns": ("number_of_returns", np.uint8),
              "ScanDirectionFlag": ("scan_direction_flag", np.uint8),
              "EdgeOfFlightLine": ("edge_of_flight_line", np.uint8),
              "Classification": ("classification", np.uint8),
              "ScanAngleRank": ("scan_angle_rank", np.float32),
              "UserData": ("user_data", np.uint8), "PointSourceId": ("point_source_id", np.uint16),
              "GpsTime": ("gps_time", np.float64), "Red": ("red", np.uint16),
              "Green": ("green", np.uint16), "Blue": ("blue", np.uint16)}
#: Where the survey lies: UTM-like offsets, as real files have them.
OFFSET = np.array([637_000.0, 850_000.0, 100.0])
#: The survey file's scale, on every axis.
SCALE = 0.001


def survey(seed=0):
    """A small classified airborne survey as PDAL's dimensions: a gently sloping ground with
    noise (class 2, 2,000 points), a flat roof 8 m above it (class 6, 500), vegetation (class 5,
    400) and unclassified returns (class 1, 150); 5 cm noise on the surfaces."""
    rng = np.random.default_rng(seed)
    parts = []
    ground = rng.uniform(0, 60, (2000, 2))
    parts.append((ground, 0.02 * ground[:, 0] + 0.3 * np.sin(ground[:, 1] / 8), 2))
    roof = rng.uniform(20, 35, (500, 2))
    parts.append((roof, np.full(500, 8.0 + 0.02 * 27.5), 6))
    trees = rng.uniform([40, 0], [60, 20], (400, 2))
    parts.append((trees, rng.uniform(1, 10, 400), 5))
    loose = rng.uniform(0, 60, (150, 2))
    parts.append((loose, rng.uniform(0, 20, 150), 1))
    xy = np.concatenate([p[0] for p in parts])
    z = np.concatenate([p[1] for p in parts])
    z[:2500] += rng.normal(0, 0.05, 2500)
    xyz = np.column_stack([xy, z]) + OFFSET
    n = xyz.shape[0]
    labels = np.concatenate([np.full(p[0].shape[0], p[2]) for p in parts])
    values = {"X": xyz[:, 0], "Y": xyz[:, 1], "Z": xyz[:, 2], "Classification": labels,
              "Intensity": rng.integers(0, 4000, n), "ReturnNumber": np.ones(n),
              "NumberOfReturns": np.ones(n), "ScanAngleRank": rng.integers(-20, 20, n),
              "PointSourceId": np.full(n, 7), "GpsTime": np.sort(rng.uniform(0, 100, n)),
              "Red": rng.integers(0, 65535, n), "Green": rng.integers(0, 65535, n),
              "Blue": rng.integers(0, 65535, n)}
    # Coordinates on the 1 mm grid of the file the survey is written to, as PDAL reads them
    # (the stored integer times the scale, plus the offset).
    for axis, offset in zip("XYZ", OFFSET):
        values[axis] = np.round((values[axis] - offset) / SCALE) * SCALE + offset
    return {name: np.asarray(values.get(name, np.zeros(n)), kind)
            for name, (_, kind) in DIMENSIONS.items()}


def write_las(path, dims):
    """Write PDAL-named dimensions to a LAS/LAZ file of point format 3 (needs laspy)."""
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.full(3, SCALE)
    header.offsets = OFFSET
    las = laspy.LasData(header)
    for name, (field, _) in DIMENSIONS.items():
        setattr(las, field, dims[name])
    las.write(str(path))


def read_las(path):
    """The dimensions of a LAS/LAZ file as PDAL's ``readers.las`` gives them (needs laspy)."""
    import laspy

    las = laspy.read(str(path))
    return {name: np.asarray(getattr(las, field), kind)
            for name, (field, kind) in DIMENSIONS.items()}


def run_stage(stage, dims):
    """Run a ``filters.python`` stage (a dict of its options) on one view, ``dims`` (name to
    1-D array), as PDAL's plugin does; return the view's dimensions afterwards."""
    # PythonFilter::ready: the source, or the text of the script file.
    source = stage.get("source") or Path(stage["script"]).read_text()
    # Invocation::compile: Py_CompileString under the module's name, PyImport_ExecCodeModule.
    code = compile(source, stage["module"], "exec")
    module = types.ModuleType(stage["module"])
    sys.modules[stage["module"]] = module
    try:
        exec(code, module.__dict__)
        function = module.__dict__[stage["function"]]
        # Invocation::execute: at most two arguments, ins and outs.
        if len(inspect.getfullargspec(function).args) > 2:
            raise RuntimeError("Only two arguments -- ins and outs numpy arrays -- can be passed!")
        # prepareData: a fresh C array per dimension; the module globals. The pdalargs option
        # is JSON (an object, or its text), handed over as json.loads(dump(1)); null unset.
        ins = {name: np.array(values, order="C") for name, values in dims.items()}
        given = stage.get("pdalargs")
        value = json.loads(given) if isinstance(given, str) else given
        module.pdalargs = json.loads(json.dumps(value, indent=1), strict=False)
        outs = {}
        result = function(ins, outs)
    finally:
        del sys.modules[stage["module"]]
    if not isinstance(result, bool):
        raise RuntimeError("User function return value not boolean.")
    if not result:
        raise RuntimeError("the function returned False")
    return _extract(dims, outs)


def _extract(dims, outs):
    """Invocation::extractData: each array of ``outs`` into the dimension of its name, checked
    as PDAL checks it."""
    unknown = sorted(set(outs) - set(dims))
    if unknown:
        raise RuntimeError(f"Can't set numpy array {unknown[0]!r} as output. Dimension not "
                           f"registered.")
    view = {name: values.copy() for name, values in dims.items()}
    for name, array in outs.items():
        if not isinstance(array, np.ndarray):
            raise RuntimeError(f"Plang output variable {name!r} is not a numpy array")
        target = view[name]
        if array.dtype.itemsize != target.dtype.itemsize:
            raise RuntimeError(f"dtype of array has size {array.dtype.itemsize} but PDAL "
                               f"dimension {name!r} has byte size of {target.dtype.itemsize}")
        if array.dtype.kind != target.dtype.kind:
            raise RuntimeError(f"dtype of array {name!r} is {array.dtype}, the dimension's "
                               f"type {target.dtype}")
        flat = array.reshape(-1)
        target[:flat.shape[0]] = flat
    return view
