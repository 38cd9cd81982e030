"""Vectorized rolling-shutter renderer (numba) with exact ground truth.

Every image line is rendered from the camera pose at that line's capture time
``t_first + camera.line_time(line)``: per (sub)pixel the ray through the *distorted* pixel
(:meth:`CameraModel.undistort`, so lens distortion is exact) is intersected with every quad of the
scene, decals (markers, pictures) on the hit quad are looked up in a per-quad grid, and the
texture is sampled trilinearly from a mip-map pyramid (level from the pixel footprint). Options:
``supersample`` x ``supersample`` samples per pixel (anti-aliasing), exposure blur (poses at
``exposure_samples`` instants over the exposure, centred on the line time) and sensor noise
(read noise + shot noise). A global-shutter render uses the pose at the reference line's time
for every line.

Conventions: pixel centres at integer coordinates (OpenCV); line ``i`` is captured at
``t_first + line_time(i)``; ground truth (:class:`RenderedFrame`) is the pose at the reference
line (camera -> world orientation and camera centre, world z up) and the angular/linear velocity
in the camera optical frame, from :func:`rs_localizer.sim.trajectory.ground_truth`.

A rig's cameras are rendered as single cameras (:meth:`Renderer.render_sequence`) along the
rig's motion composed with each one's mounting
(:class:`~rs_localizer.sim.trajectory.MountedTrajectory`), with its own first-frame offset and
frame rate, their frames merged by stamp (:func:`render_rig_images`; with an image front end's
correspondences: :func:`render_rig_video`). Two rigs: :func:`rendered_rig` (1-4 cameras laid
out as :data:`rs_localizer.sim.synthetic.LAYOUTS`; the built-in scene ``apriltag_rig_room``,
tags on all four walls, gives every camera markers to see) and :func:`vga_rig` (1-3 cameras
looking front, left and right at the ``aruco_room`` walls: the image tests' rig,
:func:`render_rig_frames`).
"""

from __future__ import annotations

import functools
import heapq
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numba import prange

from ..._jit import kernel
from ...camera import CameraModel
from ..synthetic import LAYOUTS, READOUTS
from ..trajectory import (
    PLACES,
    RigCameraSim,
    RigFrameSim,
    RigTrajectory,
    Trajectory,
    ground_truth,
    project_rs,
)
from .motion import rig_trajectory
from .scene import Scene, load_scene

__all__ = [
    "CAMERA_PRESETS",
    "RIG_TIMING",
    "NoiseModel",
    "RenderedFrame",
    "Renderer",
    "camera_preset",
    "frame_times",
    "render_rig_frames",
    "render_rig_images",
    "render_rig_video",
    "rendered_rig",
    "vga_rig",
]

MAX_LEVELS = 16


# ------------------------------------------------------------------------------ cameras
#: name -> (width, height, fx, fy, cx, cy, D (plumb_bob), readout time s)
CAMERA_PRESETS = {
    # a 640x480 webcam/phone stream: ~63 deg horizontal FOV, mild barrel, 30 ms readout
    "vga": (640, 480, 520.0, 520.0, 319.6, 239.3, (0.055, -0.11, 3e-4, -2e-4, 0.035), 0.030),
    # a 1280x720 phone/action camera (as rs_localizer.sim.trajectory.default_camera), 25 ms readout
    "hd": (1280, 720, 1002.5, 1001.8, 641.3, 358.2, (0.062, -0.118, 4e-4, -3e-4, 0.041), 0.025),
}


def camera_preset(
    name: str = "vga",
    distortion: bool = True,
    readout_time: float | None = None,
    line_delay: float | None = None,
    reference_row: float | None = None,
    readout: str = "top_to_bottom",
) -> CameraModel:
    """A preset camera (``vga`` 640x480, ``hd`` 1280x720) with RS timing.

    ``line_delay`` (s/line) wins over ``readout_time`` (s/frame); ``line_delay=0`` gives a
    global shutter. Raises ValueError for an unknown preset."""
    if name not in CAMERA_PRESETS:
        raise ValueError(
            f"unknown camera preset {name!r}; expected one of {sorted(CAMERA_PRESETS)}"
        )
    w, h, fx, fy, cx, cy, D, ro = CAMERA_PRESETS[name]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    lines = h if readout in ("top_to_bottom", "bottom_to_top") else w
    if line_delay is None:
        line_delay = (ro if readout_time is None else readout_time) / lines
    return CameraModel(
        K=K,
        D=np.array(D) if distortion else np.zeros(0),
        width=w,
        height=h,
        line_delay=line_delay,
        readout=readout,
        reference_row=reference_row,
        distortion_model="plumb_bob",
    )


#: name -> (frame readout time s, first-frame offset s) of :func:`rendered_rig`'s cameras
#: (placed as :data:`~rs_localizer.sim.trajectory.PLACES`)
RIG_TIMING = {
    "front": (0.030, 0.000),
    "left": (0.025, 0.004),
    "right": (0.020, 0.009),
    "back": (0.028, 0.002),
}


def vga_rig(num_cameras: int = 3, offsets_s: tuple = (0.0, 0.004, 0.008)) -> list:
    """``num_cameras`` (1-3) 640x480 cameras (the ``vga`` preset, 30 ms readout) looking front,
    35 deg left and 35 deg right, 5-15 cm off the rig origin, readouts top-down, bottom-up and
    left-right (62.5, 62.5 and 46.9 us/line), first frames ``offsets_s`` apart, 30 fps: a rig
    that sees the ``aruco_room`` walls from its viewpoint
    (:class:`~rs_localizer.sim.trajectory.RigCameraSim` each).

    Raises:
        ValueError: ``num_cameras`` outside 1-3.
    """
    if not 1 <= num_cameras <= 3:
        raise ValueError(f"num_cameras must be 1-3, got {num_cameras}")
    spec = [
        ("front", 0.0, (0.10, 0.0, 0.05), "top_to_bottom"),
        ("left", 35.0, (0.0, 0.08, 0.06), "bottom_to_top"),
        ("right", -35.0, (0.0, -0.08, 0.06), "left_to_right"),
    ]
    return [
        RigCameraSim.facing(name, camera_preset("vga", readout=readout), yaw, pos, offsets_s[k])
        for k, (name, yaw, pos, readout) in enumerate(spec[:num_cameras])
    ]


def rendered_rig(
    num_cameras: int = 3,
    fps: float = 30.0,
    names: tuple[str, ...] | None = None,
    camera: str | Sequence[str] = "vga",
) -> list[RigCameraSim]:
    """``num_cameras`` (1-4) cameras laid out as :data:`rs_localizer.sim.synthetic.LAYOUTS` (2:
    front, back; 3: front, left, right; 4: front, right, back, left), each the ``camera``
    preset (default 640x480, mild plumb_bob distortion; a sequence: one preset per camera, in
    layout order, e.g. ``("hd", "vga", "vga")``) placed as
    :data:`~rs_localizer.sim.trajectory.PLACES`, with its :data:`RIG_TIMING` readout
    time (30, 25, 20, 28 ms: front, left, right, back) over its lines, the readout directions
    of :data:`rs_localizer.sim.synthetic.READOUTS` in layout order (top-down, left-right,
    bottom-up, right-left), and first frames 0-9 ms apart (unsynchronized).

    Raises:
        ValueError: ``num_cameras`` outside 1-4, an unknown name, or a sequence of presets of
            another length than the cameras.
    """
    if names is None:
        if num_cameras not in LAYOUTS:
            raise ValueError(f"a rendered rig has 1 to 4 cameras, got {num_cameras}")
        names = tuple(n for n, _ in LAYOUTS[num_cameras])
    presets = [camera] * len(names) if isinstance(camera, str) else list(camera)
    if len(presets) != len(names):
        raise ValueError(
            f"{len(presets)} camera presets {presets} for the {len(names)} cameras {list(names)}"
        )
    out = []
    for k, name in enumerate(names):
        if name not in RIG_TIMING:
            raise ValueError(f"unknown rig camera {name!r}; expected one of {sorted(RIG_TIMING)}")
        readout_time, offset = RIG_TIMING[name]
        cam = camera_preset(presets[k], readout_time=readout_time, readout=READOUTS[k % 4])
        out.append(RigCameraSim.facing(name, cam, *PLACES[name], offset, fps))
    return out


# ------------------------------------------------------------------------------ packing
@dataclass
class _Packed:
    qo: np.ndarray
    qu: np.ndarray
    qv: np.ndarray
    qn: np.ndarray
    qsize: np.ndarray
    qtex: np.ndarray
    qtexel: np.ndarray
    gcell: np.ndarray
    gdim: np.ndarray
    goff: np.ndarray
    gcells: np.ndarray
    drect: np.ndarray
    dtex: np.ndarray
    dtexel: np.ndarray
    tbuf: np.ndarray
    tinfo: np.ndarray
    tnl: np.ndarray
    bg: np.ndarray

    def quad_args(self):
        return (self.qo, self.qu, self.qv, self.qn, self.qsize)

    def all_args(self):
        return (
            self.qo,
            self.qu,
            self.qv,
            self.qn,
            self.qsize,
            self.qtex,
            self.qtexel,
            self.gcell,
            self.gdim,
            self.goff,
            self.gcells,
            self.drect,
            self.dtex,
            self.dtexel,
            self.tbuf,
            self.tinfo,
            self.tnl,
            self.bg,
        )


def _pyramid(tex: np.ndarray):
    levels = [np.ascontiguousarray(tex, dtype=np.uint8)]
    while max(levels[-1].shape[:2]) > 1 and len(levels) < MAX_LEVELS:
        h, w = levels[-1].shape[:2]
        nxt = cv2.resize(
            levels[-1], (max((w + 1) // 2, 1), max((h + 1) // 2, 1)), interpolation=cv2.INTER_AREA
        )
        levels.append(np.ascontiguousarray(nxt.reshape(nxt.shape[0], nxt.shape[1], 3)))
    return levels


def _pack(scene: Scene) -> _Packed:
    """Flatten a scene into numba-friendly arrays (cached on the scene)."""
    if scene.render_cache is not None:
        return scene.render_cache
    tex_ids = {}
    textures = []

    def add_tex(img):
        key = id(img)
        if key not in tex_ids:
            tex_ids[key] = len(textures)
            textures.append(img)
        return tex_ids[key]

    Q = len(scene.quads)
    qo = np.array([q.origin for q in scene.quads], float).reshape(Q, 3)
    qu = np.array([q.u for q in scene.quads], float).reshape(Q, 3)
    qv = np.array([q.v for q in scene.quads], float).reshape(Q, 3)
    qn = np.cross(qv, qu)
    qsize = np.array([q.size for q in scene.quads], float).reshape(Q, 2)
    qtex = np.array([add_tex(q.texture) for q in scene.quads], np.int64)
    qtexel = np.array(
        [
            math.sqrt(q.size[0] / q.texture.shape[1] * q.size[1] / q.texture.shape[0])
            for q in scene.quads
        ]
    )
    M = len(scene.decals)
    drect = np.array([d.rect for d in scene.decals], float).reshape(M, 4)
    dtex = np.array([add_tex(d.texture) for d in scene.decals], np.int64)
    dtexel = np.array(
        [
            math.sqrt(
                (d.rect[2] - d.rect[0])
                / d.texture.shape[1]
                * (d.rect[3] - d.rect[1])
                / d.texture.shape[0]
            )
            for d in scene.decals
        ]
    )
    # per-quad uniform grid of decal indices
    gcell = np.ones(Q)
    gdim = np.ones((Q, 2), np.int64)
    goff = np.zeros(Q, np.int64)
    lists = []
    for qi in range(Q):
        mine = [k for k, d in enumerate(scene.decals) if d.quad == qi]
        cell = min(
            [
                min(
                    scene.decals[k].rect[2] - scene.decals[k].rect[0],
                    scene.decals[k].rect[3] - scene.decals[k].rect[1],
                )
                for k in mine
            ]
            + [max(qsize[qi])]
        )
        nx = max(int(math.ceil(qsize[qi, 0] / cell)), 1)
        ny = max(int(math.ceil(qsize[qi, 1] / cell)), 1)
        gcell[qi], gdim[qi] = cell, (nx, ny)
        goff[qi] = len(lists)
        cells = [[] for _ in range(nx * ny)]
        for k in mine:
            a0, b0, a1, b1 = scene.decals[k].rect
            for gy in range(max(int(b0 // cell), 0), min(int(b1 // cell), ny - 1) + 1):
                for gx in range(max(int(a0 // cell), 0), min(int(a1 // cell), nx - 1) + 1):
                    cells[gy * nx + gx].append(k)
        lists.extend(cells)
    maxd = max([len(c) for c in lists] + [1])
    gcells = np.full((len(lists), maxd), -1, np.int32)
    for i, c in enumerate(lists):
        gcells[i, : len(c)] = c
    # texture pyramids in one buffer
    chunks, tinfo, tnl, off = [], np.zeros((len(textures), MAX_LEVELS, 3), np.int64), [], 0
    for t, img in enumerate(textures):
        levels = _pyramid(img)
        tnl.append(len(levels))
        for L, lv in enumerate(levels):
            tinfo[t, L] = (off, lv.shape[1], lv.shape[0])
            chunks.append(lv.ravel())
            off += lv.size
    packed = _Packed(
        qo,
        qu,
        qv,
        qn,
        qsize,
        qtex,
        qtexel,
        gcell,
        gdim,
        goff,
        gcells,
        drect,
        dtex,
        dtexel,
        np.concatenate(chunks),
        tinfo,
        np.array(tnl, np.int64),
        np.asarray(scene.background, float),
    )
    scene.render_cache = packed
    return packed


# ------------------------------------------------------------------------------ kernels
@kernel(fastmath=True)
def _bilinear(tbuf, tinfo, t, L, sx, sy):
    off, w, h = tinfo[t, L, 0], tinfo[t, L, 1], tinfo[t, L, 2]
    x = sx * w - 0.5
    y = sy * h - 0.5
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    xa = min(max(int(x0), 0), w - 1)
    xb = min(max(int(x0) + 1, 0), w - 1)
    ya = min(max(int(y0), 0), h - 1)
    yb = min(max(int(y0) + 1, 0), h - 1)
    i00 = off + (ya * w + xa) * 3
    i01 = off + (ya * w + xb) * 3
    i10 = off + (yb * w + xa) * 3
    i11 = off + (yb * w + xb) * 3
    w00 = (1 - fx) * (1 - fy)
    w01 = fx * (1 - fy)
    w10 = (1 - fx) * fy
    w11 = fx * fy
    r = w00 * tbuf[i00] + w01 * tbuf[i01] + w10 * tbuf[i10] + w11 * tbuf[i11]
    g = w00 * tbuf[i00 + 1] + w01 * tbuf[i01 + 1] + w10 * tbuf[i10 + 1] + w11 * tbuf[i11 + 1]
    b = w00 * tbuf[i00 + 2] + w01 * tbuf[i01 + 2] + w10 * tbuf[i10 + 2] + w11 * tbuf[i11 + 2]
    return r, g, b


@kernel(fastmath=True)
def _trilinear(tbuf, tinfo, tnl, t, lod, sx, sy):
    nl = tnl[t]
    if lod <= 0.0:
        return _bilinear(tbuf, tinfo, t, 0, sx, sy)
    L = int(lod)
    if nl - 1 <= L:
        return _bilinear(tbuf, tinfo, t, nl - 1, sx, sy)
    f = lod - L
    r0, g0, b0 = _bilinear(tbuf, tinfo, t, L, sx, sy)
    r1, g1, b1 = _bilinear(tbuf, tinfo, t, L + 1, sx, sy)
    return r0 + f * (r1 - r0), g0 + f * (g1 - g0), b0 + f * (b1 - b0)


@kernel(fastmath=True)
def _intersect(o0, o1, o2, d0, d1, d2, qo, qu, qv, qn, qsize):
    """Nearest quad hit of the ray o + lam d (lam > 0). Returns (quad or -1, lam, a, b, cos)."""
    best = np.inf
    bq = -1
    ba = 0.0
    bb = 0.0
    bcos = 1.0
    dn = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    for q in range(qo.shape[0]):
        den = qn[q, 0] * d0 + qn[q, 1] * d1 + qn[q, 2] * d2
        if abs(den) < 1e-12:
            continue
        e0 = qo[q, 0] - o0
        e1 = qo[q, 1] - o1
        e2 = qo[q, 2] - o2
        lam = (qn[q, 0] * e0 + qn[q, 1] * e1 + qn[q, 2] * e2) / den
        if lam <= 1e-9 or lam >= best:
            continue
        r0 = o0 + lam * d0 - qo[q, 0]
        r1 = o1 + lam * d1 - qo[q, 1]
        r2 = o2 + lam * d2 - qo[q, 2]
        a = r0 * qu[q, 0] + r1 * qu[q, 1] + r2 * qu[q, 2]
        b = r0 * qv[q, 0] + r1 * qv[q, 1] + r2 * qv[q, 2]
        if a >= 0.0 and a <= qsize[q, 0] and b >= 0.0 and b <= qsize[q, 1]:
            best = lam
            bq = q
            ba = a
            bb = b
            bcos = abs(den) / dn
    return bq, best, ba, bb, bcos


@kernel(parallel=True, fastmath=True)
def _render_kernel(
    dirs,
    ss,
    axis,
    Rs,
    ps,
    inv_f,
    qo,
    qu,
    qv,
    qn,
    qsize,
    qtex,
    qtexel,
    gcell,
    gdim,
    goff,
    gcells,
    drect,
    dtex,
    dtexel,
    tbuf,
    tinfo,
    tnl,
    bg,
    out,
):
    H = out.shape[0]
    W = out.shape[1]
    K = Rs.shape[0]
    maxd = gcells.shape[1]
    norm = 1.0 / (K * ss * ss)
    for py in prange(H):
        for px in range(W):
            line = np.int64(0)
            if axis == 1:
                line = np.int64(py)
            elif axis == 0:
                line = np.int64(px)
            ar = 0.0
            ag = 0.0
            ab = 0.0
            for k in range(K):
                o0 = ps[k, line, 0]
                o1 = ps[k, line, 1]
                o2 = ps[k, line, 2]
                for sy in range(ss):
                    for sx in range(ss):
                        c0 = dirs[py * ss + sy, px * ss + sx, 0]
                        c1 = dirs[py * ss + sy, px * ss + sx, 1]
                        d0 = Rs[k, line, 0, 0] * c0 + Rs[k, line, 0, 1] * c1 + Rs[k, line, 0, 2]
                        d1 = Rs[k, line, 1, 0] * c0 + Rs[k, line, 1, 1] * c1 + Rs[k, line, 1, 2]
                        d2 = Rs[k, line, 2, 0] * c0 + Rs[k, line, 2, 1] * c1 + Rs[k, line, 2, 2]
                        q, lam, a, b, cs = _intersect(o0, o1, o2, d0, d1, d2, qo, qu, qv, qn, qsize)
                        if q < 0:
                            ar += bg[0]
                            ag += bg[1]
                            ab += bg[2]
                            continue
                        t = qtex[q]
                        sxn = a / qsize[q, 0]
                        syn = b / qsize[q, 1]
                        texel = qtexel[q]
                        gx = min(int(a / gcell[q]), gdim[q, 0] - 1)
                        gy = min(int(b / gcell[q]), gdim[q, 1] - 1)
                        cell = goff[q] + gy * gdim[q, 0] + gx
                        for m in range(maxd):
                            di = gcells[cell, m]
                            if di < 0:
                                break
                            if (
                                a >= drect[di, 0]
                                and a <= drect[di, 2]
                                and b >= drect[di, 1]
                                and b <= drect[di, 3]
                            ):
                                t = dtex[di]
                                sxn = (a - drect[di, 0]) / (drect[di, 2] - drect[di, 0])
                                syn = (b - drect[di, 1]) / (drect[di, 3] - drect[di, 1])
                                texel = dtexel[di]
                        fp = lam * inv_f / ss / math.sqrt(max(cs, 0.02))
                        lod = np.log2(max(fp / texel, 1e-6))  # (numba < 0.60: no math.log2)
                        r, g, bb = _trilinear(tbuf, tinfo, tnl, t, lod, sxn, syn)
                        ar += r
                        ag += g
                        ab += bb
            out[py, px, 0] = ar * norm
            out[py, px, 1] = ag * norm
            out[py, px, 2] = ab * norm


@kernel(parallel=True)
def _cast_kernel(dirs, lines, Rs, ps, qo, qu, qv, qn, qsize, X, quad, depth):
    for i in prange(dirs.shape[0]):
        L = lines[i]
        c0 = dirs[i, 0]
        c1 = dirs[i, 1]
        c2 = dirs[i, 2]
        d0 = Rs[L, 0, 0] * c0 + Rs[L, 0, 1] * c1 + Rs[L, 0, 2] * c2
        d1 = Rs[L, 1, 0] * c0 + Rs[L, 1, 1] * c1 + Rs[L, 1, 2] * c2
        d2 = Rs[L, 2, 0] * c0 + Rs[L, 2, 1] * c1 + Rs[L, 2, 2] * c2
        q, lam, _a, _b, _cs = _intersect(
            ps[L, 0], ps[L, 1], ps[L, 2], d0, d1, d2, qo, qu, qv, qn, qsize
        )
        quad[i] = q
        if q < 0:
            X[i, 0] = np.nan
            X[i, 1] = np.nan
            X[i, 2] = np.nan
            depth[i] = np.nan
        else:
            X[i, 0] = ps[L, 0] + lam * d0
            X[i, 1] = ps[L, 1] + lam * d1
            X[i, 2] = ps[L, 2] + lam * d2
            depth[i] = lam


# ------------------------------------------------------------------------------ rays
@functools.lru_cache(maxsize=8)
def _rays_cached(key, ss):
    K, D, w, h, model = key
    cam = CameraModel(
        K=np.frombuffer(K).reshape(3, 3),
        D=np.frombuffer(D),
        width=w,
        height=h,
        distortion_model=model,
    )
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    us = (np.arange(w)[:, None] + offs[None, :]).ravel()
    vs = (np.arange(h)[:, None] + offs[None, :]).ravel()
    uu, vv = np.meshgrid(us, vs)
    xy = cam.undistort(np.stack([uu.ravel(), vv.ravel()], axis=1))
    rays = np.ones((h * ss, w * ss, 3))
    rays[:, :, :2] = xy.reshape(h * ss, w * ss, 2)
    rays.setflags(write=False)
    return rays


def camera_rays(camera: CameraModel, supersample: int = 1) -> np.ndarray:
    """(H*s, W*s, 3) camera-frame ray directions ``(x, y, 1)`` of the (sub)pixel samples: the
    undistorted normalized coordinates of each distorted pixel position (cached)."""
    key = (
        camera.K.tobytes(),
        camera.D.tobytes(),
        camera.width,
        camera.height,
        camera.distortion_model,
    )
    return _rays_cached(key, int(supersample))


# ------------------------------------------------------------------------------ frames
@dataclass(frozen=True)
class NoiseModel:
    """Sensor noise in 8-bit digital numbers: ``sigma^2 = read^2 + shot_gain * value``."""

    read: float = 1.0
    shot_gain: float = 0.05

    def apply(self, img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        sigma = np.sqrt(self.read**2 + self.shot_gain * np.clip(img, 0, None))
        return img + rng.standard_normal(img.shape, dtype=np.float32) * sigma


def frame_times(index: int | np.ndarray, fps: float = 30.0, t0: float = 0.0) -> np.ndarray:
    """Capture time (s) of the first line of frame ``index`` at ``fps``."""
    return t0 + np.asarray(index, dtype=float) / fps


@dataclass
class RenderedFrame:
    """One rendered image with ground truth.

    ``image``: (H, W, 3) uint8 RGB (or (H, W) mono8). ``t_first``: capture time (s) of the
    first line read out; ``t_ref``: of the reference line; ``line_times``: (lines,) capture time
    of every line (s; rows for vertical readout). ``orientation`` (camera -> world) and
    ``position`` (camera centre, world) at ``t_ref``; ``angular_velocity``/``linear_velocity``:
    camera optical frame (rad/s, m/s) at ``t_ref``. ``shutter``: ``rolling`` or ``global``
    (then every line is captured at ``t_ref``).
    """

    index: int
    image: np.ndarray
    t_first: float
    t_ref: float
    line_times: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    shutter: str = "rolling"

    @property
    def R(self) -> np.ndarray:
        """World -> camera rotation at the reference line (``X_cam = R X + C``)."""
        return self.orientation.T

    @property
    def C(self) -> np.ndarray:
        return -self.orientation.T @ self.position

    def stamp_ns(
        self, t0_ns: int = 0, row: float | None = None, camera: CameraModel | None = None
    ) -> int:
        """Header stamp: capture time of the first line (or of ``row`` given ``camera``)."""
        t = self.t_first if row is None else self.t_first + float(camera.line_time(row))
        return int(t0_ns) + int(round(t * 1e9))


class Renderer:
    """Rolling-shutter renderer of a :class:`Scene` seen by a :class:`CameraModel`.

    Args:
        scene: the scene. camera: intrinsics, distortion and RS timing.
        supersample: samples per pixel along each axis (2 = 4 samples, default).
        exposure: exposure time (s) for motion blur (0 = none); exposure_samples: poses per
            exposure (default: ~2 per pixel of blur, at most 16).
        noise: :class:`NoiseModel` or None.
    """

    def __init__(
        self,
        scene: Scene,
        camera: CameraModel,
        supersample: int = 2,
        exposure: float = 0.0,
        exposure_samples: int | None = None,
        noise: NoiseModel | None = None,
    ):
        if supersample < 1:
            raise ValueError("supersample must be >= 1")
        if exposure < 0:
            raise ValueError("exposure must be >= 0")
        self.scene = scene
        self.camera = camera
        self.supersample = int(supersample)
        self.exposure = float(exposure)
        self.exposure_samples = exposure_samples
        self.noise = noise
        self.packed = _pack(scene)

    # ---------------------------------------------------------------- timing
    @property
    def _axis(self) -> int:
        return 1 if self.camera.readout in ("top_to_bottom", "bottom_to_top") else 0

    def line_times(self, t_first: float, shutter: str = "rolling") -> np.ndarray:
        """(lines,) capture time (s) of every line."""
        cam = self.camera
        if shutter == "global":
            return np.full(cam.lines, t_first + float(cam.line_time(cam.reference_line)))
        return t_first + cam.line_time(np.arange(cam.lines))

    def _poses(self, motion, t_first, shutter, exposure, n_exp):
        if shutter == "global":
            t_lines = np.array([t_first + float(self.camera.line_time(self.camera.reference_line))])
        elif shutter == "rolling":
            t_lines = self.line_times(t_first)
        else:
            raise ValueError(f"shutter must be 'rolling' or 'global', got {shutter!r}")
        offs = exposure * ((np.arange(n_exp) + 0.5) / n_exp - 0.5) if exposure > 0 else np.zeros(1)
        t = offs[:, None] + t_lines[None, :]
        R, p = motion.pose(t)
        return np.ascontiguousarray(R, dtype=np.float64), np.ascontiguousarray(p, dtype=np.float64)

    # ---------------------------------------------------------------- rendering
    def render_image(
        self,
        motion: Trajectory,
        t_first: float,
        shutter: str = "rolling",
        exposure: float | None = None,
    ) -> np.ndarray:
        """(H, W, 3) float32 noise-free RGB in [0, 255] for the frame starting at ``t_first``."""
        exposure = self.exposure if exposure is None else float(exposure)
        n_exp = 1
        if exposure > 0:
            if self.exposure_samples is not None:
                n_exp = int(self.exposure_samples)
            else:
                w, v = motion.velocity_body(t_first)
                blur_px = (
                    (np.linalg.norm(w) + np.linalg.norm(v) / 2.0)
                    * exposure
                    * self.camera.mean_focal
                )
                n_exp = int(np.clip(np.ceil(2.0 * blur_px), 1, 16))
        Rs, ps = self._poses(motion, t_first, shutter, exposure, n_exp)
        cam = self.camera
        out = np.empty((cam.height, cam.width, 3), np.float32)
        axis = -1 if shutter == "global" else self._axis
        _render_kernel(
            camera_rays(cam, self.supersample),
            self.supersample,
            axis,
            Rs,
            ps,
            1.0 / cam.mean_focal,
            *self.packed.all_args(),
            out,
        )
        return out

    def render_pose(
        self, orientation: np.ndarray, position: np.ndarray, mono: bool = False
    ) -> np.ndarray:
        """Noise-free uint8 image from one fixed pose (camera -> world orientation, camera
        centre): a global-shutter view, e.g. for building a feature map."""
        cam = self.camera
        Rs = np.ascontiguousarray(np.asarray(orientation, float).reshape(1, 1, 3, 3))
        ps = np.ascontiguousarray(np.asarray(position, float).reshape(1, 1, 3))
        out = np.empty((cam.height, cam.width, 3), np.float32)
        _render_kernel(
            camera_rays(cam, self.supersample),
            self.supersample,
            -1,
            Rs,
            ps,
            1.0 / cam.mean_focal,
            *self.packed.all_args(),
            out,
        )
        img = np.clip(np.rint(out), 0, 255).astype(np.uint8)
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if mono else img

    def render(
        self,
        motion: Trajectory,
        t_first: float = 0.0,
        index: int = 0,
        shutter: str = "rolling",
        mono: bool = False,
        rng: np.random.Generator | None = None,
        exposure: float | None = None,
    ) -> RenderedFrame:
        """Render one frame (uint8, with noise if configured) and its ground truth."""
        img = self.render_image(motion, t_first, shutter, exposure)
        if self.noise is not None:
            rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
            img = self.noise.apply(img, rng)
        img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        if mono:
            img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        R, p, w, v, t_ref = ground_truth(self.camera, motion, t_first)
        return RenderedFrame(
            index=int(index),
            image=img,
            t_first=float(t_first),
            t_ref=float(t_ref),
            line_times=self.line_times(t_first, shutter),
            orientation=R,
            position=p,
            angular_velocity=w,
            linear_velocity=v,
            shutter=shutter,
        )

    def render_sequence(
        self,
        motion: Trajectory,
        frames: int,
        fps: float = 30.0,
        t0: float = 0.0,
        shutter: str = "rolling",
        mono: bool = False,
        seed: int | tuple = 0,
    ) -> Iterator[RenderedFrame]:
        """Yield :class:`RenderedFrame` for frames ``0..frames-1`` (first line at
        ``t0 + k / fps``); noise is seeded per frame from ``seed`` (an int or a tuple of them:
        frame k's generator is seeded by ``[*seed, k]``)."""
        key = [seed] if np.isscalar(seed) else list(seed)
        for k in range(int(frames)):
            yield self.render(
                motion,
                float(frame_times(k, fps, t0)),
                index=k,
                shutter=shutter,
                mono=mono,
                rng=np.random.default_rng([*key, k]),
            )

    # ---------------------------------------------------------------- geometry
    def cast(
        self,
        points_px: np.ndarray,
        motion: Trajectory | None = None,
        t_first: float = 0.0,
        shutter: str = "rolling",
        pose: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World points seen at (distorted) pixels: ray casting with the pose of each pixel's
        line (or a fixed ``pose=(orientation cam->world, position)``).

        Returns:
            (X (N, 3), quad (N,) int, -1 = nothing hit (X nan), depth (N,) camera z).
        """
        uv = np.asarray(points_px, dtype=float).reshape(-1, 2)
        cam = self.camera
        xy = cam.undistort(uv)
        dirs = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        if pose is not None:
            Rs = np.asarray(pose[0], float).reshape(1, 3, 3)
            ps = np.asarray(pose[1], float).reshape(1, 3)
            lines = np.zeros(len(uv), np.int64)
        elif shutter == "global":
            Rs, ps = self._poses(motion, t_first, "global", 0.0, 1)
            Rs, ps = Rs[0], ps[0]
            lines = np.zeros(len(uv), np.int64)
        else:
            # the line (row for vertical readout) a pixel sits on, as the renderer does
            line_f = np.clip(np.rint(uv[:, self._axis]), 0, cam.lines - 1)
            t = t_first + cam.line_time(line_f)
            Rs, ps = motion.pose(t)
            lines = np.arange(len(uv), dtype=np.int64)
        X = np.empty((len(uv), 3))
        quad = np.empty(len(uv), np.int64)
        depth = np.empty(len(uv))
        p = self.packed
        _cast_kernel(
            np.ascontiguousarray(dirs),
            lines,
            np.ascontiguousarray(Rs, dtype=float),
            np.ascontiguousarray(ps, dtype=float),
            p.qo,
            p.qu,
            p.qv,
            p.qn,
            p.qsize,
            X,
            quad,
            depth,
        )
        return X, quad, depth

    def hit_map(
        self, motion: Trajectory, t_first: float = 0.0, shutter: str = "rolling"
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-pixel (pixel centres) world points (H, W, 3), quad ids (H, W), depth (H, W)."""
        cam = self.camera
        vv, uu = np.mgrid[0 : cam.height, 0 : cam.width]
        X, q, d = self.cast(
            np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float), motion, t_first, shutter
        )
        return (
            X.reshape(cam.height, cam.width, 3),
            q.reshape(cam.height, cam.width),
            d.reshape(cam.height, cam.width),
        )

    def project(
        self,
        X: np.ndarray,
        motion: Trajectory,
        t_first: float = 0.0,
        shutter: str = "rolling",
        occlusion: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Exact projection of world points into the frame: each point at the capture time of
        its own line (:func:`rs_localizer.sim.trajectory.project_rs`), or with the reference pose
        for a global shutter. With ``occlusion``, points hidden behind a quad are dropped.

        Returns:
            (uv (N, 2) distorted pixels, ok (N,) bool: in front, inside the image, visible).
        """
        X = np.asarray(X, dtype=float).reshape(-1, 3)
        cam = self.camera
        if shutter == "global":
            R, p, _, _, _ = ground_truth(cam, motion, t_first)
            Xc = (X - p) @ R
            ok = Xc[:, 2] > 1e-6
            uv = np.full((len(X), 2), np.nan)
            uv[ok] = cam.distort(Xc[ok, :2] / Xc[ok, 2:])
            ok &= np.isfinite(uv).all(axis=1) & cam.in_image(np.nan_to_num(uv, nan=-1e9))
        else:
            uv, ok = project_rs(cam, motion, t_first, X)
        if occlusion and ok.any():
            idx = np.flatnonzero(ok)
            Xh, _, _ = self.cast(uv[idx], motion, t_first, shutter)
            err = np.linalg.norm(Xh - X[idx], axis=1)
            vis = err < 1e-3 * (1 + np.linalg.norm(X[idx], axis=1))  # nan (no hit) -> False
            ok[idx[~vis]] = False
        uv = np.where(ok[:, None], uv, np.nan)
        return uv, ok


# ------------------------------------------------------------------------------ rigs
def _duration(cameras: list[RigCameraSim], frames: int) -> float:
    """s of rig time until the last camera's last frame starts."""
    return max(c.offset + frames / c.fps for c in cameras)


def render_rig_images(
    cameras: list[RigCameraSim],
    scene: Scene,
    trajectory: RigTrajectory,
    frames: int,
    *,
    t0_ns: int = 1_700_000_000_000_000_000,
    stamp_row: float = 0.0,
    supersample: int = 2,
    noise: bool = True,
    seed: int = 0,
    mono: bool = False,
) -> Iterator[RigFrameSim]:
    """Yield every camera's rendered images (``frames`` per camera), sorted by stamp (then by
    camera, in ``cameras`` order), rendered as they are asked for (each camera's next frame
    ahead): a :class:`~rs_localizer.sim.trajectory.RigFrameSim` with its ``image`` ((H, W, 3)
    uint8 RGB, or (H, W) mono8), ``render_s`` (CPU s), the rig's pose at its reference line and
    no correspondences.

    Camera c's frames are :meth:`Renderer.render_sequence` along ``trajectory`` composed with
    its mounting, frame k's first line read at rig time ``c.offset + k / c.fps`` (rig time t is
    stamped ``t0_ns + t * 1e9`` ns; the header stamp is the capture time of line
    ``stamp_row``), its noise seeded by ``(seed, c's index)``.

    Args:
        cameras: the rig (:func:`rendered_rig`, :func:`vga_rig`). scene: the scene.
        trajectory: the rig's motion (:func:`~rs_localizer.sim.render.motion.rig_trajectory`).
        supersample: anti-aliasing samples per axis. noise: sensor noise
            (:class:`NoiseModel`) or none. mono: mono8 images instead of RGB.
    """

    def stream(ci: int, c: RigCameraSim) -> Iterator[tuple]:
        """(stamp s, ci, frame, CPU s to render it) of camera ``c``'s frames."""
        r = Renderer(scene, c.camera, supersample, noise=NoiseModel() if noise else None)
        mounted = c.on(trajectory)
        seq = r.render_sequence(mounted, frames, c.fps, c.offset, mono=mono, seed=(seed, ci))
        while True:
            tic = time.process_time()
            fr = next(seq, None)
            if fr is None:
                return
            stamp = fr.t_first + float(c.camera.line_time(stamp_row))
            yield stamp, ci, fr, time.process_time() - tic

    cameras = list(cameras)
    for stamp, ci, fr, render_s in heapq.merge(*(stream(*c) for c in enumerate(cameras))):
        R, p = trajectory.pose(fr.t_ref)
        yield RigFrameSim(
            cameras[ci].name, fr.index, int(t0_ns) + int(round(stamp * 1e9)),
            int(t0_ns) + int(round(fr.t_ref * 1e9)), np.zeros((0, 2)), np.zeros((0, 3)), R, p,
            image=fr.image, render_s=render_s,
        )  # fmt: skip


def render_rig_frames(
    cameras: list,
    frames: int,
    *,
    scene: str = "aruco_room",
    motion: str = "shake",
    seed: int = 0,
    t0_ns: int = 1_700_000_000_000_000_000,
    supersample: int = 1,
    noise: bool = True,
    mono: bool = False,
) -> tuple[list[RigFrameSim], RigTrajectory]:
    """Render ``frames`` frames of every camera, stamped at their row 0, sorted by stamp:
    :func:`render_rig_images` along the ``motion`` preset
    (:func:`~rs_localizer.sim.render.motion.rig_trajectory`) over the rendered time, around
    ``scene``'s viewpoint.

    Args:
        cameras: :class:`~rs_localizer.sim.trajectory.RigCameraSim` (e.g. :func:`vga_rig`).
        scene, motion: the renderer's scene and motion preset names.
        supersample, noise, mono: as :func:`render_rig_images`.
    Returns:
        (frames, the rig's motion; :func:`~rs_localizer.sim.trajectory.rig_truth` gives its
        truth).
    """
    sc = load_scene(scene)
    rig = rig_trajectory(motion, sc, _duration(cameras, frames))
    images = render_rig_images(
        cameras, sc, rig, frames, t0_ns=t0_ns, supersample=supersample, noise=noise, seed=seed,
        mono=mono,
    )  # fmt: skip
    return list(images), rig


def render_rig_video(
    cameras: list[RigCameraSim],
    scene: str | Scene = "apriltag_rig_room",
    trajectory: RigTrajectory | None = None,
    frames: int = 30,
    *,
    frontend: Callable | None = None,
    t0_ns: int = 1_700_000_000_000_000_000,
    stamp_row: float = 0.0,
    supersample: int = 2,
    noise: bool = True,
    seed: int = 0,
) -> Iterator[RigFrameSim]:
    """Yield every camera's rendered frames (``frames`` per camera; :func:`render_rig_images`),
    sorted by stamp, each with its front end's correspondences and the rig's pose at its
    reference line.

    Args:
        cameras: the rig (:func:`rendered_rig`). scene: a built-in name, YAML path or
            :class:`Scene`. trajectory: the rig's motion (default
            :func:`~rs_localizer.sim.render.motion.rig_trajectory` ``pan`` over the video).
        frontend: ``make(camera_name) -> object with process(image, camera) -> (uv, xyz,
            ids)``, one front end per camera (default: the AprilTag/ArUco front end of the
            scene's markers, :class:`~rs_localizer.frontends.ArucoFrontend`).
        supersample: anti-aliasing samples per axis. noise: sensor noise, seeded per camera and
            frame from ``seed``.
    """
    from ...frontends import ArucoFrontend

    sc = scene if isinstance(scene, Scene) else load_scene(scene)
    cameras = list(cameras)
    trajectory = trajectory or rig_trajectory("pan", sc, _duration(cameras, frames))
    make_fe = frontend or (lambda name: ArucoFrontend.from_scene(sc))
    by_name = {c.name: (c.camera, make_fe(c.name)) for c in cameras}
    images = render_rig_images(
        cameras, sc, trajectory, frames, t0_ns=t0_ns, stamp_row=stamp_row,
        supersample=supersample, noise=noise, seed=seed,
    )  # fmt: skip
    for f in images:
        camera, fe = by_name[f.name]
        tic = time.process_time()
        uv, xyz, ids = fe.process(f.image, camera)
        f.uv, f.xyz = np.asarray(uv, float).reshape(-1, 2), np.asarray(xyz, float).reshape(-1, 3)
        f.ids = np.asarray(ids, np.uint32).reshape(-1)
        f.frontend_s = time.process_time() - tic
        yield f
