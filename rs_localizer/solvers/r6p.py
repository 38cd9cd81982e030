"""R6P: minimal rolling-shutter absolute pose from six 2D-3D correspondences (all 20 roots).

Model (Albl, Kukelova, Pajdla, CVPR 2015; Kukelova et al., ACCV 2018, eq. 5), with
``tau_i = r_i - r0``::

    lambda_i [x_i; y_i; 1] = (I + tau_i [w]x)(I + [v]x) X_i + C + tau_i t            (eq. 5)

Eliminating ``lambda_i`` with the first two rows of ``[x_hat_i]x`` gives, per point, the two
equations ``E . p_i = 0`` with ``E1 = [0, -1, y_i]`` and ``E2 = [1, 0, -x_i]``: 12 equations,
12 unknowns, 20 complex solutions in general.

Elimination used here (instead of the 196 x 216 Groebner-basis template of the CVPR paper):

1. ``C`` and ``t`` enter linearly through the 12 x 6 block ``B = [E, tau E]``. Householder QR
   of ``B``; the last 6 rows of ``Q^T`` (its left null space) remove them.
2. What remains are 6 equations bilinear in (v, w): ``A(w) [1; v] = 0`` with ``A(w)`` a 6 x 4
   matrix affine in ``w``. A solution needs ``rank A(w) <= 3``, so all fifteen 4 x 4 minors of
   ``A(w)`` vanish: 15 quartics in ``w`` (35 monomials), computed by Laplace expansion from the
   2 x 2 minors. The locus ``rank A(w) <= 3`` has degree ``C(6, 3) = 20`` = the number of roots.
3. Template 15 x 35: eliminating its degree-4 block (15 x 15, Gauss-Jordan with partial
   pivoting) expresses every quartic monomial in the basis of the 20 monomials of degree <= 3.
   That gives the 20 x 20 multiplication matrix of a fixed generic linear form ``g . w``; its
   eigenvectors are the monomial vectors ``[1, w1, w2, w3, w1^2, ...]`` at the 20 roots. (Before
   this, ``w = u / (1 + c . u)`` with a fixed c: a projective change of the hidden variable that
   turns isolated roots at infinity, which would make the quartic block singular, into finite
   roots that are dropped afterwards.)
4. Eigenvalues by balancing, Hessenberg reduction and Francis double-shift QR (EISPACK
   balanc/elmhes/hqr, hand-written: for 20 x 20 the LAPACK call overhead dominates), eigenvectors
   of the (nearly) real ones by inverse iteration on the Hessenberg matrix.
5. Per real root: ``v`` from ``A(w) [1; v] = 0`` (6 x 3 least squares), ``C, t`` from the QR of
   step 1, then Newton steps on the 12 equations of eq. 5 (with step halving) polish it to
   machine precision. Roots whose residual stays above machine precision are dropped (real parts
   of complex pairs), duplicates are merged.

World points are centred and scaled and ``tau`` is scaled before solving; this is an exact
reparametrisation of eq. 5 (the offset is absorbed by ``C`` and ``t``) and is undone at the end.

Coplanar world points are structurally special: the rank-deficiency locus of ``A(w)`` then also
contains a curve at infinity and the template breaks down. For them the template is built from
points lifted 1e-6 (normalised units) off their plane and the roots are polished on the true
equations (see :func:`_planar_lift`): the returned roots are exact, but ground truth is found in
~99 % of random coplanar instances instead of ~100 %, and the number of real roots can be odd.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from .._jit import kernel
from .._linalg import (
    balance,
    elmhes,
    hessenberg_lu,
    hessenberg_lu_solve,
    householder_lstsq_into,
    householder_qr,
    hqr,
    solve_square,
)
from ._common import DegenerateInputError, RSSolution, check_inputs

__all__ = ["r6p"]

# ---------------------------------------------------------------------------------------------
# Monomials in w = (w1, w2, w3) of degree <= 4, graded: [1 | w1 w2 w3 | 6 quadratic | 10 cubic |
# 15 quartic]. Index 0..19 (degree <= 3) is the basis of the quotient ring, 20..34 the quartics.
_MONOS = [
    e
    for d in range(5)
    for e in sorted((e for e in itertools.product(range(5), repeat=3) if sum(e) == d), reverse=True)
]
_MIDX = {m: i for i, m in enumerate(_MONOS)}


def _mul_table(n1, n2):
    tab = np.full((n1, n2), -1, dtype=np.int64)
    for i in range(n1):
        for j in range(n2):
            m = tuple(a + b for a, b in zip(_MONOS[i], _MONOS[j], strict=False))
            if sum(m) <= 4:
                tab[i, j] = _MIDX[m]
    return tab


_MUL11 = _mul_table(4, 4)  # affine x affine -> index in 0..9
_MUL22 = _mul_table(10, 10)  # quadratic x quadratic -> index in 0..34
# _SHIFT[b, k]: index of w_k * (basis monomial b); >= 20 means a quartic to be reduced
_SHIFT = np.array(
    [[_MIDX[tuple(m[i] + (i == k) for i in range(3))] for k in range(3)] for m in _MONOS[:20]],
    dtype=np.int64,
)
# row pairs (15) of the 6 x 4 matrix A(w), and the 15 row quadruples (a, b | c, d) for Laplace
_PAIRS = np.array(list(itertools.combinations(range(6), 2)), dtype=np.int64)
_PAIR_ID = {tuple(p): i for i, p in enumerate(_PAIRS.tolist())}
_QUADS = np.array(
    [[_PAIR_ID[(q[0], q[1])], _PAIR_ID[(q[2], q[3])]] for q in itertools.combinations(range(6), 4)],
    dtype=np.int64,
)
# column pairs of a 4 x 4 matrix, their complements, and the Laplace signs (-1)^(0+1+p+q)
_CPAIRS = np.array(list(itertools.combinations(range(4), 2)), dtype=np.int64)
_CCOMP = np.array([5 - i for i in range(6)], dtype=np.int64)  # complement of pair i is pair 5-i
_CSIGN = np.array([(-1.0) ** (1 + p + q) for p, q in _CPAIRS.tolist()])
# generic linear form g . w whose multiplication matrix is diagonalised (fixed for determinism)
_G = np.array([0.6410713, -0.3785134, 0.5287362])
# projective change of the hidden variable w = u / (1 + c.u) (moves roots at infinity in)
_PROJ_C = np.array([0.2137, -0.1694, 0.2581])

_PLANAR_TOL = 1e-6  # smallest/largest principal axis of X below which X counts as planar
_LIFT = 1e-6  # RMS lift off the plane (normalised units) for coplanar points
_LIFT_PATTERN = np.array([0.83, -0.41, 0.27, -0.95, 0.64, -0.12])
_RANK_TOL = 1e-10  # relative pivot threshold of the QR of B
_PIVOT_TOL = 1e-13  # relative pivot threshold of the 15 x 15 elimination
_IMAG_TOL = 1e-3  # eigenvalues with |Im| > _IMAG_TOL (1 + |Re|) are complex roots
_ACCEPT_TOL = 1e-14  # accept a polished root if RMS residual <= _ACCEPT_TOL (1 + |z|)^2
# (normalised units; z = (v, w, C, t))
_ZMAX = 1e12  # roots with |z| above this (normalised units) are dropped as overflow-prone
_MAX_NEWTON = 15  # Newton steps per root at most (2-3 are typical)


# ---------------------------------------------------------------------------------------------
@kernel
def _eq5_system(x, Xn, tau):
    """Coefficients of the 12 equations ``E . p_i`` of eq. 5.

    Returns M (12, 16) with column ``4 j + k`` the coefficient of ``[1, v1, v2, v3]_j *
    [1, w1, w2, w3]_k`` and B (12, 6) the coefficients of (C, t). With ``Y = X + v x X``:
    ``E . p = E.X + v.(X x E) + tau w.(X x E) + tau sum_jk v_j w_k (X_k E_j - d_jk X.E)
    + E.C + tau E.t`` (from ``E.(w x Y) = w.(Y x E)`` and ``(v x X) x E = X (v.E) - v (X.E)``).
    """
    M = np.zeros((12, 16))
    B = np.zeros((12, 6))
    E = np.zeros(3)
    for i in range(6):
        X0, X1, X2 = Xn[i, 0], Xn[i, 1], Xn[i, 2]
        ti = tau[i]
        for q in range(2):
            if q == 0:  # row 1 of [x_hat]x: -p_y + y p_z
                E[0], E[1], E[2] = 0.0, -1.0, x[i, 1]
            else:  # row 2: p_x - x p_z
                E[0], E[1], E[2] = 1.0, 0.0, -x[i, 0]
            row = 2 * i + q
            XE0 = X1 * E[2] - X2 * E[1]
            XE1 = X2 * E[0] - X0 * E[2]
            XE2 = X0 * E[1] - X1 * E[0]
            XdE = X0 * E[0] + X1 * E[1] + X2 * E[2]
            M[row, 0] = XdE
            M[row, 1] = ti * XE0
            M[row, 2] = ti * XE1
            M[row, 3] = ti * XE2
            M[row, 4] = XE0
            M[row, 8] = XE1
            M[row, 12] = XE2
            for j in range(3):
                for k in range(3):
                    c = Xn[i, k] * E[j]
                    if j == k:
                        c -= XdE
                    M[row, 4 * (j + 1) + (k + 1)] = ti * c
                B[row, j] = E[j]
                B[row, 3 + j] = ti * E[j]
    return M, B


@kernel
def _action_matrix(A, mul11, mul22, quads, ccomp, csign, shift, g):
    """20 x 20 multiplication matrix of ``g . w`` from the 4 x 4 minors of A(w) (6, 4, 4).

    ``A[i, j, :]`` holds the affine polynomial (coefficients of 1, w1, w2, w3) of entry (i, j).
    Returns (Mact, pivot ratio of the 15 x 15 elimination).
    """
    # 2 x 2 minors: rows (a, b) in _PAIRS order, column pairs in _CPAIRS order -> quadratics
    m2 = np.zeros((15, 6, 10))
    pa = 0
    for a in range(6):
        for b in range(a + 1, 6):
            pc = 0
            for p in range(4):
                for q in range(p + 1, 4):
                    for u in range(4):
                        for s in range(4):
                            idx = mul11[u, s]
                            m2[pa, pc, idx] += A[a, p, u] * A[b, q, s] - A[a, q, u] * A[b, p, s]
                    pc += 1
            pa += 1
    # 4 x 4 minors by Laplace expansion along the first two rows -> 15 quartics (15 x 35)
    P = np.zeros((15, 35))
    for n in range(15):
        r1 = quads[n, 0]
        r2 = quads[n, 1]
        for c in range(6):
            sg = csign[c]
            cc = ccomp[c]
            for u in range(10):
                cu = sg * m2[r1, c, u]
                if cu == 0.0:
                    continue
                for s in range(10):
                    P[n, mul22[u, s]] += cu * m2[r2, cc, s]
        # row scaling (the minors are defined up to scale)
        mx = 0.0
        for j in range(35):
            mx = max(mx, abs(P[n, j]))
        if mx > 0.0:
            for j in range(35):
                P[n, j] /= mx
    # Gaussian elimination with partial pivoting on the quartic block (columns 20..34), applied
    # to the whole row: afterwards quartic monomial 20+k = -sum_j P[k, j] * basis_j.
    pmax = 0.0
    pmin = np.inf
    for k in range(15):
        piv = k
        best = abs(P[k, 20 + k])
        for i in range(k + 1, 15):
            if abs(P[i, 20 + k]) > best:
                best = abs(P[i, 20 + k])
                piv = i
        if piv != k:
            for j in range(35):
                tmp = P[k, j]
                P[k, j] = P[piv, j]
                P[piv, j] = tmp
        pmax = max(pmax, best)
        pmin = min(pmin, best)
        if best == 0.0:
            return np.zeros((20, 20)), 0.0
        inv = 1.0 / P[k, 20 + k]
        for j in range(35):
            P[k, j] *= inv
        for i in range(15):
            if i != k:
                f = P[i, 20 + k]
                if f != 0.0:
                    for j in range(35):
                        P[i, j] -= f * P[k, j]
    # multiplication matrix: (g.w) * basis_b = sum_c Mact[b, c] basis_c on the variety
    Mact = np.zeros((20, 20))
    for b in range(20):
        for k in range(3):
            s = shift[b, k]
            if s < 20:
                Mact[b, s] += g[k]
            else:
                for c in range(20):
                    Mact[b, c] -= g[k] * P[s - 20, c]
    return Mact, pmin / pmax


@kernel
def _residual_jacobian(x, Xn, tau, z, F, J):
    """Residual F (12) of eq. 5 and its Jacobian J (12, 12) w.r.t. z = (v, w, C, t)."""
    v0, v1, v2 = z[0], z[1], z[2]
    w0, w1, w2 = z[3], z[4], z[5]
    for i in range(6):
        X0, X1, X2 = Xn[i, 0], Xn[i, 1], Xn[i, 2]
        ti = tau[i]
        # Y = (I + [v]x) X
        Y0 = X0 + v1 * X2 - v2 * X1
        Y1 = X1 + v2 * X0 - v0 * X2
        Y2 = X2 + v0 * X1 - v1 * X0
        # p = Y + tau w x Y + C + tau t
        p0 = Y0 + ti * (w1 * Y2 - w2 * Y1) + z[6] + ti * z[9]
        p1 = Y1 + ti * (w2 * Y0 - w0 * Y2) + z[7] + ti * z[10]
        p2 = Y2 + ti * (w0 * Y1 - w1 * Y0) + z[8] + ti * z[11]
        # dp/dv_k = (I + tau [w]x)(e_k x X) ; dp/dw_k = tau e_k x Y ; dp/dC = I ; dp/dt = tau I
        for q in range(2):
            if q == 0:
                E0, E1, E2 = 0.0, -1.0, x[i, 1]
                F[2 * i] = -p1 + x[i, 1] * p2
            else:
                E0, E1, E2 = 1.0, 0.0, -x[i, 0]
                F[2 * i + 1] = p0 - x[i, 0] * p2
            row = 2 * i + q
            # a = (I + tau [w]x)^T E = E - tau (w x E), so E . dp/dv_k = a . (e_k x X)
            a0 = E0 - ti * (w1 * E2 - w2 * E1)
            a1 = E1 - ti * (w2 * E0 - w0 * E2)
            a2 = E2 - ti * (w0 * E1 - w1 * E0)
            # d/dv_k of a . (v x X) = a . (e_k x X) = e_k . (X x a)
            J[row, 0] = X1 * a2 - X2 * a1
            J[row, 1] = X2 * a0 - X0 * a2
            J[row, 2] = X0 * a1 - X1 * a0
            # d/dw_k of tau E . (w x Y) = tau e_k . (Y x E)
            J[row, 3] = ti * (Y1 * E2 - Y2 * E1)
            J[row, 4] = ti * (Y2 * E0 - Y0 * E2)
            J[row, 5] = ti * (Y0 * E1 - Y1 * E0)
            J[row, 6] = E0
            J[row, 7] = E1
            J[row, 8] = E2
            J[row, 9] = ti * E0
            J[row, 10] = ti * E1
            J[row, 11] = ti * E2


# ---------------------------------------------------------------------------------------------
# Small helpers. The njit functions are written with scalar loops: array expressions and
# NumPy library calls inside njit functions multiply the one-off compile time.
@kernel
def _norm(a):
    sm = 0.0
    for i in range(a.shape[0]):
        sm += a[i] * a[i]
    return np.sqrt(sm)


@kernel
def _dist(a, b):
    sm = 0.0
    for i in range(a.shape[0]):
        sm += (a[i] - b[i]) ** 2
    return np.sqrt(sm)


@kernel
def _finite(a):
    for i in range(a.shape[0]):  # noqa: SIM110 - numba compiles no generator inside all()
        if not np.isfinite(a[i]):
            return False
    return True


# ---------------------------------------------------------------------------------------------
# The action matrix's real roots (the eigenvalue kernels are in rs_localizer._linalg)
@kernel
def _w_from_eigvec(u, shift, out):
    """w from an eigenvector u ~ [1, w1, w2, w3, w1^2, ...] (20,): w_k = u[w_k m] / u[m] with
    m the largest entry of degree <= 2 (accurate also for roots with large |w|)."""
    mb = 0
    for b in range(10):
        if abs(u[b]) > abs(u[mb]):
            mb = b
    if u[mb] == 0.0:
        return False
    for k in range(3):
        out[k] = u[shift[mb, k]] / u[mb]
    return True


@kernel
def _real_candidates(Mact, shift, imag_tol):
    """w at the real (or nearly real) eigenvalues of the multiplication matrix.

    Eigenvalues by balancing + Hessenberg reduction + Francis QR (EISPACK balanc/elmhes/hqr).
    The eigenvector of each real eigenvalue comes from two steps of inverse iteration on the
    Hessenberg matrix (O(n^2) each), mapped back by the accumulated similarity ``D Z``.
    Returns (ok, W (k, 3)); ok is False if the QR iteration did not converge.
    """
    n = 20
    H = np.zeros((n + 1, n + 1))
    for i in range(n):
        for j in range(n):
            H[i + 1, j + 1] = Mact[i, j]
    D = np.ones(n + 1)
    Z = np.zeros((n + 1, n + 1))
    for i in range(1, n + 1):
        Z[i, i] = 1.0
    balance(H, D)
    elmhes(H, Z)
    Hq = H.copy()
    wr = np.zeros(n + 1)
    wi = np.zeros(n + 1)
    W = np.zeros((n, 3))
    if not hqr(Hq, wr, wi):
        return False, W[:0]
    k = 0
    b = np.zeros(n + 1)
    T = np.zeros((n + 1, n + 1))
    swap = np.zeros(n + 1, dtype=np.bool_)
    u = np.zeros(n)
    w = np.zeros(3)
    for e in range(1, n + 1):
        lam = wr[e]
        if wi[e] < 0.0 or abs(wi[e]) > imag_tol * (1.0 + abs(lam)):
            continue  # complex root (of a nearly real pair only the + member is used)
        for i in range(1, n + 1):
            b[i] = 1.0 + 0.1 * ((i * 7) % 5)  # fixed generic start vector
        hessenberg_lu(H, lam, T, swap)
        good = True
        for _it in range(2):  # inverse iteration: (H - lam I) b_new = b
            hessenberg_lu_solve(T, swap, b)
            nrm = 0.0
            for i in range(1, n + 1):
                nrm = max(nrm, abs(b[i]))
            if not (nrm > 0.0) or not np.isfinite(nrm):
                good = False
                break
            for i in range(1, n + 1):
                b[i] /= nrm
        if not good:
            continue
        # eigenvector of Mact: u = D Z y
        for i in range(n):
            sm = 0.0
            for j in range(1, n + 1):
                sm += Z[i + 1, j] * b[j]
            u[i] = D[i + 1] * sm
        if _w_from_eigvec(u, shift, w) and _finite(w):
            for i in range(3):
                W[k, i] = w[i]
            k += 1
    return True, W[:k]


@kernel
def _polish(x, Xn, tau, A, Bqr, V, W, accept_tol, max_newton, zmax):
    """From candidate w's: v, C, t by linear algebra, then Newton on eq. 5 (normalised units).

    Returns (Z (n, 12) rows (v, w, C, t), Newton steps (n,)); only roots with residual at
    machine precision and norm <= zmax are kept, duplicates merged.
    """
    nc = W.shape[0]
    Z = np.zeros((nc, 12))
    its = np.zeros(nc, dtype=np.int64)
    rms = np.zeros(nc)
    n = 0
    F = np.zeros(12)
    J = np.zeros((12, 12))
    dz = np.zeros(12)
    z = np.zeros(12)
    znew = np.zeros(12)
    ct = np.zeros(6)
    A1 = np.zeros((6, 3))
    a0 = np.zeros(6)
    N3 = np.zeros((3, 3))
    v = np.zeros(3)
    for c in range(nc):
        w0, w1, w2 = W[c, 0], W[c, 1], W[c, 2]
        # v from A(w) [1; v] = 0: 6 x 3 least squares by normal equations (refined by Newton)
        for i in range(6):
            a0[i] = A[i, 0, 0] + A[i, 0, 1] * w0 + A[i, 0, 2] * w1 + A[i, 0, 3] * w2
            for j in range(3):
                A1[i, j] = (
                    A[i, j + 1, 0] + A[i, j + 1, 1] * w0 + A[i, j + 1, 2] * w1 + A[i, j + 1, 3] * w2
                )
        for j in range(3):
            sm = 0.0
            for i in range(6):
                sm -= A1[i, j] * a0[i]
            v[j] = sm
            for ell in range(3):
                sm = 0.0
                for i in range(6):
                    sm += A1[i, j] * A1[i, ell]
                N3[j, ell] = sm
        if not solve_square(N3, v, v, 0.0):
            continue
        # C, t: evaluate the (v, w) part of the 12 equations (C = t = 0), then QR of B
        for i in range(12):
            z[i] = 0.0
        z[0] = v[0]
        z[1] = v[1]
        z[2] = v[2]
        z[3] = w0
        z[4] = w1
        z[5] = w2
        _residual_jacobian(x, Xn, tau, z, F, J)
        householder_lstsq_into(Bqr, V, F, ct)
        for i in range(6):
            z[6 + i] = ct[i]
        # Newton on the 12 x 12 system (J is square: the problem is minimal)
        _residual_jacobian(x, Xn, tau, z, F, J)
        res = _norm(F) / np.sqrt(12.0)
        it = 0
        for _ in range(max_newton):
            if res <= 1e-16:
                break
            for i in range(12):
                dz[i] = -F[i]
            if not solve_square(J, dz, dz, 0.0):
                break
            # a step at rounding level ends the iteration; far from the root the step is halved
            # (up to 4 times) until the residual decreases
            small = _norm(dz) <= 1e-12 * (1.0 + _norm(z))
            accepted = False
            rnew = res
            for _h in range(1 if small else 5):
                for i in range(12):
                    znew[i] = z[i] + dz[i]
                _residual_jacobian(x, Xn, tau, znew, F, J)
                rnew = _norm(F) / np.sqrt(12.0)
                if rnew < res:
                    accepted = True
                    break
                for i in range(12):
                    dz[i] *= 0.5
            if accepted:
                for i in range(12):
                    z[i] = znew[i]
                res = rnew
                it += 1
            if small or not accepted:
                break
        # accept roots at machine precision; rounding in eq. 5 grows like the products v w
        nz = _norm(z)
        if not (res <= accept_tol * (1.0 + nz) ** 2) or not (nz <= zmax):
            continue
        # merge duplicates (the two members of a nearly real pair, or repeated roots)
        dup = False
        for m in range(n):
            d = _dist(Z[m], z)
            if d <= 1e-8 * (1.0 + nz):
                dup = True
                if res < rms[m]:
                    for i in range(12):
                        Z[m, i] = z[i]
                    rms[m] = res
                    its[m] = it
                break
        if dup:
            continue
        for i in range(12):
            Z[n, i] = z[i]
        its[n] = it
        rms[n] = res
        n += 1
    return Z[:n], its[:n]


@kernel
def _normalise(x, X, r, r0, planar_tol):
    """Degeneracy checks and the exact reparametrisation of eq. 5.

    Returns (status, Xn, taun, m, s, st, maybe_planar) with Xn = (X - m) / s,
    taun = (r - r0) / st. status: 0 ok, 1 coincident/collinear world points, 2 duplicated world
    points, 3 all r_i equal to r0. maybe_planar is False when the smallest principal axis of Xn
    is certainly above ``planar_tol`` of the largest (lambda_min >= det / tr^2).
    """
    N = X.shape[0]
    m = np.zeros(3)
    for i in range(N):
        for k in range(3):
            m[k] += X[i, k] / N
    Xn = np.zeros((N, 3))
    s2 = 0.0
    for i in range(N):
        for k in range(3):
            Xn[i, k] = X[i, k] - m[k]
            s2 += Xn[i, k] * Xn[i, k]
    s = np.sqrt(s2 / N)
    taun = np.zeros(N)
    if not s > 0.0:
        return 1, Xn, taun, m, 1.0, 1.0, False
    for i in range(N):
        for k in range(3):
            Xn[i, k] /= s
    # duplicated points: two rows of X closer than 1e-10 of the point spread
    # collinear points: every point within 1e-9 of the line through the farthest pair
    dmax = -1.0
    ia = 0
    ib = 1
    for i in range(N):
        for j in range(i + 1, N):
            d = 0.0
            for k in range(3):
                d += (Xn[i, k] - Xn[j, k]) ** 2
            if d <= 1e-20:
                return 2, Xn, taun, m, s, 1.0, False
            if d > dmax:
                dmax = d
                ia = i
                ib = j
    dl = np.sqrt(dmax)
    e0 = (Xn[ib, 0] - Xn[ia, 0]) / dl
    e1 = (Xn[ib, 1] - Xn[ia, 1]) / dl
    e2 = (Xn[ib, 2] - Xn[ia, 2]) / dl
    off = 0.0
    for i in range(N):
        d0 = Xn[i, 0] - Xn[ia, 0]
        d1 = Xn[i, 1] - Xn[ia, 1]
        d2 = Xn[i, 2] - Xn[ia, 2]
        c0 = d1 * e2 - d2 * e1
        c1 = d2 * e0 - d0 * e2
        c2 = d0 * e1 - d1 * e0
        off = max(off, np.sqrt(c0 * c0 + c1 * c1 + c2 * c2))
    if off <= 1e-9 * dl:
        return 1, Xn, taun, m, s, 1.0, False
    st = 0.0
    for i in range(N):
        st = max(st, abs(r[i] - r0))
    if not st > 0.0:
        return 3, Xn, taun, m, s, 1.0, False
    for i in range(N):
        taun[i] = (r[i] - r0) / st
    # coplanarity pre-test on the scatter matrix S (exact test in _planar_lift)
    S = np.zeros((3, 3))
    for i in range(N):
        for a in range(3):
            for b in range(3):
                S[a, b] += Xn[i, a] * Xn[i, b]
    tr = S[0, 0] + S[1, 1] + S[2, 2]
    det = (
        S[0, 0] * (S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1])
        - S[0, 1] * (S[1, 0] * S[2, 2] - S[1, 2] * S[2, 0])
        + S[0, 2] * (S[1, 0] * S[2, 1] - S[1, 1] * S[2, 0])
    )
    maybe_planar = det < planar_tol * planar_tol * tr * tr * tr
    return 0, Xn, taun, m, s, st, maybe_planar


@kernel
def _denormalise(x, X, r, r0, Z, m, s, st):
    """Undo the normalisation (X = s Xn + m, tau = st taun) and compute the RMS algebraic error of
    eq. 5 (as :func:`._common.algebraic_error`). Returns (Zout (n, 12), err (n,))."""
    n = Z.shape[0]
    out = np.zeros((n, 12))
    err = np.zeros(n)
    for c in range(n):
        v0, v1, v2 = Z[c, 0], Z[c, 1], Z[c, 2]
        w0, w1, w2 = Z[c, 3] / st, Z[c, 4] / st, Z[c, 5] / st
        # Ym = (I + [v]x) m ; C = s Cn - Ym ; t = s tn / st - w x Ym
        y0 = m[0] + v1 * m[2] - v2 * m[1]
        y1 = m[1] + v2 * m[0] - v0 * m[2]
        y2 = m[2] + v0 * m[1] - v1 * m[0]
        out[c, 0] = v0
        out[c, 1] = v1
        out[c, 2] = v2
        out[c, 3] = w0
        out[c, 4] = w1
        out[c, 5] = w2
        out[c, 6] = s * Z[c, 6] - y0
        out[c, 7] = s * Z[c, 7] - y1
        out[c, 8] = s * Z[c, 8] - y2
        out[c, 9] = s * Z[c, 9] / st - (w1 * y2 - w2 * y1)
        out[c, 10] = s * Z[c, 10] / st - (w2 * y0 - w0 * y2)
        out[c, 11] = s * Z[c, 11] / st - (w0 * y1 - w1 * y0)
        sm = 0.0
        for i in range(X.shape[0]):
            ti = r[i] - r0
            P0 = X[i, 0] + v1 * X[i, 2] - v2 * X[i, 1]
            P1 = X[i, 1] + v2 * X[i, 0] - v0 * X[i, 2]
            P2 = X[i, 2] + v0 * X[i, 1] - v1 * X[i, 0]
            p0 = P0 + ti * (w1 * P2 - w2 * P1) + out[c, 6] + ti * out[c, 9]
            p1 = P1 + ti * (w2 * P0 - w0 * P2) + out[c, 7] + ti * out[c, 10]
            p2 = P2 + ti * (w0 * P1 - w1 * P0) + out[c, 8] + ti * out[c, 11]
            e1 = -p1 + x[i, 1] * p2
            e2 = p0 - x[i, 0] * p2
            sm += e1 * e1 + e2 * e2
        err[c] = np.sqrt(sm / X.shape[0])
    return out, err


@kernel
def _template(x, Xp, taun, proj_c):
    """Eq. 5 -> the 6 x 4 matrix A(w) and the QR of B (for C, t).

    Returns (ok, A, Au, Bqr, V): ``A[i, j, :]`` the affine entry (1, w1, w2, w3) of A(w),
    ``Au`` the same after the projective change ``w = u / (1 + c.u)``, and the Householder QR of
    B (R in ``Bqr``, reflectors in ``V``); ok is False if B is rank deficient.
    """
    # the 12 equations of eq. 5, and the elimination of C, t (Householder QR of B)
    M, B = _eq5_system(x, Xp, taun)
    V = np.zeros((12, 6))
    Rd = np.zeros(6)
    ok = householder_qr(B, M, V, Rd) > _RANK_TOL
    A = np.zeros((6, 4, 4))
    Au = np.zeros((6, 4, 4))
    for i in range(6):
        for j in range(4):
            for k in range(4):
                A[i, j, k] = M[6 + i, 4 * j + k]
                Au[i, j, k] = A[i, j, k]
            # projective change of the hidden variables, w = u / (1 + c.u): the entries of A
            # become a0 + (a + a0 c).u. Roots of A(w) at infinity become finite roots with
            # 1 + c.u = 0 (they are dropped when mapping back).
            for k in range(3):
                Au[i, j, k + 1] += A[i, j, 0] * proj_c[k]
    return ok, A, Au, B, V


@kernel
def _roots(x, X, r, r0, Xn, taun, A, Bqr, V, Uc, m, s, st, proj_c, accept_tol, max_newton, zmax):
    """Candidates u (k, 3) -> polished, de-normalised roots sorted by algebraic error.

    Returns (Z (n, 12) = (v, w, C, t) in input units, Newton steps (n,), algebraic errors (n,)).
    """
    # back from u to w = u / (1 + c.u)
    W = np.zeros((Uc.shape[0], 3))
    nw = 0
    for c in range(Uc.shape[0]):
        den = 1.0 + proj_c[0] * Uc[c, 0] + proj_c[1] * Uc[c, 1] + proj_c[2] * Uc[c, 2]
        if abs(den) <= 1e-8 * (1.0 + abs(Uc[c, 0]) + abs(Uc[c, 1]) + abs(Uc[c, 2])):
            continue  # root at infinity of A(w)
        for i in range(3):
            W[nw, i] = Uc[c, i] / den
        nw += 1
    Z, its = _polish(x, Xn, taun, A, Bqr, V, W[:nw], accept_tol, max_newton, zmax)
    Zo, err = _denormalise(x, X, r, r0, Z, m, s, st)
    # sort by algebraic error (insertion sort: n <= 20)
    n = err.shape[0]
    for i in range(1, n):
        j = i
        while j > 0 and err[j - 1] > err[j]:
            tmp = err[j]
            err[j] = err[j - 1]
            err[j - 1] = tmp
            ti = its[j]
            its[j] = its[j - 1]
            its[j - 1] = ti
            for k in range(12):
                tmp = Zo[j, k]
                Zo[j, k] = Zo[j - 1, k]
                Zo[j - 1, k] = tmp
            j -= 1
    return Zo, its, err


def _planar_lift(Xn):
    """Coplanar world points: a generic lift off their plane (NumPy; only runs for such data).

    For (nearly) coplanar points the rank-deficiency locus of A(w) contains a curve at infinity
    besides the isolated roots (the quotient ring is no longer 20-dimensional), so the template
    breaks down. If the smallest principal axis of Xn is below ``_PLANAR_TOL`` of the largest,
    the points used to build the template are moved off their plane by a fixed generic pattern
    of RMS ``_LIFT`` (made orthogonal to the affine functions on the plane). The roots of this
    nearby problem are then polished by Newton on the true equations, so only exact roots are
    returned. Returns (Xp, lifted).
    """
    ev, E = np.linalg.eigh(Xn.T @ Xn)  # ascending
    if not ev[0] < _PLANAR_TOL**2 * ev[2]:
        return Xn, False
    G = np.column_stack([np.ones(len(Xn)), Xn @ E[:, 2], Xn @ E[:, 1]])
    xi = _LIFT_PATTERN - G @ np.linalg.lstsq(G, _LIFT_PATTERN, rcond=None)[0]
    rms = np.sqrt(np.mean(xi * xi))
    if not rms > 0.0:
        return Xn, False
    return Xn + (_LIFT * xi / rms)[:, None] * E[:, 0], True


def _solve(x, X, r, r0):
    """The solver pipeline (each stage one compiled function). Returns (Z, its, err)."""
    status, Xn, taun, m, s, st, maybe_planar = _normalise(x, X, r, r0, _PLANAR_TOL)
    if status != 0:
        raise DegenerateInputError(_DEGENERATE[status])
    # coplanar points: build the template from points lifted off the plane (see _planar_lift)
    Xp, lifted = _planar_lift(Xn) if maybe_planar else (Xn, False)
    ok, A, Au, Bqr, V = _template(x, Xp, taun, _PROJ_C)
    if not ok:
        raise DegenerateInputError(_DEGENERATE[3])
    Mact, pivot_ratio = _action_matrix(Au, _MUL11, _MUL22, _QUADS, _CCOMP, _CSIGN, _SHIFT, _G)
    if not pivot_ratio > _PIVOT_TOL or not np.isfinite(Mact).all():
        raise DegenerateInputError(_DEGENERATE[4])
    ok, Uc = _real_candidates(Mact, _SHIFT, _IMAG_TOL)
    if not ok:
        # fallback (the Francis QR did not converge; very rare): LAPACK eigenvectors
        lam, U = np.linalg.eig(Mact)
        keep = (lam.imag >= 0) & (np.abs(lam.imag) <= _IMAG_TOL * (1.0 + np.abs(lam.real)))
        Uc = np.zeros((int(keep.sum()), 3))
        for k, u in enumerate(U[:, keep].T):
            mb = int(np.argmax(np.abs(u[:10])))
            Uc[k] = (u[_SHIFT[mb]] / u[mb]).real
    # lifted coplanar case: roots of norm >~ 1 / _LIFT are artefacts of the lift (they sit on the
    # curve at infinity of the planar problem), drop them
    zmax = 1e-2 / _LIFT if lifted else _ZMAX
    return _roots(
        x, X, r, r0, Xn, taun, A, Bqr, V, Uc, m, s, st, _PROJ_C, _ACCEPT_TOL, _MAX_NEWTON, zmax
    )


@kernel
def _solve_core(x, X, r, r0):
    """:func:`_solve` in one compiled call for the common case (the module's constant tables
    are compile-time constants here). Returns (status, Z, its, err): status 0 with the roots;
    1-4 a degeneracy (:data:`_DEGENERATE`); -1 when :func:`_solve` must run instead (maybe
    coplanar points, which need the NumPy lift, or a Francis QR that did not converge)."""
    Z0 = np.zeros((0, 12))
    its0 = np.zeros(0, dtype=np.int64)
    err0 = np.zeros(0)
    status, Xn, taun, m, s, st, maybe_planar = _normalise(x, X, r, r0, _PLANAR_TOL)
    if status != 0:
        return status, Z0, its0, err0
    if maybe_planar:
        return -1, Z0, its0, err0
    ok, A, Au, Bqr, V = _template(x, Xn, taun, _PROJ_C)
    if not ok:
        return 3, Z0, its0, err0
    Mact, pivot_ratio = _action_matrix(Au, _MUL11, _MUL22, _QUADS, _CCOMP, _CSIGN, _SHIFT, _G)
    if not pivot_ratio > _PIVOT_TOL:
        return 4, Z0, its0, err0
    for i in range(Mact.shape[0]):
        for j in range(Mact.shape[1]):
            if not np.isfinite(Mact[i, j]):
                return 4, Z0, its0, err0
    ok, Uc = _real_candidates(Mact, _SHIFT, _IMAG_TOL)
    if not ok:
        return -1, Z0, its0, err0
    Z, its, err = _roots(
        x, X, r, r0, Xn, taun, A, Bqr, V, Uc, m, s, st, _PROJ_C, _ACCEPT_TOL, _MAX_NEWTON, _ZMAX
    )
    return 0, Z, its, err


@kernel
def _check6(x, X, r, r0):
    """True if the six rows of x (6, 2), X (6, 3), r (6,) and r0 are all finite."""
    if not np.isfinite(r0):
        return False
    for i in range(6):
        if not (
            np.isfinite(x[i, 0])
            and np.isfinite(x[i, 1])
            and np.isfinite(r[i])
            and np.isfinite(X[i, 0])
            and np.isfinite(X[i, 1])
            and np.isfinite(X[i, 2])
        ):
            return False
    return True


_DEGENERATE = {
    1: "r6p: world points are coincident or collinear",
    2: "r6p: duplicated world points",
    3: "r6p: C and t are not separable (all RS coordinates r_i equal, or degenerate image points)",
    4: "r6p: rank-deficient elimination template (degenerate configuration)",
}


def r6p(
    x: np.ndarray, X: np.ndarray, r: np.ndarray | None = None, r0: float = 0.0
) -> list[RSSolution]:
    """All real solutions of the minimal rolling-shutter absolute pose problem R6P (eq. 5).

    Solves ``lambda_i [x_i; y_i; 1] = (I + (r_i - r0)[w]x)(I + [v]x) X_i + C + (r_i - r0) t``
    for the six correspondences exactly (Albl, Kukelova, Pajdla, "R6P - Rolling shutter absolute
    pose problem", CVPR 2015; model as eq. 5 of Kukelova et al., ACCV 2018). There are up to 20
    complex solutions; the real ones are returned.

    Method (see the module docstring): C and t are eliminated by the left null space of their
    12 x 6 coefficient block; the remaining 6 bilinear equations ``A(w) [1; v] = 0`` (A 6 x 4,
    affine in w) require the fifteen 4 x 4 minors of A(w) to vanish, i.e. 15 quartics in w.
    Their 15 x 35 coefficient matrix (one 15 x 15 elimination) yields the 20 x 20 multiplication
    matrix of a linear form in w on the basis of the 20 monomials of degree <= 3; its real
    eigenvectors give w, then v (6 x 3 least squares) and C, t (linear). Every root is polished
    by Newton steps on the 12 equations and kept if its residual is at machine precision.
    Coplanar world points are handled by a tiny lift off the plane (module docstring): roots
    are still exact, but a root can be missed (~1 % of random coplanar instances).

    Args:
        x: (6, 2) calibrated (undistorted, normalized) image points ``[x_i, y_i]`` in the camera
            optical frame (z forward).
        X: (6, 3) world points, any length unit.
        r: (6,) rolling-shutter coordinate of each observation (default ``x[:, 1]``, rows read
            top to bottom); ``w`` and ``t`` are rates per unit of ``r``.
        r0: reference RS coordinate (the pose ``v, C`` is the one at ``r = r0``).
    Returns:
        list of :class:`RSSolution` (possibly empty: no real root), sorted by increasing
        algebraic error. Each has ``v`` (3,) rad (``R ~ I + [v]x``, world -> camera), ``C`` (3,)
        translation in the camera frame in world units (``X_cam = R X + C``), ``w`` (3,) rad per
        unit r, ``t`` (3,) world units per unit r, ``iterations`` = Newton steps applied to that
        root and ``algebraic_error`` = RMS residual of eq. 5 (the quantity of
        :func:`._common.algebraic_error`, evaluated in compiled code). For generic data the
        number of real roots is even and at most 20.
    Raises:
        ValueError: wrong shapes, N != 6, NaN or inf in any input.
        DegenerateInputError (a ValueError): world points coincident, collinear or duplicated
            (two rows of X equal to 1e-10 of their spread), C and t not separable (all ``r_i``
            equal, or e.g. all image points equal), or numerical rank loss of the elimination
            template. The solver never
            returns NaN; "no real root" is an empty list.
    """
    f64 = np.float64
    if (
        type(x) is np.ndarray
        and type(X) is np.ndarray
        and x.dtype == f64
        and X.dtype == f64
        and x.shape == (6, 2)
        and X.shape == (6, 3)
        and x.flags.c_contiguous
        and X.flags.c_contiguous
        and r is None
        and type(r0) in (float, int)
    ):
        # fast path (the common call; same checks as check_inputs, one compiled call)
        r, r0 = x[:, 1].copy(), float(r0)
        if not _check6(x, X, r, r0):
            raise ValueError("r6p: inputs contain NaN or inf")
    else:
        x, X, r, r0 = check_inputs(x, X, r, r0, min_points=6, name="r6p")
        if len(x) != 6:
            raise ValueError(
                f"r6p: is a minimal solver and needs exactly 6 correspondences, got {len(x)}"
            )
    status, Z, its, err = _solve_core(x, X, r, r0)
    if status > 0:
        raise DegenerateInputError(_DEGENERATE[status])
    if status < 0:
        Z, its, err = _solve(x, X, r, r0)
    Z.setflags(write=False)  # the solutions' arrays are read-only views of Z
    return [
        RSSolution._trusted(Z[i, 0:3], Z[i, 6:9], Z[i, 3:6], Z[i, 9:12], int(its[i]), float(err[i]))
        for i in range(len(err))
        if math.isfinite(err[i])
    ]
