"""A synthetic rolling-shutter sequence as ``rs-localizer make-bag`` writes it: the scene, the
motion, the frames, the optional IMU samples and the settings recorded in ``sequence.json``."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraModel
from .planar import sequence_scene
from .trajectory import (
    R_IMU_CAMERA,
    SequenceConfig,
    Teleport,
    default_camera,
    generate_sequence,
    imu_samples,
    make_trajectory,
)

__all__ = ["SimulatedSequence", "parse_frame_list", "simulate_bag_sequence"]


@dataclass
class SimulatedSequence:
    """What :func:`simulate_bag_sequence` makes.

    Attributes:
        frames: list of :class:`rs_localizer.sim.trajectory.Frame` (pixels, landmarks,
            ground truth). scene, camera, trajectory: as
            :func:`rs_localizer.sim.trajectory.generate_sequence` returns them.
        settings: the generator's settings recorded in the bag's ``sequence.json``.
        imu: ``(stamps_ns (N,) int64 on the IMU's clock, angular velocity (N, 3) rad/s,
            specific force (N, 3) m/s^2)`` in IMU axes, or None.
        extra: further ``sequence.json`` sections (``imu``: topic, rate, mounting, time offset).
    """

    frames: list
    scene: object
    camera: CameraModel
    trajectory: object
    settings: dict
    imu: tuple | None = None
    extra: dict = field(default_factory=dict)


def parse_frame_list(text: str) -> tuple[int, ...]:
    """``"3,5-7"`` -> ``(3, 5, 6, 7)``. Raises ValueError on a malformed entry."""
    out = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        a, _, b = part.partition("-")
        try:
            out.extend(range(int(a), int(b or a) + 1))
        except ValueError:
            raise ValueError(f"expected frame numbers like 10,20-23, got {part!r}") from None
    return tuple(out)


def simulate_bag_sequence(
    *,
    frames: int = 40,
    points: int = 500,
    fps: float = 30.0,
    noise: float = 0.5,
    outliers: float = 0.2,
    seed: int = 0,
    line_delay: float = 30e-6,
    direction: str = "top_to_bottom",
    reference_row: float | None = None,
    stamp_row: float = 0.0,
    motion_scale: float = 1.0,
    landmarks: int = 6000,
    scene: str = "corridor",
    distortion: bool = True,
    start_time: float = 1_700_000_000.0,
    motion: str = "walk",
    drop_frames: tuple[int, ...] = (),
    teleport: int | None = None,
    imu_rate: float = 0.0,
    imu_topic: str = "/imu/data",
    imu_time_offset: float = 0.0,
    progress=None,
) -> SimulatedSequence:
    """Simulate the sequence of ``rs-localizer make-bag`` (the CLI's options, same names).

    Args:
        frames, points, fps: frames, correspondences per frame, frame rate (Hz).
        noise: pixel noise sigma (px). outliers: fraction of wrong matches in [0, 1].
        line_delay: s per row; direction: readout direction; reference_row: row (px) of the
            ground-truth pose (None: image centre); stamp_row: row of the header stamp.
        motion_scale: scale of the rotational motion; landmarks: landmarks in the scene.
        scene: ``corridor``, ``plane`` or ``board``
            (:func:`rs_localizer.sim.planar.sequence_scene`).
        motion: ``walk`` or a :func:`rs_localizer.sim.trajectory.make_trajectory` preset
            (corridor and plane scenes only). drop_frames: frame indices left out.
        teleport: the camera jumps just before frame N (None: no jump).
        imu_rate: > 0: IMU samples at this rate (Hz) from 0.1 s before the first frame to 0.1 s
            after the last, stamped on a clock ``imu_time_offset`` s behind the camera's
            (t_cam = t_imu + offset); imu_topic: recorded in ``extra``.
        progress: None or a callable called with each frame's index before it is made.
    Raises:
        ValueError: ``motion`` other than walk with the board scene.
    """
    camera = default_camera(
        line_delay=line_delay, reference_row=reference_row, distortion=distortion, readout=direction
    )
    drop = tuple(drop_frames)
    cfg = SequenceConfig(
        num_frames=frames,
        num_points=points,
        fps=fps,
        noise_px=noise,
        outlier_ratio=outliers,
        seed=seed,
        stamp_row=stamp_row,
        motion_scale=motion_scale,
        num_landmarks=landmarks,
        t0_ns=int(round(start_time * 1e9)),
        drop_frames=drop,
    )
    sc, trajectory = sequence_scene(
        scene, np.random.default_rng([seed, 16]), landmarks, motion_scale
    )
    if motion != "walk":
        if trajectory is not None:
            raise ValueError(f"--motion applies to the corridor and plane scenes, not to {scene!r}")
        trajectory = make_trajectory(motion, motion_scale)
    if teleport is not None:  # jump in the gap before frame N's readout
        trajectory = Teleport(
            trajectory or make_trajectory("walk", motion_scale), time=(teleport - 0.25) / fps
        )
    out_frames, sc, camera, trajectory = generate_sequence(
        cfg, camera=camera, trajectory=trajectory, scene=sc, progress=progress
    )
    keys = (
        "num_frames",
        "num_points",
        "fps",
        "noise_px",
        "outlier_ratio",
        "seed",
        "motion_scale",
        "num_landmarks",
    )
    settings = {k: getattr(cfg, k) for k in keys}
    if scene != "corridor":
        settings["scene"] = scene
    # options beyond the first ones are recorded only when used (older bags stay as they are)
    if motion != "walk":
        settings["motion"] = motion
    if drop:
        settings["drop_frames"] = list(drop)
    if teleport is not None:
        settings["teleport_before_frame"] = teleport
    extra, imu = {}, None
    if imu_rate:
        t, om, fo = imu_samples(trajectory, -0.1, frames / fps + 0.1, imu_rate, seed=seed)
        imu = (cfg.t0_ns + np.round((t - imu_time_offset) * 1e9).astype(np.int64), om, fo)
        extra["imu"] = {
            "topic": imu_topic,
            "rate": imu_rate,
            "rotation_imu_from_camera": R_IMU_CAMERA.tolist(),
        }
        if imu_time_offset:
            extra["imu"]["time_offset"] = imu_time_offset
    return SimulatedSequence(out_frames, sc, camera, trajectory, settings, imu, extra)
