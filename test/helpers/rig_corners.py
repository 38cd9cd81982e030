"""A synthetic rig video's corners for the corner-level problems' tests (the package's
``RigCorners`` and the benchmarks' ``TagSLAMCorners``): three global-shutter cameras with known
mountings, a start off the truth, and the solved mountings' errors."""

from __future__ import annotations

import numpy as np

from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.trajectory import default_camera, default_rig

#: px, the corners' Gaussian noise
NOISE_PX = 0.5


def scene(seed: int, frames: int = 10, points: int = 30, noise: float = NOISE_PX):
    """Three cameras (front, left, right: the simulator's rig) on ``frames`` rig poses, each
    seeing ``points`` points 3-8 m away; returns the camera model, the truth (rig poses rig ->
    world, mountings camera -> rig), the corners ``(pixels with noise px of Gaussian noise,
    map points, rig frames, mountings)`` and the random generator, to go on drawing from."""
    rng = np.random.default_rng(seed)
    cam = default_camera(line_delay=0.0)
    rig = default_rig(3, (0.0,) * 4)
    Rm = np.array([c.R_rig_cam for c in rig])
    pm = np.array([c.p_rig_cam for c in rig])
    Rg = rotvec_to_matrix(rng.normal(0, 0.3, (frames, 3)))
    Pg = rng.normal(0, 1.0, (frames, 3))
    uv, X, f_idx, m_idx = [], [], [], []
    for g in range(frames):
        for m in range(3):
            xy = rng.uniform(-0.5, 0.5, (points, 2))
            x_cam = np.column_stack([xy, np.ones(points)]) * rng.uniform(3, 8, (points, 1))
            X.append((x_cam @ Rm[m].T + pm[m]) @ Rg[g].T + Pg[g])
            uv.append(cam.project(x_cam) + rng.normal(0, noise, (points, 2)))
            f_idx.append(np.full(points, g))
            m_idx.append(np.full(points, m))
    corners = tuple(np.concatenate(v) for v in (uv, X, f_idx, m_idx))
    return cam, (Rg, Pg), (Rm, pm), corners, rng


def _turned(R, rng, rad):
    return rotvec_to_matrix(rng.normal(0, rad, (len(R), 3))) @ R


def start(seed: int, **kw):
    """:func:`scene` (``kw``: its sizes) with a start to solve from: every rig pose turned by
    ~0.01 rad and moved by ~1 cm, the left and right mountings turned by ~0.01 rad and every
    camera's position moved by ~5 mm but the front camera's (the gauge). Returns the camera
    model, the corners ``(uv, X, frame, mounting)``, the start's rig poses and mountings (rig ->
    world, camera -> rig), the mountings adjusted (front fixed) and the true mountings."""
    cam, (Rg, Pg), (Rm, pm), corners, rng = scene(seed, **kw)
    start_m = (np.r_[Rm[:1], _turned(Rm[1:], rng, 0.01)], pm + rng.normal(0, 0.005, pm.shape))
    start_g = (_turned(Rg, rng, 0.01), Pg + rng.normal(0, 0.01, Pg.shape))
    start_m[1][0] = pm[0]
    return cam, corners, start_g, start_m, np.array([False, True, True]), (Rm, pm)


def mount_errors(mounts, truth):
    """(2, 6) the free (left, right) mountings' errors (rotation rad rig axes, position m) of
    ``mounts`` ``(R (3, 3, 3) camera -> rig, p (3, 3) m)`` against ``truth``."""
    R, p = mounts
    Rt, pt = truth
    return np.array([np.r_[matrix_to_rotvec(R[i] @ Rt[i].T), p[i] - pt[i]] for i in (1, 2)])
