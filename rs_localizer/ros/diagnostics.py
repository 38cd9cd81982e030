"""The localizer's ``/diagnostics`` status (level, message, key-value pairs) from its counters,
without ROS: the node wraps it into a ``diagnostic_msgs/DiagnosticStatus``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..runtime.background import background_state, compiled_ready
from .config import LocalizerConfig
from .frame_queue import FrameCounts
from .pipeline import StatsSnapshot

__all__ = ["ERROR", "IMU_IDLE_WARN_S", "OK", "WARN", "diagnostic_status"]

#: levels of ``diagnostic_msgs/DiagnosticStatus``
OK, WARN, ERROR = 0, 1, 2
#: s; with ``imu.enabled``, no usable IMU sample for this long while frames arrive is a WARN
IMU_IDLE_WARN_S = 2.0


def _ms(seconds: Sequence[float]) -> np.ndarray:
    return np.array(list(seconds)) * 1e3


#: s: a frame whose stamp is further than this from the node's clock carries stamps of
#: another clock (a recorded bag played without ``use_sim_time``), not a stamp age
OFF_CLOCK_S = 60.0


def diagnostic_status(
    cfg: LocalizerConfig,
    frames: FrameCounts,
    stats: StatsSnapshot,
    tracking: dict[str, Any],
    camera_source: str,
    messages_lost: int,
    latencies: Sequence[float],
    stamp_ages: Sequence[float],
    imu_rate_hz: float | None = None,
    gyro_bias: tuple[Sequence[float], Sequence[float]] | None = None,
    gyro_inconsistent: bool = False,
    imu_idle_s: float | None = None,
    frontend: Any = None,
) -> tuple[int, str, dict[str, Any]]:
    """``(level, message, values)`` of the localizer's status.

    Level ERROR when frames arrived but none was solved, WARN when a frame failed, was skipped,
    a message was lost or the gyro is left out because the rotation between frames contradicts
    it (``gyro_inconsistent``) or, with ``imu.enabled``, frames arrive but no usable IMU sample
    did for :data:`IMU_IDLE_WARN_S` (``imu_idle_s``: s since the last buffered sample, or since
    the start; e.g. every message rejected), else OK. ``values`` (in publishing order): solver,
    camera (``camera_source``), frame accounting (received, solved, failed, skipped, pending),
    the estimator's path (``compiled``: the compiled kernels in use, else the uncompiled path;
    the background compile's state, failures and last error; frames solved on each path;
    :func:`rs_localizer.runtime.background.background_state`), counters of ``stats`` and
    ``messages_lost``, inliers, planarity, ``tracking`` (see
    :meth:`.pipeline.FramePipeline.tracking_values`), latency (``latencies``: s from arrival to
    published) and stamp age (``stamp_ages``: s from the input stamp to published) in ms,
    stage times, front-end values (with a front end), gyro values (with ``imu.enabled``:
    ``imu_rate_hz`` the buffered samples' rate, frames solved with the gyro, frames whose
    gyro the image contradicted, frames without gyro samples, IMU samples rejected, the gyro
    bias used and its standard deviation: ``gyro_bias`` = (bias (3,), std (3,)) rad/s, IMU
    frame, the online estimate with ``imu.estimate_bias``, default ``imu.gyro_bias`` and
    ``imu.gyro_bias_sigma``; pairs of frames the bias estimator rejected; the check of the
    gyro against the rotation between frames: ``gyro_inconsistent``, the frames solved
    without the gyro because of it, its failed pairs and detections), then
    ``failed.<reason>``, ``camera_info_rejected.<reason>``, ``gyro_missing.<reason>`` and
    ``imu_rejected.<reason>`` counts. ``frontend``: the image front end in use
    (:attr:`.pipeline.FramePipeline.maps`), None without one.
    """
    c = stats.counts
    failed = dict(sorted(frames.failures.items()))
    level, message = _level_and_message(
        cfg, frames, c, failed, messages_lost, gyro_inconsistent, imu_idle_s
    )
    compiled, bg = compiled_ready(), background_state()
    if not compiled:  # (a lower rate while the kernels compile is not a fault)
        message += (
            "; kernels compiling in the background: frames on the uncompiled path"
            if bg["state"] in ("compiling", "loading")
            else "; frames on the uncompiled path"
        )
    values = _core_values(
        cfg,
        frames,
        stats,
        tracking,
        camera_source,
        messages_lost,
        latencies,
        stamp_ages,
        compiled,
        bg,
        frontend is not None,
    )
    if frontend is not None:
        values.update(_frontend_values(cfg, frontend, stats))
    if cfg.imu is not None:
        values.update(_imu_values(cfg, c, imu_rate_hz, gyro_bias, gyro_inconsistent, imu_idle_s))
    values.update({f"failed.{k}": v for k, v in failed.items()})
    prefixes = ("camera_info_rejected.", "gyro_missing.", "imu_rejected.")
    values.update({k: v for k, v in sorted(c.items()) if k.startswith(prefixes)})
    return level, message, values


def _level_and_message(
    cfg: LocalizerConfig,
    frames: FrameCounts,
    c: dict[str, int],
    failed: dict[str, int],
    messages_lost: int,
    gyro_inconsistent: bool,
    imu_idle_s: float | None,
) -> tuple[int, str]:
    """The status level and message of :func:`diagnostic_status` (before the compile note)."""
    if frames.received and not frames.solved:
        level, message = ERROR, "no frame solved" + (f" ({failed})" if failed else "")
    elif frames.failed or messages_lost or frames.skipped:
        level = WARN
        message = f"{frames.solved}/{frames.received} frames solved" + (
            f", {frames.skipped} skipped (busy)" if frames.skipped else ""
        )
    elif gyro_inconsistent and cfg.imu is not None:
        level = WARN
        message = (
            f"{frames.solved}/{frames.received} frames solved; the gyro contradicts the image "
            "(check imu.rotation, imu.time_offset): frames solved without it"
        )
    elif (
        cfg.imu is not None
        and frames.received
        and imu_idle_s is not None
        and imu_idle_s > IMU_IDLE_WARN_S
    ):
        level = WARN
        rejected = c.get("imu_rejected", 0)
        message = (
            f"{frames.solved}/{frames.received} frames solved; no usable IMU sample for "
            f"{imu_idle_s:.1f} s ({rejected} IMU messages rejected): frames solved without the "
            "gyro; check the imu topic and its stamps"
        )
    else:
        level = OK
        message = (
            f"{frames.solved}/{frames.received} frames solved"
            if frames.received
            else "waiting for frames"
        )
    if c.get("map_fit_doubtful", 0) and level != OK:
        message += (
            "; most frames with many matches refused: does the map fit this place? mirrored "
            "or another room?"
        )
    return level, message


def _core_values(
    cfg: LocalizerConfig,
    frames: FrameCounts,
    stats: StatsSnapshot,
    tracking: dict[str, Any],
    camera_source: str,
    messages_lost: int,
    latencies: Sequence[float],
    stamp_ages: Sequence[float],
    compiled: bool,
    bg: dict[str, Any],
    has_frontend: bool,
) -> dict[str, Any]:
    """The values every status carries, through the stage times (see :func:`diagnostic_status`)."""
    c = stats.counts
    lat, age = _ms(latencies), _ms(stamp_ages)
    on_clock = np.abs(age) <= OFF_CLOCK_S * 1e3
    off_clock, age = int(np.sum(~on_clock)), age[on_clock]
    inliers = stats.inliers
    values: dict[str, Any] = {
        "solver": cfg.solver,
        "camera": camera_source,
        "frames_received": frames.received,
        "frames_solved": frames.solved,
        "frames_failed": frames.failed,
        "frames_skipped": frames.skipped,
        "frames_pending": frames.pending,
        "compiled": str(compiled).lower(),
        "compile_state": bg["state"],
        "compile_failures": bg["failures"],
        "compile_error": bg["reason"] or "",
        "frames_compiled": c.get("frames_compiled", 0),
        "frames_uncompiled": c.get("frames_uncompiled", 0),
        "queue_size": cfg.queue_size,
        "time_resets": c.get("time_resets", 0),
        "messages_lost": messages_lost,
        "points_dropped": c.get("points_dropped", 0),
        "clouds_capped": c.get("capped_clouds", 0),
        "unknown_landmark_ids": c.get("unknown_landmark_ids", 0),
        "camera_info_rejected": c.get("camera_info_rejected", 0),
        "frames_single_tag": c.get("frames_single_tag", 0),
        "frames_failed_with_matches": c.get("frames_failed_with_matches", 0),
        "map_fit_doubtful": str(bool(c.get("map_fit_doubtful", 0))).lower(),
        "inliers_last": inliers[-1] if inliers else 0,
        "inliers_mean": f"{np.mean(inliers):.1f}" if inliers else "0",
        "planar": str(stats.planar).lower(),
        **tracking,
        "condition_number_last": f"{stats.condition_number:.3g}",
        "latency_ms_last": f"{lat[-1]:.3f}" if len(lat) else "nan",
        "latency_ms_median": f"{np.median(lat):.3f}" if len(lat) else "nan",
        "latency_ms_p99": f"{np.percentile(lat, 99):.3f}" if len(lat) else "nan",
        "stamp_age_ms_last": f"{age[-1]:.3f}" if len(age) else "nan",
        "stamp_age_ms_median": f"{np.median(age):.3f}" if len(age) else "nan",
        "stamps_off_clock": off_clock,
    }
    for k, d in stats.stage_times.items():
        if k == "frontend" and not has_frontend:
            continue
        values[f"{k}_ms_median"] = f"{np.median(d) * 1e3:.3f}" if d else "nan"
    return values


def _frontend_values(cfg: LocalizerConfig, frontend: Any, stats: StatsSnapshot) -> dict[str, Any]:
    """The front end's values of :func:`diagnostic_status` (with a ``frontend``)."""
    c = stats.counts
    values: dict[str, Any] = {}
    fe = stats.stage_times["frontend"]
    runs = c.get("frontend_runs", 0)
    values.update(
        {
            "frontend": cfg.frontend_kind,
            "image_frames": c.get("image_frames", 0),
            "frames_beside_frontend": c.get("frames_beside_frontend", 0),
            "frontend_ms_last": f"{fe[-1] * 1e3:.3f}" if fe else "nan",
            "frontend_correspondences_last": stats.frontend_last,
            "frontend_correspondences_mean": (
                f"{c.get('frontend_points', 0) / runs:.1f}" if runs else "0"
            ),
            "frontend_ms_p99": f"{np.percentile(fe, 99) * 1e3:.3f}" if fe else "nan",
        }
    )
    summary = getattr(frontend, "summary", None)  # (a tracking front end)
    values.update(summary() if summary is not None else {"frontend_frames_global": runs})
    few = getattr(frontend, "few_match_frames", None)  # (a feature front end)
    if few is not None:
        values["frontend_few_match_frames"] = few
    return values


def _imu_values(
    cfg: LocalizerConfig,
    c: dict[str, int],
    imu_rate_hz: float | None,
    gyro_bias: tuple[Sequence[float], Sequence[float]] | None,
    gyro_inconsistent: bool,
    imu_idle_s: float | None,
) -> dict[str, Any]:
    """The gyro's values of :func:`diagnostic_status` (``cfg.imu`` set)."""
    values: dict[str, Any] = {}
    bias, std = gyro_bias or (cfg.imu.gyro_bias, np.full(3, cfg.imu.gyro_bias_sigma))
    values.update(
        {
            "imu_rate_hz": f"{imu_rate_hz or 0.0:.1f}",
            "frames_with_gyro": c.get("frames_with_gyro", 0),
            "gyro_rejected": c.get("gyro_rejected", 0),
            "gyro_missing": c.get("gyro_missing", 0),
            "imu_rejected": c.get("imu_rejected", 0),
            "imu_idle_s": "nan" if imu_idle_s is None else f"{imu_idle_s:.1f}",
            "gyro_bias": " ".join(f"{b:.5f}" for b in bias),
            "gyro_bias_std": " ".join(f"{b:.5f}" for b in std),
            "gyro_bias_rejected": c.get("gyro_bias_rejected", 0),
            "gyro_inconsistent": str(bool(gyro_inconsistent)).lower(),
            "gyro_disabled_inconsistent": c.get("gyro_disabled_inconsistent", 0),
            "gyro_pairs_failed": c.get("gyro_pairs_failed", 0),
            "gyro_inconsistent_detections": c.get("gyro_inconsistent_detections", 0),
        }
    )
    return values
