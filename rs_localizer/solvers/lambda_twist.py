"""Lambda Twist P3P (Persson and Nordberg, ECCV 2018) as numba kernels.

Written from the paper ("Lambda Twist: An Accurate Fast Robust Perspective Three Point (P3P)
Solver"), section numbers below refer to it. Given unit bearings ``y_i`` and world points
``x_i`` (i = 1..3), the depths ``Lambda = (l1, l2, l3)`` satisfy (eq. 4)::

    Lambda^T M12 Lambda = a12,  Lambda^T M13 Lambda = a13,  Lambda^T M23 Lambda = a23

with ``a_ij = |x_i - x_j|^2``, ``b_ij = y_i . y_j`` and ``Lambda^T M_ij Lambda = l_i^2 + l_j^2 -
2 b_ij l_i l_j``. Eliminating the right-hand sides gives two homogeneous conics (sec. 3.2)::

    D1 = a23 M12 - a12 M23,   D2 = a23 M13 - a13 M23,   Lambda^T D1 Lambda = Lambda^T D2 Lambda = 0

A real root gamma of the cubic ``det(D1 + gamma D2) = 0`` (sec. 3.3) makes ``D0 = D1 + gamma
D2`` a degenerate conic: a pair of lines through the origin. Its eigen-decomposition with the
known zero eigenvalue (sec. 3.4) ``D0 = sigma1 e1 e1^T + sigma2 e2 e2^T`` gives the lines
``(e1 +- s e2) . Lambda = 0`` with ``s = sqrt(-sigma2 / sigma1)`` (sec. 3.5). Each line meets the
conic D1 (or D2) in up to two rays, the scale comes from eq. 4 (sec. 3.6), a few verified
Gauss-Newton steps refine Lambda on eq. 4 (sec. 3.8), and the pose follows from the two
triangles ``[x1 - x2, x1 - x3, cross]`` and ``[l1 y1 - l2 y2, l1 y1 - l3 y3, cross]`` (sec. 3.7).

Implementation choices of our own (the paper leaves them open or picks differently):

* The cubic is solved in closed form (trigonometric / Cardano) in gamma or, when
  ``|det D2| < |det D1|``, in ``delta = 1 / gamma`` (``D0 = delta D1 + D2``); of the real roots we
  take the one with the largest ``|f'|`` (best conditioned) and polish it with two Newton steps.
  When the polynomial has 4 real solutions every real root gives a real line pair; with 2 real
  solutions there is exactly one real root and it does; a real root with a definite ``D0``
  (``sigma1 sigma2 > 0``) means there are no real solutions.
* Each line ``u . Lambda = 0`` is parametrized as ``alpha e3 + beta (s' e1 - e2)`` (``e3`` the
  null vector, ``s' = +-s``), so no division by a component of ``u`` is needed; the homogeneous
  quadratic in (alpha, beta) is solved without cancellation. The scale uses the sum of the three
  equations of eq. 4 (a positive definite form for distinct bearings).
* Degenerate input (coincident or collinear world points, parallel bearings, NaN) and
  solutions whose ``Y X^-1`` is not orthonormal to 1e-6 (ill-conditioned near-degenerate
  input) are dropped: the kernels return only finite poses. The accepted ``R`` gets one
  Newton-Schulz step towards its polar factor (orthonormal to rounding; ``Y X^-1`` alone is off
  by ~1e-13), then ``t = l1 y1 - R x1``.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .._so3 import INLINE

__all__ = ["MAX_SOLUTIONS", "lambda_twist", "lambda_twist_batch", "lambda_twist_into"]

#: at most 4 solutions per triplet (two lines of D0, each meeting a conic twice)
MAX_SOLUTIONS = 4
_GN_ITERATIONS = 5
#: squared sine of the angle below which two world-point edges / two bearings count as parallel
_DEGENERATE_SIN2 = 1e-20
#: tolerance on max |R^T R - I| for accepting a solution
_ORTHO_TOL = 1e-6


@kernel(inline=INLINE)
def _det3(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    return (
        a00 * (a11 * a22 - a12 * a21)
        - a01 * (a10 * a22 - a12 * a20)
        + a02 * (a10 * a21 - a11 * a20)
    )


@kernel
def _cubic_root(b, c, d):
    """The real root of ``g^3 + b g^2 + c g + d`` with the largest ``|f'|`` (closed form, then
    two Newton steps)."""
    third = 1.0 / 3.0
    p = c - b * b * third
    q = 2.0 * b * b * b / 27.0 - b * c * third + d
    h = 0.25 * q * q + p * p * p / 27.0
    shift = -b * third
    if h > 0.0 or p == 0.0:  # one real root (Cardano, cancellation-free form)
        sq = math.sqrt(max(h, 0.0))
        w = 0.5 * abs(q) + sq
        A = -math.copysign(w**third, q) if w > 0.0 else 0.0
        t = A - p / (3.0 * A) if A != 0.0 else 0.0
        g = t + shift
    else:  # three real roots: t_k = 2 sqrt(-p/3) cos(phi/3 - 2 pi k / 3)
        m = 2.0 * math.sqrt(-p * third)
        arg = 3.0 * q / (p * m)
        arg = min(1.0, max(-1.0, arg))
        phi = math.acos(arg) * third
        g = shift
        best = -1.0
        for k in range(3):
            t = m * math.cos(phi - 2.0943951023931957 * k)
            df = abs(3.0 * t * t + p)
            if df > best:
                best = df
                g = t + shift
    for _ in range(2):
        f = ((g + b) * g + c) * g + d
        df = (3.0 * g + 2.0 * b) * g + c
        if df == 0.0:
            break
        g -= f / df
    return g


@kernel(inline=INLINE)
def _best_cross(r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """Unit vector orthogonal to the rows of a rank-2 3x3 matrix: the longest of the three row
    cross products (0 vector if the matrix has rank < 2)."""
    c00 = r01 * r12 - r02 * r11
    c01 = r02 * r10 - r00 * r12
    c02 = r00 * r11 - r01 * r10
    c10 = r01 * r22 - r02 * r21
    c11 = r02 * r20 - r00 * r22
    c12 = r00 * r21 - r01 * r20
    c20 = r11 * r22 - r12 * r21
    c21 = r12 * r20 - r10 * r22
    c22 = r10 * r21 - r11 * r20
    n0 = c00 * c00 + c01 * c01 + c02 * c02
    n1 = c10 * c10 + c11 * c11 + c12 * c12
    n2 = c20 * c20 + c21 * c21 + c22 * c22
    if n0 >= n1 and n0 >= n2:
        v0, v1, v2, n = c00, c01, c02, n0
    elif n1 >= n2:
        v0, v1, v2, n = c10, c11, c12, n1
    else:
        v0, v1, v2, n = c20, c21, c22, n2
    if not n > 0.0:
        return 0.0, 0.0, 0.0
    n = 1.0 / math.sqrt(n)
    return v0 * n, v1 * n, v2 * n


@kernel(inline=INLINE)
def _quad(D00, D01, D02, D11, D12, D22, p0, p1, p2, q0, q1, q2):
    """p^T D q for a symmetric D given by its upper triangle."""
    return (
        p0 * (D00 * q0 + D01 * q1 + D02 * q2)
        + p1 * (D01 * q0 + D11 * q1 + D12 * q2)
        + p2 * (D02 * q0 + D12 * q1 + D22 * q2)
    )


@kernel(inline=INLINE)
def _residuals(l1, l2, l3, a12, a13, a23, b12, b13, b23):
    r1 = l1 * l1 + l2 * l2 - 2.0 * b12 * l1 * l2 - a12
    r2 = l1 * l1 + l3 * l3 - 2.0 * b13 * l1 * l3 - a13
    r3 = l2 * l2 + l3 * l3 - 2.0 * b23 * l2 * l3 - a23
    return r1, r2, r3


@kernel
def _refine(l1, l2, l3, a12, a13, a23, b12, b13, b23):
    """Verified Gauss-Newton steps on eq. 4 (sec. 3.8): a step is taken only if it lowers the
    sum of squared residuals. The system is square, so each step solves J d = -r (Cramer)."""
    r1, r2, r3 = _residuals(l1, l2, l3, a12, a13, a23, b12, b13, b23)
    e = r1 * r1 + r2 * r2 + r3 * r3
    for _ in range(_GN_ITERATIONS):
        if e == 0.0:
            break
        j00 = 2.0 * (l1 - b12 * l2)
        j01 = 2.0 * (l2 - b12 * l1)
        j10 = 2.0 * (l1 - b13 * l3)
        j12 = 2.0 * (l3 - b13 * l1)
        j21 = 2.0 * (l2 - b23 * l3)
        j22 = 2.0 * (l3 - b23 * l2)
        # J = [[j00, j01, 0], [j10, 0, j12], [0, j21, j22]]
        det = -j00 * j12 * j21 - j01 * j10 * j22
        if det == 0.0 or not math.isfinite(det):
            break
        inv = 1.0 / det
        # adjugate of J applied to -r
        d1 = -(-j12 * j21 * r1 - j01 * j22 * r2 + j01 * j12 * r3) * inv
        d2 = -(-j10 * j22 * r1 + j00 * j22 * r2 - j00 * j12 * r3) * inv
        d3 = -(j10 * j21 * r1 - j00 * j21 * r2 - j01 * j10 * r3) * inv
        n1, n2, n3 = l1 + d1, l2 + d2, l3 + d3
        s1, s2, s3 = _residuals(n1, n2, n3, a12, a13, a23, b12, b13, b23)
        en = s1 * s1 + s2 * s2 + s3 * s3
        if not en < e:
            break
        l1, l2, l3, r1, r2, r3, e = n1, n2, n3, s1, s2, s3, en
    return l1, l2, l3


@kernel
def lambda_twist_into(y, X, Rout, tout, off):
    """Lambda Twist on one triplet into the caller's buffers (for kernels that solve one
    sample at a time, :func:`lambda_twist` without its arrays): writes the n <= 4 solutions
    ``X_cam = R X + t`` to ``Rout[off:off + n]`` (3, 3) and ``tout[off:off + n]`` (3,) and
    returns n (0 for degenerate input). y: (3, 3) float64 bearings (rows, any length), X:
    (3, 3) float64 world points; ``off`` an int64 (a literal int compiles another
    specialization)."""
    # unit bearings (sec. 3.1)
    n1 = math.sqrt(y[0, 0] ** 2 + y[0, 1] ** 2 + y[0, 2] ** 2)
    n2 = math.sqrt(y[1, 0] ** 2 + y[1, 1] ** 2 + y[1, 2] ** 2)
    n3 = math.sqrt(y[2, 0] ** 2 + y[2, 1] ** 2 + y[2, 2] ** 2)
    if not (n1 > 0.0 and n2 > 0.0 and n3 > 0.0):
        return 0
    y10, y11, y12 = y[0, 0] / n1, y[0, 1] / n1, y[0, 2] / n1
    y20, y21, y22 = y[1, 0] / n2, y[1, 1] / n2, y[1, 2] / n2
    y30, y31, y32 = y[2, 0] / n3, y[2, 1] / n3, y[2, 2] / n3
    b12 = y10 * y20 + y11 * y21 + y12 * y22
    b13 = y10 * y30 + y11 * y31 + y12 * y32
    b23 = y20 * y30 + y21 * y31 + y22 * y32
    # parallel bearings: the system of eq. 4 has no isolated solution
    if not (
        1.0 - b12 * b12 > _DEGENERATE_SIN2
        and 1.0 - b13 * b13 > _DEGENERATE_SIN2
        and 1.0 - b23 * b23 > _DEGENERATE_SIN2
    ):
        return 0
    # world triangle: edges u = x1 - x2, v = x1 - x3, normal w = u x v
    u0, u1, u2 = X[0, 0] - X[1, 0], X[0, 1] - X[1, 1], X[0, 2] - X[1, 2]
    v0, v1, v2 = X[0, 0] - X[2, 0], X[0, 1] - X[2, 1], X[0, 2] - X[2, 2]
    a12 = u0 * u0 + u1 * u1 + u2 * u2
    a13 = v0 * v0 + v1 * v1 + v2 * v2
    w0 = u1 * v2 - u2 * v1
    w1 = u2 * v0 - u0 * v2
    w2 = u0 * v1 - u1 * v0
    ww = w0 * w0 + w1 * w1 + w2 * w2
    # coincident or collinear world points (|u x v|^2 = |u|^2 |v|^2 sin^2)
    if not ww > _DEGENERATE_SIN2 * a12 * a13:
        return 0
    d0, d1, d2 = X[1, 0] - X[2, 0], X[1, 1] - X[2, 1], X[1, 2] - X[2, 2]
    a23 = d0 * d0 + d1 * d1 + d2 * d2
    # D1 = a23 M12 - a12 M23 and D2 = a23 M13 - a13 M23 (sec. 3.2), upper triangles
    A00, A01, A02 = a23, -a23 * b12, 0.0
    A11, A12, A22 = a23 - a12, a12 * b23, -a12
    B00, B01, B02 = a23, 0.0, -a23 * b13
    B11, B12, B22 = -a13, a13 * b23, a23 - a13
    # det(D1 + g D2) = c3 g^3 + c2 g^2 + c1 g + c0, by multilinearity in the columns (sec. 3.3)
    c0 = _det3(A00, A01, A02, A01, A11, A12, A02, A12, A22)
    c3 = _det3(B00, B01, B02, B01, B11, B12, B02, B12, B22)
    # columns of D1 / D2 are their rows (symmetric); det(x, y, z) of column vectors
    c1 = (
        _det3(B00, A01, A02, B01, A11, A12, B02, A12, A22)
        + _det3(A00, B01, A02, A01, B11, A12, A02, B12, A22)
        + _det3(A00, A01, B02, A01, A11, B12, A02, A12, B22)
    )
    c2 = (
        _det3(A00, B01, B02, A01, B11, B12, A02, B12, B22)
        + _det3(B00, A01, B02, B01, A11, B12, B02, A12, B22)
        + _det3(B00, B01, A02, B01, B11, A12, B02, B12, A22)
    )
    # D0 = ka D1 + kb D2 with (ka, kb) = (1, gamma) or (delta, 1); the conic we intersect the
    # lines with is whichever of D1, D2 has the smaller weight in D0 (the most independent one)
    if abs(c3) >= abs(c0):
        if c3 == 0.0:
            return 0
        ka, kb = 1.0, _cubic_root(c2 / c3, c1 / c3, c0 / c3)
    else:
        ka, kb = _cubic_root(c1 / c0, c2 / c0, c3 / c0), 1.0
    E00, E01, E02 = ka * A00 + kb * B00, ka * A01 + kb * B01, ka * A02 + kb * B02
    E11, E12, E22 = ka * A11 + kb * B11, ka * A12 + kb * B12, ka * A22 + kb * B22
    if abs(ka) <= abs(kb):
        C00, C01, C02, C11, C12, C22 = A00, A01, A02, A11, A12, A22
    else:
        C00, C01, C02, C11, C12, C22 = B00, B01, B02, B11, B12, B22
    # eigen-decomposition of the rank-2 D0 (sec. 3.4): sigma1 sigma2 = sum of principal minors
    tr = E00 + E11 + E22
    mn = (E00 * E11 - E01 * E01) + (E00 * E22 - E02 * E02) + (E11 * E22 - E12 * E12)
    if not mn <= 0.0:  # definite (or NaN): the lines are complex, no real solution
        return 0
    disc = 0.25 * tr * tr - mn
    sig1 = 0.5 * tr + math.copysign(math.sqrt(disc), tr)  # the larger |eigenvalue|
    if sig1 == 0.0:
        return 0
    s = math.sqrt(-mn) / abs(sig1)  # sqrt(-sigma2 / sigma1), in [0, 1]
    e10, e11, e12 = _best_cross(E00 - sig1, E01, E02, E01, E11 - sig1, E12, E02, E12, E22 - sig1)
    e30, e31, e32 = _best_cross(E00, E01, E02, E01, E11, E12, E02, E12, E22)
    # e2 = e3 x e1 (right-handed, so e2 x e3 = e1 and e1 x e3 = -e2)
    e20 = e31 * e12 - e32 * e11
    e21 = e32 * e10 - e30 * e12
    e22 = e30 * e11 - e31 * e10
    # the scale form: sum of the three equations of eq. 4
    asum = a12 + a13 + a23
    # inverse of the world triangle matrix [u, v, w] (rows: (v x w, w x u, w) / |w|^2), sec. 3.7
    iw = 1.0 / ww
    p00, p01, p02 = (v1 * w2 - v2 * w1) * iw, (v2 * w0 - v0 * w2) * iw, (v0 * w1 - v1 * w0) * iw
    p10, p11, p12 = (w1 * u2 - w2 * u1) * iw, (w2 * u0 - w0 * u2) * iw, (w0 * u1 - w1 * u0) * iw
    p20, p21, p22 = w0 * iw, w1 * iw, w2 * iw
    n = 0
    for sgn in (1.0, -1.0):
        if sgn < 0.0 and s == 0.0:  # a double line: one line only
            break
        # line (e1 + sgn s e2) . Lambda = 0 is spanned by e3 and q = sgn s e1 - e2 (sec. 3.5)
        q0 = sgn * s * e10 - e20
        q1 = sgn * s * e11 - e21
        q2 = sgn * s * e12 - e22
        # Lambda = al e3 + be q on the conic C: A al^2 + 2 B al be + C be^2 = 0
        qa = _quad(C00, C01, C02, C11, C12, C22, e30, e31, e32, e30, e31, e32)
        qb = _quad(C00, C01, C02, C11, C12, C22, e30, e31, e32, q0, q1, q2)
        qc = _quad(C00, C01, C02, C11, C12, C22, q0, q1, q2, q0, q1, q2)
        dq = qb * qb - qa * qc
        if not dq >= 0.0:
            continue
        r = -qb - math.copysign(math.sqrt(dq), qb)
        # the two roots as directions (al, be): (r, A) and (C, r)
        for root in range(2):
            if root == 0:
                al, be = r, qa
            else:
                if dq == 0.0:  # double root: already done
                    break
                al, be = qc, r
            l1 = al * e30 + be * q0
            l2 = al * e31 + be * q1
            l3 = al * e32 + be * q2
            # scale from the sum of eq. 4 (sec. 3.6); sign makes the depths positive
            den = 2.0 * (l1 * l1 + l2 * l2 + l3 * l3) - 2.0 * (
                b12 * l1 * l2 + b13 * l1 * l3 + b23 * l2 * l3
            )
            if not den > 0.0:
                continue
            k = math.sqrt(asum / den)
            if l1 + l2 + l3 < 0.0:
                k = -k
            l1, l2, l3 = k * l1, k * l2, k * l3
            if not (l1 > 0.0 and l2 > 0.0 and l3 > 0.0):
                continue
            l1, l2, l3 = _refine(l1, l2, l3, a12, a13, a23, b12, b13, b23)
            if not (l1 > 0.0 and l2 > 0.0 and l3 > 0.0):
                continue
            # camera triangle [l1 y1 - l2 y2, l1 y1 - l3 y3, cross] (sec. 3.7)
            f0, f1, f2 = l1 * y10 - l2 * y20, l1 * y11 - l2 * y21, l1 * y12 - l2 * y22
            g0, g1, g2 = l1 * y10 - l3 * y30, l1 * y11 - l3 * y31, l1 * y12 - l3 * y32
            h0, h1, h2 = f1 * g2 - f2 * g1, f2 * g0 - f0 * g2, f0 * g1 - f1 * g0
            R = Rout[off + n]
            R[0, 0] = f0 * p00 + g0 * p10 + h0 * p20
            R[0, 1] = f0 * p01 + g0 * p11 + h0 * p21
            R[0, 2] = f0 * p02 + g0 * p12 + h0 * p22
            R[1, 0] = f1 * p00 + g1 * p10 + h1 * p20
            R[1, 1] = f1 * p01 + g1 * p11 + h1 * p21
            R[1, 2] = f1 * p02 + g1 * p12 + h1 * p22
            R[2, 0] = f2 * p00 + g2 * p10 + h2 * p20
            R[2, 1] = f2 * p01 + g2 * p11 + h2 * p21
            R[2, 2] = f2 * p02 + g2 * p12 + h2 * p22
            # accept only (numerically) orthonormal, finite rotations: S = R^T R - I
            s00 = R[0, 0] * R[0, 0] + R[1, 0] * R[1, 0] + R[2, 0] * R[2, 0] - 1.0
            s11 = R[0, 1] * R[0, 1] + R[1, 1] * R[1, 1] + R[2, 1] * R[2, 1] - 1.0
            s22 = R[0, 2] * R[0, 2] + R[1, 2] * R[1, 2] + R[2, 2] * R[2, 2] - 1.0
            s01 = R[0, 0] * R[0, 1] + R[1, 0] * R[1, 1] + R[2, 0] * R[2, 1]
            s02 = R[0, 0] * R[0, 2] + R[1, 0] * R[1, 2] + R[2, 0] * R[2, 2]
            s12 = R[0, 1] * R[0, 2] + R[1, 1] * R[1, 2] + R[2, 1] * R[2, 2]
            if not max(abs(s00), abs(s11), abs(s22), abs(s01), abs(s02), abs(s12)) <= _ORTHO_TOL:
                continue
            # one Newton-Schulz step towards the polar factor, R <- R (I - S / 2): the
            # orthonormality error goes from |S| (~1e-13 typically) to O(|S|^2)
            for i in range(3):
                r0, r1, r2 = R[i, 0], R[i, 1], R[i, 2]
                R[i, 0] = r0 - 0.5 * (r0 * s00 + r1 * s01 + r2 * s02)
                R[i, 1] = r1 - 0.5 * (r0 * s01 + r1 * s11 + r2 * s12)
                R[i, 2] = r2 - 0.5 * (r0 * s02 + r1 * s12 + r2 * s22)
            t = tout[off + n]
            for i in range(3):
                t[i] = l1 * y[0, i] / n1 - R[i, 0] * X[0, 0] - R[i, 1] * X[0, 1] - R[i, 2] * X[0, 2]
            if not (math.isfinite(t[0]) and math.isfinite(t[1]) and math.isfinite(t[2])):
                continue
            n += 1
    return n


@kernel
def lambda_twist(bearings, X):
    """Lambda Twist P3P (Persson and Nordberg, ECCV 2018) on one triplet.

    Args:
        bearings: (3, 3) float64, row i the camera ray of point i (camera frame; normalized
            inside, so any positive length works).
        X: (3, 3) float64, row i world point i (world frame, world units).
    Returns:
        (R (n, 3, 3), t (n, 3)) with n in 0..4: every pose ``X_cam = R X + t`` that maps the
        three points onto their rays in front of the camera. n = 0 for degenerate input
        (coincident or collinear world points, parallel bearings, non-finite values); the
        returned arrays are always finite.
    Raises:
        nothing: no validation beyond the degeneracy checks (use :func:`rs_localizer.solvers.p3p`
        for checked input).
    """
    R = np.empty((MAX_SOLUTIONS, 3, 3))
    t = np.empty((MAX_SOLUTIONS, 3))
    # (a non-literal offset: the same compiled lambda_twist_into as lambda_twist_batch's)
    n = lambda_twist_into(bearings, X, R, t, np.int64(0))
    return R[:n].copy(), t[:n].copy()


@kernel
def lambda_twist_batch(bearings, X):
    """Lambda Twist P3P on K triplets (RANSAC hypotheses), one thread.

    Args:
        bearings: (K, 3, 3) float64 camera rays (camera frame, any positive length).
        X: (K, 3, 3) float64 world points (world frame).
    Returns:
        (R (M, 3, 3), C (M, 3), owner (M,) int64): all M <= 4K finite solutions
        ``X_cam = R X + C``, grouped by triplet in increasing ``owner`` order (the index of the
        triplet each came from), as :func:`lambda_twist` gives them per triplet.
    """
    K = bearings.shape[0]
    R = np.empty((MAX_SOLUTIONS * K, 3, 3))
    t = np.empty((MAX_SOLUTIONS * K, 3))
    own = np.empty(MAX_SOLUTIONS * K, dtype=np.int64)
    # (an int64 from the start: numba would otherwise also compile lambda_twist_into for the
    # literal 0 it sees first)
    m = np.int64(0)
    for k in range(K):
        n = lambda_twist_into(bearings[k], X[k], R, t, m)
        for j in range(n):
            own[m + j] = k
        m += n
    return R[:m].copy(), t[:m].copy(), own[:m].copy()
