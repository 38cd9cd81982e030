"""Numba helpers for SO(3) shared by the RANSAC scoring and the refinement kernels."""

from __future__ import annotations

import numpy as np
from numba.core import ir as _numba_ir

from ._jit import kernel

#: numba fast-math flags of the hot kernels: fused multiply-add only (no reassociation, and
#: NaN/inf semantics are kept, which the kernels rely on); ~30% faster scoring, results
#: change in the last bits only
FMA = {"contract"}

#: ``inline=`` of the small numba helpers: "always" (numba-IR inlining) where numba copies an
#: inlined callee's IR without deep-copying every variable's scope and location (numba >= 0.59,
#: which gave ``ir.Var`` its ``__deepcopy__``); "never" before (Debian 12's numba 0.56 took
#: > 20 min to compile the refinement kernel with "always", ~20 s without)
INLINE = "always" if hasattr(_numba_ir.Var, "__deepcopy__") else "never"


@kernel(inline=INLINE, fastmath=FMA)
def so3_coefficients(th2):
    """Rodrigues/left-Jacobian coefficients for an angle t with ``t^2 = th2``:
    ``(sin t / t, (1 - cos t) / t^2, (t - sin t) / t^3)``, so that
    ``expm([a]x) = I + c1 [a]x + c2 [a]x^2`` and ``J_l(a) = I + c2 [a]x + c3 [a]x^2``.
    Taylor series to t^8 below t = 0.2 (exact to rounding there), trigonometry above."""
    if th2 < 0.04:  # divisions by constants written as multiplications (hot path)
        c1 = 1.0 - th2 * (1.0 / 6.0) * (
            1.0 - th2 * (1.0 / 20.0) * (1.0 - th2 * (1.0 / 42.0) * (1.0 - th2 * (1.0 / 72.0)))
        )
        c2 = 0.5 * (
            1.0
            - th2
            * (1.0 / 12.0)
            * (1.0 - th2 * (1.0 / 30.0) * (1.0 - th2 * (1.0 / 56.0) * (1.0 - th2 * (1.0 / 90.0))))
        )
        c3 = (
            1.0
            - th2
            * (1.0 / 20.0)
            * (1.0 - th2 * (1.0 / 42.0) * (1.0 - th2 * (1.0 / 72.0) * (1.0 - th2 * (1.0 / 110.0))))
        ) * (1.0 / 6.0)
        return c1, c2, c3
    th = np.sqrt(th2)
    s = np.sin(th)
    return s / th, (1.0 - np.cos(th)) / th2, (th - s) / (th2 * th)


@kernel(inline=INLINE, fastmath=FMA)
def rotate_small(a0, a1, a2, q0, q1, q2):
    """``expm([a]x) q = q + c1 a x q + c2 a x (a x q)`` (Rodrigues) for a point q, with the
    coefficients ``(c1, c2, c3)`` of :func:`so3_coefficients` at ``a``: six scalars. The
    constant-velocity RS model places a point seen at ``tau`` at ``rotate_small(tau w, R X) +
    C + tau t`` (paper eq. 4, exact)."""
    c1, c2, c3 = so3_coefficients(a0 * a0 + a1 * a1 + a2 * a2)
    h0 = a1 * q2 - a2 * q1
    h1 = a2 * q0 - a0 * q2
    h2 = a0 * q1 - a1 * q0
    return (
        q0 + c1 * h0 + c2 * (a1 * h2 - a2 * h1),
        q1 + c1 * h1 + c2 * (a2 * h0 - a0 * h2),
        q2 + c1 * h2 + c2 * (a0 * h1 - a1 * h0),
        c1,
        c2,
        c3,
    )


@kernel(inline=INLINE, fastmath=FMA)
def rotate_left_into(a0, a1, a2, R, out):
    """``out = expm([a]x) R`` for R, out (3, 3) (Rodrigues)."""
    sa, ca, _ = so3_coefficients(a0 * a0 + a1 * a1 + a2 * a2)
    e00 = 1.0 - ca * (a1 * a1 + a2 * a2)
    e11 = 1.0 - ca * (a0 * a0 + a2 * a2)
    e22 = 1.0 - ca * (a0 * a0 + a1 * a1)
    e01 = -sa * a2 + ca * a0 * a1
    e10 = sa * a2 + ca * a0 * a1
    e02 = sa * a1 + ca * a0 * a2
    e20 = -sa * a1 + ca * a0 * a2
    e12 = -sa * a0 + ca * a1 * a2
    e21 = sa * a0 + ca * a1 * a2
    for j in range(3):
        r0, r1, r2 = R[0, j], R[1, j], R[2, j]
        out[0, j] = e00 * r0 + e01 * r1 + e02 * r2
        out[1, j] = e10 * r0 + e11 * r1 + e12 * r2
        out[2, j] = e20 * r0 + e21 * r1 + e22 * r2


@kernel(fastmath=FMA)
def compose_rotvec(v, R_pre):
    """(K, 3, 3) rotations ``expm([v_k]x) R_pre[k]`` (Rodrigues), the RS solvers' v applied
    on top of the pre-rotation."""
    K = v.shape[0]
    out = np.empty((K, 3, 3))
    for k in range(K):
        rotate_left_into(v[k, 0], v[k, 1], v[k, 2], R_pre[k], out[k])
    return out


@kernel(inline=INLINE)
def copy_matrix3(src, dst):
    """``dst[:, :] = src`` for 3 x 3 arrays, element by element. A slice assignment between
    arrays also compiles numba's shape-mismatch error with its string formatting (seconds of
    compiling on a cold start) for an error that cannot occur here."""
    for a in range(3):
        for b in range(3):
            dst[a, b] = src[a, b]


@kernel
def skew_matrix(v):
    """``[v]x`` (3, 3), a new array, of a 3-vector ``v`` (3,): ``[v]x a = v x a``."""
    S = np.zeros((3, 3))
    S[0, 1], S[0, 2], S[1, 2] = -v[2], v[1], -v[0]
    S[1, 0], S[2, 0], S[2, 1] = v[2], -v[1], v[0]
    return S


@kernel
def rotation_log_into(R, v):
    """``v`` (3,) = the rotation vector (axis times angle in [0, pi], rad) of the rotation
    matrix ``R`` (3, 3): from the antisymmetric part (``0.5 (R - R^T)`` below 1e-6 rad), and
    near pi, where that part vanishes, the axis from the symmetric part (the largest diagonal
    entry of ``(R + I) / 2``) signed by the antisymmetric part."""
    c = min(max(0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0), -1.0), 1.0)
    th = np.arccos(c)
    a0, a1, a2 = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    if th < np.pi - 1e-4:
        f = 0.5 if th < 1e-6 else 0.5 * th / np.sin(th)
        v[0], v[1], v[2] = a0 * f, a1 * f, a2 * f
        return
    k = 0
    for j in (1, 2):
        if R[j, j] > R[k, k]:
            k = j
    d = 0.5 * (R[k, k] + 1.0)
    s = np.sqrt(max(d, 1e-300))
    b0 = 0.5 * (R[0, k] + (1.0 if k == 0 else 0.0)) / s
    b1 = 0.5 * (R[1, k] + (1.0 if k == 1 else 0.0)) / s
    b2 = 0.5 * (R[2, k] + (1.0 if k == 2 else 0.0)) / s
    n = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    if b0 * a0 + b1 * a1 + b2 * a2 < 0:
        n = -n
    v[0], v[1], v[2] = b0 / n * th, b1 / n * th, b2 / n * th
