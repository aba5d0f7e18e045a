"""Column names of text files: the names other tools write, mapped to the names pssd_fast uses."""
import re

import numpy as np

# Lower-case spellings -> canonical name. Covers CloudCompare (``//X Y Z R G B``, ``Nx``,
# ``scalar_Intensity``), MeshLab, PDAL and PTS exports.
_ALIASES = {
    **{c: c for c in ("x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha",
                      "intensity", "classification", "gps_time", "return_number",
                      "number_of_returns", "point_source_id", "user_data", "scan_angle",
                      "scan_angle_rank", "likelihood", "feature_intensity", "displacement",
                      "curvature")},
    **{f"{p}{c}": f"n{c}" for c in "xyz" for p in ("normal_", "normal", "n_", "normals_")},
    "r": "red", "g": "green", "b": "blue", "a": "alpha",
    "i": "intensity", "inten": "intensity", "reflectance": "intensity",
    "gpstime": "gps_time",
}
COLOURS = ("red", "green", "blue", "alpha")
#: A unit after a name: ``x [m]``, ``Z (ft)``, ``intensity[dB]``.
_UNIT = re.compile(r"\s*[\[(][^\])]*[\])]$")


def canonical(name):
    """The pssd_fast name of a column called ``name`` (case-insensitive aliases, a
    ``scalar_`` prefix and a unit in brackets, ``x [m]`` or ``Z (ft)``, dropped around known
    names); other names are kept, spaces as ``_``."""
    key = name.strip().lower()
    bare = _UNIT.sub("", key)
    if bare != key and bare in _ALIASES:
        key = bare
    if key.startswith("scalar_") and key[7:] in _ALIASES:
        key = key[7:]
    return _ALIASES.get(key, "_".join(name.split()))


def integer_type(name, values):
    """The integer dtype for whole-number ``values`` of column ``name``: colours as uint8 (or
    uint16 for 16-bit colours), other columns as int32 unless they need int64."""
    lo, hi = (values.min(), values.max()) if len(values) else (0, 0)
    if name in COLOURS and lo >= 0 and hi <= 65535:
        return np.dtype(np.uint8 if hi <= 255 else np.uint16)
    info = np.iinfo(np.int32)
    return np.dtype(np.int32 if info.min <= lo and hi <= info.max else np.int64)
