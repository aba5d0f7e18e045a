"""benchmarks/noise_probe.py: the probe's calibration measured again, in the table's form."""
import ast
import math

import numpy as np
import pytest

from benchmarks import noise_probe
from pssd_fast import noise

pytestmark = pytest.mark.tooling


def test_the_calibration_command_prints_the_library_s_table(capsys):
    """A small plane (20,000 points, 3 noise levels) reads within 6% of CALIBRATION, and the
    printed table parses as one of the same form."""
    rows = noise_probe.measure(20_000, (0.009, 2.0, 3), seed=1)
    for values in noise_probe.against_library(rows).values():
        assert all(abs(v - 1) < 0.06 for v in values), values
    assert noise_probe.main(["--calibrate", "--points", "20000"]) == 0
    out = capsys.readouterr().out
    table = ast.literal_eval(out[out.index("{"):out.index("}") + 1])
    assert sorted(table) == sorted(noise.CALIBRATION)
    assert all(len(rows) == noise_probe.LEVELS[2] for rows in table.values())


def test_the_own_calibration_command_prints_the_library_s_table(capsys):
    """The own fits' table measured on smaller planes (30,000 points, 3 noise levels, more
    of their points near a border) reads within 10% of OWN_CALIBRATION, and ``--own`` prints
    a table of its form."""
    rows = noise_probe.measure_own(30_000, (0.6, 1.8, 3.0), seed=1)
    xs, fs = (np.log(np.array(column)) for column in zip(*noise.OWN_CALIBRATION))
    for x, read in rows:
        assert abs(read / math.exp(np.interp(math.log(x), xs, fs)) - 1) < 0.1, (x, read)
    assert noise_probe.main(["--own", "--points", "20000"]) == 0
    out = capsys.readouterr().out
    table = ast.literal_eval(out[out.index("("):out.index("\n")])
    assert len(table) == len(noise_probe.OWN_RATIOS)
    assert [x for x, _ in table] == sorted(x for x, _ in table)
