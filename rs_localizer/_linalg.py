"""Small dense linear algebra as numba kernels (scalar loops, written for the 3x3 to 36x36
systems of the solvers, the refinement and the twist filter, where a LAPACK call's overhead
dominates the arithmetic): Gaussian elimination, Cholesky and LU for symmetric systems,
Householder QR least squares, and the EISPACK eigenvalue path (balance, reduction to
Hessenberg form, the shifted QR iteration, inverse iteration on the Hessenberg matrix) that
gives R6P the eigenvalues of its action matrix (Albl, Kukelova, Pajdla, "R6P - Rolling shutter
absolute pose problem", CVPR 2015). Every kernel is compiled once and cached (``cache=True``);
arrays are float64 and overwritten where the docstring says so.
"""

from __future__ import annotations

import numpy as np

from ._jit import kernel

__all__ = [
    "balance",
    "cholesky_into",
    "elmhes",
    "hessenberg_lu",
    "hessenberg_lu_solve",
    "householder_lstsq_into",
    "householder_qr",
    "hqr",
    "lu_solve",
    "solve_square",
    "solve_symmetric",
]


@kernel
def householder_qr(B, M, V, Rd):
    """In-place Householder QR of B (m, n), m >= n (R left in its upper triangle), applying
    Q^T to M (m, k) as well.

    Reflector k is stored in V[k:, k] (unit norm), R's diagonal in Rd. Returns min/max |R_kk|.
    """
    m, n = B.shape
    rmax = 0.0
    rmin = np.inf
    for k in range(n):
        s = 0.0
        for i in range(k, m):
            s += B[i, k] * B[i, k]
        nrm = np.sqrt(s)
        alpha = -nrm if B[k, k] > 0 else nrm
        for i in range(m):
            V[i, k] = 0.0
        for i in range(k, m):
            V[i, k] = B[i, k]
        V[k, k] -= alpha
        vn = 0.0
        for i in range(k, m):
            vn += V[i, k] * V[i, k]
        vn = np.sqrt(vn)
        if vn > 0.0:
            for i in range(k, m):
                V[i, k] /= vn
        for j in range(k, n):
            d = 0.0
            for i in range(k, m):
                d += V[i, k] * B[i, j]
            for i in range(k, m):
                B[i, j] -= 2.0 * d * V[i, k]
        for j in range(M.shape[1]):
            d = 0.0
            for i in range(k, m):
                d += V[i, k] * M[i, j]
            for i in range(k, m):
                M[i, j] -= 2.0 * d * V[i, k]
        Rd[k] = alpha
        rmax = max(rmax, abs(alpha))
        rmin = min(rmin, abs(alpha))
    return rmin / rmax if rmax > 0.0 else 0.0


@kernel
def householder_lstsq_into(Bqr, V, f, out):
    """Least squares ``B y = -f`` for B (m, n), m >= n, with the QR :func:`householder_qr` left
    in ``Bqr`` (R in its upper triangle) and ``V`` (m, n) (the reflectors): ``y`` (n,) goes to
    ``out``; ``f`` (m,) is overwritten by ``Q^T f``."""
    m, n = V.shape
    for k in range(n):
        d = 0.0
        for i in range(k, m):
            d += V[i, k] * f[i]
        for i in range(k, m):
            f[i] -= 2.0 * d * V[i, k]
    for k in range(n - 1, -1, -1):
        s = -f[k]
        for j in range(k + 1, n):
            s -= Bqr[k, j] * out[j]
        out[k] = s / Bqr[k, k]


@kernel
def balance(a, D):
    """Balance a square matrix in place (EISPACK balanc, radix 2), 1-based arrays:
    ``a_out = D^-1 a_in D`` with the diagonal D (n + 1,) returned in D."""
    n = a.shape[0] - 1
    done = False
    while not done:
        done = True
        for i in range(1, n + 1):
            r = 0.0
            c = 0.0
            for j in range(1, n + 1):
                if j != i:
                    c += abs(a[j, i])
                    r += abs(a[i, j])
            if c != 0.0 and r != 0.0:
                g = r / 2.0
                f = 1.0
                sm = c + r
                while c < g:
                    f *= 2.0
                    c *= 4.0
                g = r * 2.0
                while c > g:
                    f /= 2.0
                    c /= 4.0
                if (c + r) / f < 0.95 * sm:
                    done = False
                    g = 1.0 / f
                    D[i] *= f
                    for j in range(1, n + 1):
                        a[i, j] *= g
                    for j in range(1, n + 1):
                        a[j, i] *= f


@kernel
def elmhes(a, Z):
    """Reduce to upper Hessenberg form in place by stabilised elimination (EISPACK elmhes),
    1-based arrays. Accumulates the similarity: on return ``a_in Z = Z a_out``."""
    n = a.shape[0] - 1
    for m in range(2, n):
        x = 0.0
        i = m
        for j in range(m, n + 1):
            if abs(a[j, m - 1]) > abs(x):
                x = a[j, m - 1]
                i = j
        if i != m:
            for j in range(m - 1, n + 1):
                tmp = a[i, j]
                a[i, j] = a[m, j]
                a[m, j] = tmp
            for j in range(1, n + 1):
                tmp = a[j, i]
                a[j, i] = a[j, m]
                a[j, m] = tmp
                tmp = Z[j, i]
                Z[j, i] = Z[j, m]
                Z[j, m] = tmp
        if x != 0.0:
            for i in range(m + 1, n + 1):
                y = a[i, m - 1]
                if y != 0.0:
                    y /= x
                    a[i, m - 1] = 0.0
                    for j in range(m, n + 1):
                        a[i, j] -= y * a[m, j]
                    for j in range(1, n + 1):
                        a[j, m] += y * a[j, i]
                        Z[j, m] += y * Z[j, i]


@kernel
def hessenberg_lu(H, lam, T, swap):
    """LU factorisation of (H - lam I) for upper Hessenberg H (1-based, n x n, not modified) with
    partial pivoting (only rows k, k+1 compete): O(n^2). Factors go to T (multipliers in
    T[k+1, k]), row swaps to swap. Tiny pivots are replaced by 1e-15 max|H| (inverse iteration).
    """
    n = H.shape[0] - 1
    hmax = 0.0
    for i in range(1, n + 1):
        for j in range(max(i - 1, 1), n + 1):
            T[i, j] = H[i, j]
            hmax = max(hmax, abs(H[i, j]))
        T[i, i] -= lam
    floor = 1e-15 * max(hmax, abs(lam))
    if floor == 0.0:
        floor = 1e-300
    for k in range(1, n):
        swap[k] = False
        if abs(T[k + 1, k]) > abs(T[k, k]):
            swap[k] = True
            for j in range(k, n + 1):
                tmp = T[k, j]
                T[k, j] = T[k + 1, j]
                T[k + 1, j] = tmp
        if abs(T[k, k]) < floor:
            T[k, k] = floor
        f = T[k + 1, k] / T[k, k]
        T[k + 1, k] = f
        if f != 0.0:
            for j in range(k + 1, n + 1):
                T[k + 1, j] -= f * T[k, j]
    if abs(T[n, n]) < floor:
        T[n, n] = floor


@kernel
def hessenberg_lu_solve(T, swap, y):
    """Solve with the factors of :func:`hessenberg_lu`; y (n + 1,) overwritten (1-based)."""
    n = T.shape[0] - 1
    for k in range(1, n):
        if swap[k]:
            tmp = y[k]
            y[k] = y[k + 1]
            y[k + 1] = tmp
        y[k + 1] -= T[k + 1, k] * y[k]
    for k in range(n, 0, -1):
        sm = y[k]
        for j in range(k + 1, n + 1):
            sm -= T[k, j] * y[j]
        y[k] = sm / T[k, k]


@kernel
def hqr(a, wr, wi):
    """Eigenvalues of an upper Hessenberg matrix (1-based, destroyed) by the Francis double-shift
    QR algorithm (EISPACK hqr). Returns False if an eigenvalue needs more than 60 iterations."""
    n = a.shape[0] - 1
    anorm = 0.0
    for i in range(1, n + 1):
        for j in range(max(i - 1, 1), n + 1):
            anorm += abs(a[i, j])
    nn = n
    t = 0.0
    x = y = z = w = p = q = r = 0.0
    while nn >= 1:
        its = 0
        while True:
            ell = nn
            while ell >= 2:
                s = abs(a[ell - 1, ell - 1]) + abs(a[ell, ell])
                if s == 0.0:
                    s = anorm
                if abs(a[ell, ell - 1]) + s == s:
                    a[ell, ell - 1] = 0.0
                    break
                ell -= 1
            x = a[nn, nn]
            if ell == nn:  # one real root
                wr[nn] = x + t
                wi[nn] = 0.0
                nn -= 1
            else:
                y = a[nn - 1, nn - 1]
                w = a[nn, nn - 1] * a[nn - 1, nn]
                if ell == nn - 1:  # a 2 x 2 block: two roots
                    p = 0.5 * (y - x)
                    q = p * p + w
                    z = np.sqrt(abs(q))
                    x += t
                    if q >= 0.0:
                        z = p + (z if p >= 0.0 else -z)
                        wr[nn - 1] = x + z
                        wr[nn] = x + z
                        if z != 0.0:
                            wr[nn] = x - w / z
                        wi[nn - 1] = 0.0
                        wi[nn] = 0.0
                    else:
                        wr[nn - 1] = x + p
                        wr[nn] = x + p
                        wi[nn - 1] = -z
                        wi[nn] = z
                    nn -= 2
                else:
                    if its == 60:
                        return False
                    if its == 10 or its == 20 or its == 40:  # exceptional shift
                        t += x
                        for i in range(1, nn + 1):
                            a[i, i] -= x
                        s = abs(a[nn, nn - 1]) + abs(a[nn - 1, nn - 2])
                        x = 0.75 * s
                        y = x
                        w = -0.4375 * s * s
                    its += 1
                    m = nn - 2
                    while m >= ell:
                        z = a[m, m]
                        r = x - z
                        s = y - z
                        p = (r * s - w) / a[m + 1, m] + a[m, m + 1]
                        q = a[m + 1, m + 1] - z - r - s
                        r = a[m + 2, m + 1]
                        s = abs(p) + abs(q) + abs(r)
                        p /= s
                        q /= s
                        r /= s
                        if m == ell:
                            break
                        u = abs(a[m, m - 1]) * (abs(q) + abs(r))
                        v = abs(p) * (abs(a[m - 1, m - 1]) + abs(z) + abs(a[m + 1, m + 1]))
                        if u + v == v:
                            break
                        m -= 1
                    for i in range(m + 2, nn + 1):
                        a[i, i - 2] = 0.0
                        if i != m + 2:
                            a[i, i - 3] = 0.0
                    for k in range(m, nn):
                        if k != m:
                            p = a[k, k - 1]
                            q = a[k + 1, k - 1]
                            r = 0.0
                            if k != nn - 1:
                                r = a[k + 2, k - 1]
                            x = abs(p) + abs(q) + abs(r)
                            if x != 0.0:
                                p /= x
                                q /= x
                                r /= x
                        s = np.sqrt(p * p + q * q + r * r)
                        if p < 0.0:
                            s = -s
                        if s != 0.0:
                            if k == m:
                                if ell != m:
                                    a[k, k - 1] = -a[k, k - 1]
                            else:
                                a[k, k - 1] = -s * x
                            p += s
                            x = p / s
                            y = q / s
                            z = r / s
                            q /= p
                            r /= p
                            for j in range(k, nn + 1):
                                p = a[k, j] + q * a[k + 1, j]
                                if k != nn - 1:
                                    p += r * a[k + 2, j]
                                    a[k + 2, j] -= p * z
                                a[k + 1, j] -= p * y
                                a[k, j] -= p * x
                            mmin = nn if nn < k + 3 else k + 3
                            for i in range(ell, mmin + 1):
                                p = x * a[i, k] + y * a[i, k + 1]
                                if k != nn - 1:
                                    p += z * a[i, k + 2]
                                    a[i, k + 2] -= p * r
                                a[i, k + 1] -= p * q
                                a[i, k] -= p
            if not (ell < nn - 1):
                break
    return True


@kernel
def cholesky_into(A, n, L):
    """Cholesky factor of the leading n x n block of A (lower triangle read) into L[:n, :n]
    (lower triangle; the strict upper part is not written). False if A is not numerically
    positive definite."""
    for j in range(n):
        s = A[j, j]
        for p in range(j):
            s -= L[j, p] * L[j, p]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            L[i, j] = s / d
    return True


@kernel
def lu_solve(M, B, n, m):
    """Solve ``M Y = B`` in place (Y in B[:n, :m]) by Gaussian elimination with partial
    pivoting on the leading n x n block of M (destroyed): LAPACK gesv's method, which
    ``np.linalg.solve`` and ``np.linalg.inv`` use. False if M is exactly singular (their
    LinAlgError)."""
    for j in range(n):
        piv = j
        big = abs(M[j, j])
        for i in range(j + 1, n):
            if abs(M[i, j]) > big:
                big = abs(M[i, j])
                piv = i
        if M[piv, j] == 0.0:
            return False
        if piv != j:
            for c in range(n):
                M[j, c], M[piv, c] = M[piv, c], M[j, c]
            for c in range(m):
                B[j, c], B[piv, c] = B[piv, c], B[j, c]
        for i in range(j + 1, n):
            f = M[i, j] / M[j, j]
            for c in range(j + 1, n):
                M[i, c] -= f * M[j, c]
            for c in range(m):
                B[i, c] -= f * B[j, c]
    for c in range(m):
        for i in range(n - 1, -1, -1):
            s = B[i, c]
            for p in range(i + 1, n):
                s -= M[i, p] * B[p, c]
            B[i, c] = s / M[i, i]
    return True


@kernel
def solve_symmetric(A, B, n, m, L, M):
    """Solve ``A Y = B`` in place in B[:n, :m] for the symmetric n x n block of A: Cholesky,
    or pivoted LU (``np.linalg.solve``'s method) when A is not numerically positive definite.
    False (B undefined) only if A is exactly singular, where ``np.linalg.solve`` and ``inv``
    raise. L, M: (12, 12) workspace."""
    if not cholesky_into(A, n, L):
        for i in range(n):
            for j in range(n):
                M[i, j] = A[i, j]
        return lu_solve(M, B, n, m)
    for c in range(m):
        for i in range(n):  # L y = b
            s = B[i, c]
            for p in range(i):
                s -= L[i, p] * B[p, c]
            B[i, c] = s / L[i, i]
        for i in range(n - 1, -1, -1):  # L^T y' = y
            s = B[i, c]
            for p in range(i + 1, n):
                s -= L[p, i] * B[p, c]
            B[i, c] = s / L[i, i]
    return True


@kernel
def solve_square(A, b, u, tol):
    """Gaussian elimination with partial pivoting for square A (n, n); A, b overwritten; the
    solution goes to u (which may be b itself).

    Returns False if a pivot is at or below ``tol`` times the largest entry (``tol = 0``: only
    an exactly zero pivot fails).
    """
    n = A.shape[0]
    amax = 0.0
    for i in range(n):
        for j in range(n):
            if abs(A[i, j]) > amax:
                amax = abs(A[i, j])
    if amax == 0.0:
        return False
    for k in range(n):
        p = k
        pv = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > pv:
                pv = abs(A[i, k])
                p = i
        if pv <= tol * amax:
            return False
        if p != k:
            for j in range(k, n):
                tmp = A[k, j]
                A[k, j] = A[p, j]
                A[p, j] = tmp
            tmp = b[k]
            b[k] = b[p]
            b[p] = tmp
        inv = 1.0 / A[k, k]
        for i in range(k + 1, n):
            f = A[i, k] * inv
            if f != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= f * A[k, j]
                b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= A[k, j] * u[j]
        u[k] = s / A[k, k]
    return True
