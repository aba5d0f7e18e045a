"""Small dense linear algebra for the per-point loops: no allocation, no LAPACK."""
import math

import numpy as np

from .config import helper

# Relative size below which the second-largest eigenvalue of a 3x3 covariance counts as zero:
# the points are collinear or coincident and no plane normal is defined.
DEGENERATE_RATIO = 1e-12


@helper
def set_sym3(a, a00, a01, a02, a11, a12, a22):
    """Fill the 3x3 array ``a`` with the symmetric matrix of the six given entries."""
    a[0, 0] = a00
    a[0, 1] = a01
    a[0, 2] = a02
    a[1, 0] = a01
    a[1, 1] = a11
    a[1, 2] = a12
    a[2, 0] = a02
    a[2, 1] = a12
    a[2, 2] = a22


@helper
def sym3_eigh(a, w, v):
    """Eigen-decompose a symmetric 3x3 matrix by cyclic Jacobi rotations.

    Parameters
    ----------
    a : (3, 3) float64
        Symmetric input; overwritten (scratch).
    w : (3,) float64
        Output eigenvalues in ascending order.
    v : (3, 3) float64
        Output eigenvectors, column ``v[:, k]`` belongs to ``w[k]``.

    Notes
    -----
    The matrix is scaled by its largest absolute entry first, so the stopping test is relative
    and no intermediate overflows. Jacobi is accurate for repeated or tiny eigenvalues, where
    closed-form (trigonometric) solvers lose the eigenvectors. A zero or non-finite matrix gives
    zero eigenvalues and the identity.
    """
    scale = 0.0
    for p in range(3):
        for q in range(3):
            scale = max(scale, abs(a[p, q]))
    for p in range(3):
        for q in range(3):
            v[p, q] = 1.0 if p == q else 0.0
    if not (scale > 0.0 and scale < np.inf):
        w[0] = 0.0
        w[1] = 0.0
        w[2] = 0.0
        return
    for p in range(3):
        for q in range(3):
            a[p, q] /= scale
    for _sweep in range(32):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        if off < 1e-40:
            break
        for pair in range(3):
            p = 0 if pair < 2 else 1
            q = 1 if pair == 0 else 2
            r = 3 - p - q
            apq = a[p, q]
            if abs(apq) < 1e-300:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * apq)
            if abs(theta) > 1e150:
                t = 0.5 / theta
            else:
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            a[p, p] -= t * apq
            a[q, q] += t * apq
            a[p, q] = 0.0
            a[q, p] = 0.0
            arp = a[r, p]
            arq = a[r, q]
            a[r, p] = c * arp - s * arq
            a[p, r] = a[r, p]
            a[r, q] = s * arp + c * arq
            a[q, r] = a[r, q]
            for k in range(3):
                vkp = v[k, p]
                vkq = v[k, q]
                v[k, p] = c * vkp - s * vkq
                v[k, q] = s * vkp + c * vkq
    for k in range(3):
        w[k] = a[k, k]
    # Sort ascending (three elements: insertion by swaps), moving eigenvector columns along.
    for p in range(2):
        for q in range(2 - p):
            if w[q] > w[q + 1]:
                tmp = w[q]
                w[q] = w[q + 1]
                w[q + 1] = tmp
                for k in range(3):
                    tmp = v[k, q]
                    v[k, q] = v[k, q + 1]
                    v[k, q + 1] = tmp
    for k in range(3):
        w[k] *= scale


@helper
def store_unit(out, row, x, y, z, fx, fy, fz):
    """Write ``(x, y, z)`` scaled to unit length into ``out[row]``, or ``(fx, fy, fz)`` where it
    has no length (a sum of normals that cancelled)."""
    norm = math.sqrt(x * x + y * y + z * z)
    if norm > 0.0:
        out[row, 0] = x / norm
        out[row, 1] = y / norm
        out[row, 2] = z / norm
    else:
        out[row, 0] = fx
        out[row, 1] = fy
        out[row, 2] = fz


@helper
def orthonormal_basis(nx, ny, nz):
    """Return two unit vectors ``u, v`` completing the unit vector ``n`` to a right-handed frame.

    Branchless construction of Duff et al. (2017), continuous except across ``nz = 0``.
    """
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (
        1.0 + sign * nx * nx * a, sign * b, -sign * nx,
        b, sign + ny * ny * a, -ny,
    )


@helper
def normal_equations(phi, wts, zs, count, m, a, b):
    """Lower triangle of ``A = Phi W Phi^T`` and ``b = Phi W z`` for the first ``m`` monomials
    (rows of ``phi``, one column per neighbour), as dot products over the neighbours, each
    summed in neighbour order."""
    if m == 6:
        _quadratic_sums(phi, wts, zs, count, a, b)
        return
    for p in range(m):
        s = 0.0
        for t in range(count):
            s += wts[t] * phi[p, t] * zs[t]
        b[p] = s
        for q in range(p + 1):
            s = 0.0
            for t in range(count):
                s += wts[t] * phi[p, t] * phi[q, t]
            a[p, q] = s


@helper
def _quadratic_sums(phi, wts, zs, count, a, b):
    """:func:`normal_equations` of the quadratic: its 27 sums side by side in one pass over the
    neighbours, each still in neighbour order (the same bits), so that they do not wait on
    each other's additions (twice as fast as one sum after another)."""
    b0 = b1 = b2 = b3 = b4 = b5 = 0.0
    a00 = a10 = a11 = a20 = a21 = a22 = 0.0
    a30 = a31 = a32 = a33 = a40 = a41 = a42 = a43 = a44 = 0.0
    a50 = a51 = a52 = a53 = a54 = a55 = 0.0
    for t in range(count):
        wt = wts[t]
        z = zs[t]
        f0, f1, f2, f3, f4, f5 = phi[0, t], phi[1, t], phi[2, t], phi[3, t], phi[4, t], phi[5, t]
        w0, w1, w2, w3, w4, w5 = wt * f0, wt * f1, wt * f2, wt * f3, wt * f4, wt * f5
        b0 += w0 * z
        b1 += w1 * z
        b2 += w2 * z
        b3 += w3 * z
        b4 += w4 * z
        b5 += w5 * z
        a00 += w0 * f0
        a10 += w1 * f0
        a11 += w1 * f1
        a20 += w2 * f0
        a21 += w2 * f1
        a22 += w2 * f2
        a30 += w3 * f0
        a31 += w3 * f1
        a32 += w3 * f2
        a33 += w3 * f3
        a40 += w4 * f0
        a41 += w4 * f1
        a42 += w4 * f2
        a43 += w4 * f3
        a44 += w4 * f4
        a50 += w5 * f0
        a51 += w5 * f1
        a52 += w5 * f2
        a53 += w5 * f3
        a54 += w5 * f4
        a55 += w5 * f5
    b[0], b[1], b[2], b[3], b[4], b[5] = b0, b1, b2, b3, b4, b5
    a[0, 0] = a00
    a[1, 0], a[1, 1] = a10, a11
    a[2, 0], a[2, 1], a[2, 2] = a20, a21, a22
    a[3, 0], a[3, 1], a[3, 2], a[3, 3] = a30, a31, a32, a33
    a[4, 0], a[4, 1], a[4, 2], a[4, 3], a[4, 4] = a40, a41, a42, a43, a44
    a[5, 0], a[5, 1], a[5, 2], a[5, 3], a[5, 4], a[5, 5] = a50, a51, a52, a53, a54, a55


@helper
def cholesky_prefix(a, m, tol):
    """Factor the leading block of a symmetric positive semi-definite matrix, as far as it goes.

    Parameters
    ----------
    a : (m, m) float64 or larger
        Lower triangle holds the matrix; overwritten by the Cholesky factor ``L``.
    m : int
        Size of the block to factor.
    tol : float
        A pivot fails when the remaining variance of its column is at most ``tol`` times the
        column's own diagonal entry (the column is numerically a combination of the earlier ones).

    Returns
    -------
    int
        The number ``p`` of leading pivots that succeeded: ``L[:p, :p]`` is the factor of the
        leading ``p x p`` block, because Cholesky factors of leading blocks are leading blocks of
        the factor.
    """
    for k in range(m):
        d = a[k, k]
        for j in range(k):
            d -= a[k, j] * a[k, j]
        if not (d > tol * a[k, k]):
            return k
        d = math.sqrt(d)
        a[k, k] = d
        for i in range(k + 1, m):
            s = a[i, k]
            for j in range(k):
                s -= a[i, j] * a[k, j]
            a[i, k] = s / d
    return m


@helper
def cholesky_solve(lower, b, m):
    """Solve ``L L^T x = b`` in place of ``b[:m]`` with the factor from :func:`cholesky_prefix`."""
    for i in range(m):
        s = b[i]
        for j in range(i):
            s -= lower[i, j] * b[j]
        b[i] = s / lower[i, i]
    for i in range(m - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, m):
            s -= lower[j, i] * b[j]
        b[i] = s / lower[i, i]
