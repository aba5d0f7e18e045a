"""pssd_fast shortens libgomp's idle spin, which its two OpenMP thread pools (pykdtree's and
numba's) would otherwise spend on each other's cores, unless the caller chose a wait policy."""
import os
import subprocess
import sys

import pytest

PRINT = ("import os, pssd_fast; "
         "print(os.environ.get('GOMP_SPINCOUNT'), os.environ.get('OMP_WAIT_POLICY'))")


def _after_import(**env):
    clean = {k: v for k, v in os.environ.items()
             if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    done = subprocess.run([sys.executable, "-c", PRINT], env={**clean, **env},
                          capture_output=True, text=True, check=True)
    return done.stdout.split()


@pytest.mark.parametrize("env, expected", [
    ({}, ["10000", "None"]),
    ({"GOMP_SPINCOUNT": "5"}, ["5", "None"]),
    ({"OMP_WAIT_POLICY": "ACTIVE"}, ["None", "ACTIVE"]),
])
def test_the_spin_is_short_unless_the_caller_chose(env, expected):
    assert _after_import(**env) == expected
