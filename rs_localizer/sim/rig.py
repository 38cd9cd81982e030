"""Rigs of rolling-shutter cameras and their frames, with exact ground truth.

A :class:`Rig` carries 2 to 4 cameras looking front, back and to the sides
(:data:`LAYOUTS`), each mounted 5-20 cm off the rig's origin with a few degrees of tilt, with
its own focal length, readout time (line delay) and readout direction, and a stamp up to
``stamp_spread`` from the others (unsynchronized cameras). Frames: the rig frame is
camera-like (x right, y down, z forward); a camera of yaw ``psi`` looks along
``(sin psi, 0, cos psi)`` of the rig.

:func:`rig_frame` draws world points in front of each camera (depth 2-8 m), projects them with
the camera's exact rolling-shutter projection (:meth:`~rs_localizer.camera.CameraModel.project_rs`)
of the rig's constant-velocity motion (the model of
:mod:`~rs_localizer.estimation.rig`, :func:`~rs_localizer.estimation.rig.camera_model_of_rig`),
adds Gaussian pixel noise and replaces a share of the pixels with outliers uniform over the
image. The tests of the rig estimator and ``python -m benchmarks.bench_rig`` use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import CameraModel
from ..estimation.rig import RigView, camera_model_of_rig
from ..frames import Mounting
from ..geometry import rotvec_to_matrix
from ..pose import RSModel

__all__ = [
    "LAYOUTS",
    "READOUTS",
    "Rig",
    "RigCamera",
    "RigFrame",
    "make_rig",
    "rig_frame",
    "rig_motion",
]

#: cameras of a rig of M cameras: (name, yaw rad) each
LAYOUTS = {
    1: (("front", 0.0),),
    2: (("front", 0.0), ("back", np.pi)),
    3: (("front", 0.0), ("left", -np.pi / 2), ("right", np.pi / 2)),
    4: (("front", 0.0), ("right", np.pi / 2), ("back", np.pi), ("left", -np.pi / 2)),
}
#: readout directions, in the order the cameras of a rig take them
READOUTS = ("top_to_bottom", "left_to_right", "bottom_to_top", "right_to_left")


@dataclass(frozen=True, eq=False)
class RigCamera:
    """One camera of a simulated rig.

    Attributes:
        name: its place on the rig (``front``, ``back``, ``left``, ``right``).
        camera: intrinsics and RS timing (no lens distortion).
        mounting: its :class:`~rs_localizer.frames.Mounting` on the rig (``x_cam = R x_rig +
            c``).
        stamp_offset: its reference line's capture time minus the rig's reference time (s).
    """

    name: str
    camera: CameraModel
    mounting: Mounting
    stamp_offset: float

    @property
    def centre(self) -> np.ndarray:
        """(3,) the camera centre in the rig frame (m)."""
        return self.mounting.position


@dataclass(frozen=True, eq=False)
class Rig:
    """A simulated rig: its cameras (:class:`RigCamera`)."""

    cameras: tuple[RigCamera, ...]

    def __len__(self) -> int:
        return len(self.cameras)


@dataclass(frozen=True, eq=False)
class RigFrame:
    """One simulated rig frame.

    Attributes:
        views: one :class:`~rs_localizer.estimation.rig.RigView` per camera (what
            :func:`~rs_localizer.estimation.rig.estimate_rig_pose` takes).
        truth: the rig's :class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)`` at its reference
            time (``w`` rad/s, ``t`` m/s: :mod:`~rs_localizer.estimation.rig`).
        outliers: one (N_c,) bool per camera: rows replaced by outliers.
        rig: the rig.
    """

    views: list
    truth: RSModel
    outliers: tuple
    rig: Rig

    def camera_truth(self, c: int) -> RSModel:
        """Camera c's true single-camera model at its reference line (per unit r)."""
        k = self.rig.cameras[c]
        return camera_model_of_rig(
            self.truth, k.mounting, k.stamp_offset, k.camera.seconds_per_unit_r
        )


def make_rig(
    m: int,
    rng: np.random.Generator,
    readout_time: tuple[float, float] = (0.015, 0.035),
    stamp_spread: float = 0.01,
    lever: tuple[float, float] = (0.05, 0.2),
    tilt: float = 0.05,
    focal: tuple[float, float] = (450.0, 600.0),
    size: tuple[int, int] = (640, 480),
) -> Rig:
    """A rig of ``m`` (1-4) cameras laid out as :data:`LAYOUTS`.

    Args:
        m: number of cameras. rng: the random generator.
        readout_time: (lo, hi) s, each camera's frame readout time drawn uniformly (0, 0: global
            shutter cameras).
        stamp_spread: s, the stamps drawn uniformly within ``+- stamp_spread / 2`` of the rig's
            reference time (at most ``stamp_spread`` apart; 0: synchronized).
        lever: (lo, hi) m, each camera centre's distance from the rig's origin.
        tilt: rad, the standard deviation of each mounting's random tilt off its layout.
        focal: (lo, hi) px, each camera's focal length. size: (width, height) px.
    Raises:
        ValueError: ``m`` not in 1..4.
    """
    if m not in LAYOUTS:
        raise ValueError(f"make_rig: a rig has 1 to 4 cameras, got {m}")
    width, height = size
    cams = []
    for k, (name, yaw) in enumerate(LAYOUTS[m]):
        f = rng.uniform(*focal)
        K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
        cam = CameraModel.from_readout_time(
            K, rng.uniform(*readout_time), width, height, readout=READOUTS[k % 4]
        )
        # camera axes in the rig frame: the layout's yaw about y, then a small tilt
        axes = rotvec_to_matrix([0.0, yaw, 0.0]) @ rotvec_to_matrix(rng.normal(size=3) * tilt)
        Rc = axes.T
        d = rng.normal(size=3)
        centre = d / np.linalg.norm(d) * rng.uniform(*lever)
        stamp = rng.uniform(-0.5, 0.5) * stamp_spread
        cams.append(RigCamera(name, cam, Mounting(Rc, -Rc @ centre), float(stamp)))
    return Rig(tuple(cams))


def rig_motion(
    rng: np.random.Generator, angular_speed: float = 1.5, linear_speed: float = 1.5
) -> RSModel:
    """A random rig pose and constant velocity: ``R`` uniform-ish (a normal rotation vector),
    ``C`` normal (m), ``w`` of norm ``angular_speed`` (rad/s), ``t`` of norm ``linear_speed``
    (m/s), in random directions. Returns the rig's :class:`~rs_localizer.pose.RSModel`."""
    w = rng.normal(size=3)
    t = rng.normal(size=3)
    return RSModel(
        rotvec_to_matrix(rng.normal(size=3)),
        rng.normal(size=3),
        w * angular_speed / np.linalg.norm(w),
        t * linear_speed / np.linalg.norm(t),
    )


def rig_frame(
    rig: Rig,
    truth: RSModel | tuple,
    counts: list[int] | tuple[int, ...],
    rng: np.random.Generator,
    noise_px: float = 0.5,
    outliers: float = 0.2,
    depth: tuple[float, float] = (2.0, 8.0),
) -> RigFrame:
    """One rig frame: ``counts[c]`` correspondences of camera c.

    World points are drawn in camera c's field of view at ``depth`` (m) from it at its
    reference line, projected by its exact RS projection of ``truth`` (points that leave the
    image at their capture time are drawn again), then noised (``noise_px`` per axis, px) and
    a share ``outliers`` of them (each row with that probability) replaced by pixels uniform
    over the image.

    Args:
        rig: the rig. truth: the rig's ``(R, C, w, t)`` (:func:`rig_motion`).
        counts: (M,) points per camera (0 allowed). rng: the random generator.
    Returns:
        :class:`RigFrame`.
    """
    if len(counts) != len(rig):
        raise ValueError(f"rig_frame: {len(counts)} counts for {len(rig)} cameras")
    truth = RSModel(*(np.asarray(a, dtype=float) for a in truth))
    views, bad_rows = [], []
    for k, n in zip(rig.cameras, counts, strict=True):
        cam = k.camera
        Rp, Cp, wp, tp = camera_model_of_rig(
            truth, k.mounting, k.stamp_offset, cam.seconds_per_unit_r
        )
        half = 0.5 * np.array([cam.width, cam.height]) / np.diag(cam.K)[:2] * 0.95
        uv, X = np.zeros((0, 2)), np.zeros((0, 3))
        while len(uv) < n:
            xn = rng.uniform(-half, half, (4 * n, 2))
            z = rng.uniform(*depth, 4 * n)
            Xw = (np.c_[xn * z[:, None], z] - Cp) @ Rp
            p = cam.project_rs(Xw, Rp, Cp, wp, tp)
            ok = np.isfinite(p).all(axis=1) & cam.in_image(p)
            uv = np.vstack([uv, p[ok]])[:n]
            X = np.vstack([X, Xw[ok]])[:n]
        uv = uv + rng.normal(size=uv.shape) * noise_px
        bad = rng.random(n) < outliers
        uv[bad] = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (int(bad.sum()), 2))
        views.append(RigView(uv, X, cam, k.mounting, k.stamp_offset, name=k.name))
        bad_rows.append(bad)
    return RigFrame(views, truth, tuple(bad_rows), rig)
