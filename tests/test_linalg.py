"""The 3x3 symmetric eigensolver, the orthonormal frame, the normal equations and the prefix
Cholesky."""
import numpy as np
import pytest

from pssd_fast.kernels.linalg import (
    cholesky_prefix, cholesky_solve, normal_equations, orthonormal_basis, sym3_eigh,
)


def _eig(a):
    w = np.empty(3)
    v = np.empty((3, 3))
    sym3_eigh(a.copy(), w, v)
    return w, v


def _random_sym(rng, scale=1.0):
    x = rng.normal(size=(3, 3)) * scale
    return x + x.T


def _cases():
    rng = np.random.default_rng(0)
    cases = [_random_sym(rng) for _ in range(200)]
    cases += [_random_sym(rng, s) for s in (1e-150, 1e-8, 1e8, 1e150)]
    u = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    for spectrum in ([0, 0, 1], [0, 1, 1], [2, 2, 2], [1, 1e-14, 0], [-1, 0, 1], [5, 5, 1e-9]):
        cases.append(u @ np.diag(spectrum) @ u.T)
    cases.append(np.diag([3.0, 1.0, 2.0]))
    return cases


@pytest.mark.parametrize("a", _cases())
def test_sym3_eigh_matches_numpy(a):
    w, v = _eig(a)
    ref_w, _ = np.linalg.eigh(a)
    scale = np.abs(a).max()
    assert np.all(np.diff(w) >= 0)
    np.testing.assert_allclose(w, ref_w, atol=1e-13 * scale, rtol=0)
    np.testing.assert_allclose(v.T @ v, np.eye(3), atol=1e-13)
    # A V = V diag(w): eigenvectors are right even where eigenvalues repeat.
    np.testing.assert_allclose(a @ v, v * w, atol=1e-12 * scale)


def test_sym3_eigh_zero_and_nonfinite():
    for a in (np.zeros((3, 3)), np.full((3, 3), np.nan)):
        w, v = _eig(a)
        np.testing.assert_array_equal(w, 0.0)
        np.testing.assert_array_equal(v, np.eye(3))


@pytest.mark.parametrize("n", [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0.6, 0, -0.8],
                               [1e-20, 1, 0], [0.36, 0.48, 0.8]])
def test_orthonormal_basis(n):
    n = np.asarray(n, float) / np.linalg.norm(n)
    ux, uy, uz, vx, vy, vz = orthonormal_basis(*n)
    frame = np.array([[ux, uy, uz], [vx, vy, vz], n])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(frame) == pytest.approx(1.0)


@pytest.mark.parametrize("m", [1, 3, 6, 10])
def test_normal_equations_sum_each_entry_in_neighbour_order(m):
    # Plain loops, one sum after another: the quadratic's unrolled sums (and the others)
    # must give these bits, which magnitudes from 1e-12 to 1e12 make depend on the order.
    rng = np.random.default_rng(m)
    for count in (0, 1, 7, 154):
        phi = rng.normal(size=(10, 160)) * 10.0 ** rng.integers(-12, 13, size=(10, 160))
        wts = rng.random(160)
        wts[::5] = 0.0
        zs = rng.normal(size=160) * 10.0 ** rng.integers(-12, 13, size=160)
        a = np.full((10, 10), np.nan)
        b = np.full(10, np.nan)
        normal_equations(phi, wts, zs, count, m, a, b)
        for p in range(m):
            s = 0.0
            for t in range(count):
                s += wts[t] * phi[p, t] * zs[t]
            assert b[p] == s
            for q in range(p + 1):
                s = 0.0
                for t in range(count):
                    s += wts[t] * phi[p, t] * phi[q, t]
                assert a[p, q] == s
        assert np.isnan(b[m:]).all() and np.isnan(a[:m][np.triu_indices(m, 1)]).all()


def test_cholesky_solves_spd_systems():
    rng = np.random.default_rng(1)
    for m in (1, 3, 6, 10):
        x = rng.normal(size=(30, m))
        a = x.T @ x
        b = rng.normal(size=m)
        work = a.copy()
        assert cholesky_prefix(work, m, 1e-9) == m
        sol = b.copy()
        cholesky_solve(work, sol, m)
        np.testing.assert_allclose(sol, np.linalg.solve(a, b), rtol=1e-9)


def test_cholesky_prefix_stops_at_first_dependent_column():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(40, 10))
    x[:, 7] = x[:, 2] - 3 * x[:, 5]  # column 7 repeats earlier ones
    work = x.T @ x
    assert cholesky_prefix(work, 10, 1e-9) == 7
    # The factor of the leading block is intact: it solves the 6x6 leading system.
    a6 = (x.T @ x)[:6, :6]
    b = rng.normal(size=6)
    sol = b.copy()
    cholesky_solve(work, sol, 6)
    np.testing.assert_allclose(sol, np.linalg.solve(a6, b), rtol=1e-9)
    zero = np.zeros((10, 10))
    assert cholesky_prefix(zero, 10, 1e-9) == 0
