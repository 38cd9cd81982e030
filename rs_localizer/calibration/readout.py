"""Readout calibration: the line delay of a rolling-shutter camera from a video with rotation.

Users rarely know their camera's line delay (it is not in CameraInfo and seldom in
datasheets). The per-frame estimator does not need it: it works in the normalized RS
coordinate ``r`` and returns the rotation per unit of ``r`` during the readout, ``w`` (model
units, :class:`~rs_localizer.estimation.estimate.RSPoseEstimate`). The camera's angular
velocity is ``omega = -w / s`` with ``s = line_delay * focal`` the seconds per unit ``r``
(:attr:`~rs_localizer.camera.CameraModel.seconds_per_unit_r`). Rotation between frames
(rad/s, from the frames' orientations and stamps, or from a gyro) against ``w`` gives ``s``:

* frames: over three consecutive frames ``k-1, k, k+1`` equally spaced by ``dt``,
  Simpson's rule gives ``log(O_{k-1}^T O_{k+1}) = (dt / 3)(omega_{k-1} + 4 omega_k +
  omega_{k+1})`` (all in frame k), so ``y_k = -(w_{k-1} + 4 w_k + w_{k+1}) / 6`` equals
  ``s x_k`` with ``x_k = log(O_{k-1}^T O_{k+1}) / (2 dt)`` (rad/s). The rule's error on a
  sinusoidal rotation of frequency f is below 1 % up to ``f dt = 0.17`` (5 Hz at 30 fps);
  the trapezoid rule over one interval would be off by 9 % there.
* gyro (``gyro=``): ``y_k = -w_k = s R_ci omega_imu(t_k) + c`` with the camera-IMU rotation
  ``R_ci`` and a gyro bias term ``c`` estimated with ``s`` (Umeyama's similarity fit). The
  frame times ``t_k`` are those of the reference line, which depend on the line delay: the fit
  iterates. Assumed: camera and IMU rigidly mounted.
* the camera-IMU rotation and the gyro bias that are reported come from a second fit: the
  rotation between consecutive frames' poses, ``log(O_k^T O_{k+1}) / dt``, against the gyro
  averaged over the same interval, ``R_ci (mean omega_imu - bias)`` (Kabsch with a centroid,
  Huber-reweighted). One frame's angular velocity trades against its linear velocity over the
  readout, and its mean error goes straight into ``c``: on 2 s of simulated hand-held shake
  the per-frame rate about the camera's x axis is 0.02 rad/s off on average, which the first
  fit turned into a bias 0.02 rad/s off; the poses determine the rotation between frames to
  ~0.01 deg. Their standard deviations (rotation about the camera's x, y, z axes; bias per IMU
  axis) are sandwich estimates as the slope's; an axis the camera never turned about leaves
  the rotation about it and the bias undetermined (infinite or large std): reported as not
  observable (std over ``max_rotation_std``, 0.5 deg, or ``max_bias_std``, 0.005 rad/s) with the
  motion that would determine them (rotating about all three axes). Over seeds 0-5 of that
  shake the errors are within 1.7 std; of a one-axis pan within 2.1 std, the stds about 1.4x
  too small there (``python -m benchmarks.bench_imu_calibration``).
* the gyro's time offset (``t_cam = t_imu + time_offset``, the node's ``imu.time_offset``): a
  shift of the gyro rates in time. For every offset of a grid (``time_offset_step``, 1 ms,
  over ``+-max_time_offset``, 50 ms) the similarity is fitted again and scored by its trimmed
  sum of squared residuals (the best 90 % of the frames); the best offset is refined by
  Brent's bounded search (SciPy) to 1 us and the fit repeated there. Its standard deviation is
  the same sandwich estimate as the slope's, with the residuals' derivative with respect to
  the offset, ``-s R_ci alpha`` (``alpha`` the gyro's angular acceleration, by central
  differences over +-20 ms: over shorter steps the sample noise would pass for
  acceleration). The offset is only observable when the rotation rate changes (on a constant
  rate every shift fits equally): it is reported as not observable when its standard
  deviation exceeds ``max_time_offset_std`` (1 ms) or the best offset is at the grid's end.
  On 2 s of simulated hand-held shake (60 frames, a gyro 10 ms late) the error is at most
  0.39 ms over seeds 0-5 with a standard deviation of 0.37-0.46 ms
  (``test/calibration/test_readout.py``).

The fit is least squares through the origin with Huber weights (threshold 3 robust sigma),
repeated to convergence. Its standard deviation is a heteroscedasticity- and
autocorrelation-consistent (Newey-West, Bartlett kernel over 2 lags: neighbouring triplets
share frames) sandwich estimate, inflated by ``n / (n - 1)``, combined in quadrature with a
systematic ``model_error`` (relative, default 0.2 %): on noise-free synthetic sequences the
per-frame ``w`` is 0.1-0.16 % smaller than the true rate (the constant-velocity fit over the
readout), which the statistical part alone would not cover (measured over 24 seeds of the
``pan`` sequence: errors -0.5 to +0.15 %, RMS of error / std 1.4 without the term). A sequence
whose rotation does
not pin ``s`` (relative standard deviation above ``max_relative_std``, fewer than
``min_samples`` samples, or ``s <= 0``) is reported as not observable.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from ..accuracy import umeyama_alignment
from ..camera import READOUT_DIRECTIONS, CameraModel
from ..estimation.estimate import EstimateOptions, estimate_rs_pose
from ..geometry import matrix_to_rotvec, skew
from .marginal import loose_inverse

__all__ = [
    "ReadoutCalibration",
    "calibrate_line_delay",
    "fit_line_delay",
    "line_delay_verdict",
    "per_frame_rates",
]


@dataclass(frozen=True)
class ReadoutCalibration:
    """Result of :func:`calibrate_line_delay` / :func:`fit_line_delay`.

    Attributes:
        line_delay: seconds per line, or ``None`` when not observable.
        line_delay_std: its standard deviation (s), or ``None``.
        frames_used: frames that entered the fit.
        observable: the rotation pins the line delay (see the module docstring).
        seconds_per_unit_r, seconds_per_unit_r_std: the fitted ``s`` and its standard deviation
            (reported even when not observable; NaN without samples).
        readout_time: ``line_delay * lines`` (s) or ``None``.
        samples: number of samples (Simpson triplets or gyro frames).
        rotation_rms: RMS angular rate of the samples (rad/s).
        reason: why not observable (empty when observable).
        camera_imu_rotation: (3, 3) ``R_ci`` (IMU -> camera) of the gyro fit, else ``None``.
        gyro_bias: (3,) the gyro's bias (rad/s, IMU frame) of the gyro fit when observable,
            else ``None``.
        residual_rms: RMS residual of the fit (rad per unit r).
        frames_failed: frames the estimator could not solve.
        time_offset: the gyro's time offset (s, ``t_cam = t_imu + time_offset``) of the gyro
            fit when observable, else ``None``; ``time_offset_std`` its standard deviation (s);
            ``time_offset_reason`` why it is not observable (empty when it is, or without a
            gyro).
        camera_imu_rotation_std: (3,) rad, the standard deviation of the camera-IMU rotation
            about the camera's x, y, z axes (gyro fit), else ``None``; ``inf`` about an axis
            the motion never turned about.
        camera_imu_rotation_observable, gyro_bias_observable: the motion determines the
            rotation (std within ``max_rotation_std`` about every axis) / the bias (std within
            ``max_bias_std`` on every axis); ``None`` without a gyro.
        gyro_bias_std: (3,) rad/s, the bias's standard deviation (IMU frame), else ``None``.
        mount_reason: what the motion leaves undetermined and which motion would determine
            it (empty when both are observable, or without a gyro).
    """

    line_delay: float | None
    line_delay_std: float | None
    frames_used: int
    observable: bool
    seconds_per_unit_r: float = float("nan")
    seconds_per_unit_r_std: float = float("nan")
    readout_time: float | None = None
    samples: int = 0
    rotation_rms: float = 0.0
    reason: str = ""
    camera_imu_rotation: np.ndarray | None = field(default=None, repr=False)
    gyro_bias: np.ndarray | None = field(default=None, repr=False)
    residual_rms: float = float("nan")
    frames_failed: int = 0
    time_offset: float | None = None
    time_offset_std: float | None = None
    time_offset_reason: str = ""
    camera_imu_rotation_std: np.ndarray | None = field(default=None, repr=False)
    camera_imu_rotation_observable: bool | None = None
    gyro_bias_std: np.ndarray | None = field(default=None, repr=False)
    gyro_bias_observable: bool | None = None
    mount_reason: str = ""

    def gyro_lines(self) -> list[str]:
        """Human-readable lines on the gyro fit's camera-IMU rotation and gyro bias: each
        with its standard deviation and whether the motion determined it, then a warning on
        what it left undetermined and the motion that would determine it. Empty without a
        gyro."""
        if self.camera_imu_rotation is None:
            return []
        lines = []
        rs = self.camera_imu_rotation_std
        verdict = "observable" if self.camera_imu_rotation_observable else "NOT observable"
        std = (
            "std about camera x/y/z " + "/".join(f"{np.degrees(v):.3g}" for v in rs) + " deg"
            if rs is not None
            else "std unknown"
        )
        lines.append(f"camera-IMU rotation: {std}: {verdict}")
        if self.gyro_bias is not None:
            bs = self.gyro_bias_std
            verdict = "observable" if self.gyro_bias_observable else "NOT observable"
            lines.append(
                "gyro bias ["
                + ", ".join(f"{b:.4f}" for b in self.gyro_bias)
                + "] rad/s (IMU frame), std "
                + ("[" + ", ".join(f"{v:.4f}" for v in bs) + "]" if bs is not None else "unknown")
                + f": {verdict}"
            )
        if self.mount_reason:
            lines.append(f"WARNING: {self.mount_reason}")
        return lines

    def as_dict(self) -> dict:
        """The four keys of ``rs-localizer calibrate-readout --json``."""
        return {
            "line_delay": self.line_delay,
            "line_delay_std": self.line_delay_std,
            "frames_used": int(self.frames_used),
            "observable": bool(self.observable),
        }


def per_frame_rates(
    frames: Iterable[tuple],
    camera: CameraModel,
    solver: str = "r6p_1lin",
    options: EstimateOptions | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Run the estimator on every frame with the camera's RS timing replaced by
    ``seconds_per_unit_r = 1`` (its stated line delay is ignored), the world origin moved to
    the previous frame's camera centre (the first frame is solved twice for that).

    Args:
        frames: iterable of ``(stamp_ns, points2d (N, 2), points3d (N, 3))`` or
            ``(stamp_ns, points2d, points3d, scores)``, in time order.
        camera: intrinsics, distortion and readout direction (line delay ignored).
    Returns:
        (stamps (K,) int64, orientations (K, 3, 3) camera -> world, w (K, 3) rotation per
        unit r in the camera frame, failed count) for the K solved frames.
    """
    cam = replace(camera, line_delay=1.0 / camera.focal)  # s = 1
    opts = options or EstimateOptions()
    stamps, Os, ws = [], [], []
    failed = 0
    origin = None
    for fr in frames:
        stamp, uv, xyz = fr[0], fr[1], fr[2]
        scores = fr[3] if len(fr) > 3 else None
        try:
            # the model's C(tau) = C + tau t is linear in camera coordinates: a camera turning
            # far from the world origin bends it and biases w (by 0.2 % at 30 m on the pan);
            # with the origin near the camera (the last frame's centre) the bias vanishes
            xyz = np.asarray(xyz, dtype=float)
            for _ in range(1 if origin is not None else 2):
                est = estimate_rs_pose(
                    uv,
                    xyz - (origin if origin is not None else 0.0),
                    cam,
                    solver=solver,
                    options=opts,
                    scores=scores,
                )
                if not est.success:
                    break
                if origin is None:
                    origin = est.pose.position
                    continue
                origin = origin + est.pose.position
                break
        except ValueError:
            failed += 1
            continue
        if not est.success:
            failed += 1
            continue
        stamps.append(int(stamp))
        Os.append(est.pose.orientation)
        ws.append(est.model.w)
    return (
        np.array(stamps, dtype=np.int64),
        np.array(Os).reshape(-1, 3, 3),
        np.array(ws).reshape(-1, 3),
        failed,
    )


def _robust_slope(x, y, lags: int = 2, iterations: int = 20):
    """Slope s of ``y = s x`` (x, y (n, 3) per sample) by Huber-weighted least squares, its
    HAC standard deviation and the residual RMS. Returns (s, std, rms)."""
    wts = np.ones(len(x))
    s = float(np.sum(x * y) / max(np.sum(x * x), 1e-300))
    for _ in range(iterations):
        wts = _huber_weights(y - s * x)
        s_new = float(np.sum(wts[:, None] * x * y) / max(np.sum(wts[:, None] * x * x), 1e-300))
        if abs(s_new - s) <= 1e-12 * max(abs(s), 1e-300):
            s = s_new
            break
        s = s_new
    r = y - s * x
    std = _hac_std(wts * np.sum(x * r, axis=1), float(np.sum(wts[:, None] * x * x)), lags, 1)
    return s, std, float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def _hac_std(u: np.ndarray, A: float, lags: int, p: int) -> float:
    """The sandwich standard deviation ``sqrt(V) / A`` of a scalar parameter fitted with
    ``p`` parameters from the (n,) scores ``u`` per sample (``A`` the weighted sum of the
    squared derivatives): ``V`` Newey-West (Bartlett kernel over ``lags``: neighbouring
    samples share frames), inflated by ``n / (n - p)``; inf when ``A`` is not positive."""
    n = len(u)
    V = float(u @ u)
    for lag in range(1, min(lags, n - 1) + 1):
        V += 2.0 * (1.0 - lag / (lags + 1.0)) * float(u[lag:] @ u[:-lag])
    V = max(V, 0.0) * n / max(n - p, 1)
    return float(np.sqrt(V) / A) if A > 0 else float("inf")


def _simpson_samples(stamps, Os, ws, max_dt: float, uniformity: float):
    """Simpson triplets (x (n, 3) rad/s, y (n, 3) rad per unit r, frame indices used)."""
    xs, ys, used = [], [], set()
    t = stamps.astype(np.float64) * 1e-9
    for k in range(1, len(t) - 1):
        d1, d2 = t[k] - t[k - 1], t[k + 1] - t[k]
        if not (0 < d1 <= max_dt and 0 < d2 <= max_dt) or abs(d1 - d2) > uniformity * d1:
            continue
        Ok = Os[k]
        theta = matrix_to_rotvec(Os[k - 1].T @ Os[k + 1])  # frame k-1 (= frame k+1) axes
        x = (Ok.T @ Os[k - 1]) @ theta / (d1 + d2)  # in frame k
        y = -((Ok.T @ Os[k - 1]) @ ws[k - 1] + 4.0 * ws[k] + (Ok.T @ Os[k + 1]) @ ws[k + 1]) / 6
        xs.append(x)
        ys.append(y)
        used.update((k - 1, k, k + 1))
    return np.array(xs).reshape(-1, 3), np.array(ys).reshape(-1, 3), used


def _rates_at(t_ns, t_imu, om_imu) -> np.ndarray:
    """(n, 3) gyro rates linearly interpolated at ``t_ns`` (ns, IMU clock)."""
    t = np.asarray(t_ns, dtype=np.float64)
    ti = t_imu.astype(np.float64)
    return np.stack([np.interp(t, ti, om_imu[:, a]) for a in range(3)], 1)


def _trimmed_cost(om, y, keep: float = 0.9) -> float:
    """Trimmed sum of squared residuals of the similarity fit ``y ~ s R om + c``."""
    R, c, s = umeyama_alignment(om, y, with_scale=True, any_on_line=True)
    r2 = np.sum((y - s * om @ R.T - c) ** 2, axis=1)
    k = max(int(keep * len(r2)), 1)
    return float(np.sum(np.partition(r2, k - 1)[:k]))


def _search_offset(t, y, t_imu, om_imu, max_offset: float, step: float) -> tuple[float, bool]:
    """The time offset (s) minimizing :func:`_trimmed_cost` over ``[-max_offset, max_offset]``
    (grid, then bounded Brent); True when the best grid point is at the grid's end."""
    from scipy.optimize import minimize_scalar

    grid = np.arange(-max_offset, max_offset + 0.5 * step, step)
    costs = [_trimmed_cost(_rates_at(t - d * 1e9, t_imu, om_imu), y) for d in grid]
    k = int(np.argmin(costs))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    res = minimize_scalar(
        lambda d: _trimmed_cost(_rates_at(t - d * 1e9, t_imu, om_imu), y),
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 1e-6},
    )
    return float(res.x), k in (0, len(grid) - 1)


def _offset_std(t, y, t_imu, om_imu, d, s, R, c, lags: int = 2, h: float = 0.02) -> float:
    """Sandwich standard deviation (s) of the time offset ``d`` (see the module docstring)."""
    r = y - s * _rates_at(t - d * 1e9, t_imu, om_imu) @ R.T - c
    alpha = (
        _rates_at(t - d * 1e9 + h * 1e9, t_imu, om_imu)
        - _rates_at(t - d * 1e9 - h * 1e9, t_imu, om_imu)
    ) / (2 * h)
    g = -s * alpha @ R.T  # d(prediction)/d(offset)
    wts = _huber_weights(r)
    return _hac_std(wts * np.sum(g * r, axis=1), float(np.sum(wts[:, None] * g * g)), lags, 2)


def _lines_to_reference(camera: CameraModel, stamp_row: float) -> float:
    """Lines read from pixel line ``stamp_row`` to the camera's reference line, in readout
    order: :meth:`~rs_localizer.camera.CameraModel.time_offset` per unit line delay (negative
    where the readout reaches the reference line first, e.g. ``bottom_to_top`` with the stamp
    at line 0). The line delay being fitted, the camera's own is not used."""
    forward = READOUT_DIRECTIONS[camera.readout][1] >= 0
    return (camera.reference_line - float(stamp_row)) * (1.0 if forward else -1.0)


def _gyro_samples(
    stamps,
    ws,
    gyro,
    camera: CameraModel,
    stamp_row: float,
    estimate_offset: bool = False,
    max_offset: float = 0.05,
    step: float = 0.001,
):
    """Gyro rates at the frames' reference-line times, in the camera frame, against the
    frames' ``-w`` (per unit r): (x (n, 3) rad/s, y (n, 3) centred, R_ci (3, 3) IMU -> camera,
    c (3,) the fit's offset, ``-s R_ci bias``, the time offset (s; 0 unless
    ``estimate_offset``), its std (s; NaN unless estimated), True when the offset is at the
    search's end, (the frame times used (n,) ns, the sorted gyro stamps and rates)). The
    frame times depend on the line delay, so the similarity fit
    (:func:`~rs_localizer.accuracy.umeyama_alignment`), the time offset and the times are
    iterated. Raises ValueError for malformed gyro samples."""
    t_imu = np.asarray(gyro[0], dtype=np.int64)
    om_imu = np.asarray(gyro[1], dtype=float).reshape(-1, 3)
    if len(t_imu) != len(om_imu) or len(t_imu) < 2:
        raise ValueError("gyro needs (t_ns (M,), omega (M, 3)) with M >= 2")
    order = np.argsort(t_imu)
    t_imu, om_imu = t_imu[order], om_imu[order]
    y = -ws
    offset_lines = _lines_to_reference(camera, stamp_row)
    margin = max_offset if estimate_offset else 0.0
    ld, d, at_end = 0.0, 0.0, False
    for _ in range(5):  # frame times depend on the line delay: iterate
        t = stamps + np.round(offset_lines * ld * 1e9).astype(np.int64)
        # (the same frames for every offset searched)
        inside = (t - margin * 1e9 >= t_imu[0]) & (t + margin * 1e9 <= t_imu[-1])
        ti, yi = t[inside], y[inside]
        if estimate_offset and len(ti) >= 3:
            d, at_end = _search_offset(ti, yi, t_imu, om_imu, max_offset, step)
        om = _rates_at(ti - np.round(d * 1e9), t_imu, om_imu)
        R_ci, c, s = umeyama_alignment(om, yi, with_scale=True, any_on_line=True)
        ld = max(s, 0.0) / camera.focal
    std = float("nan")
    if estimate_offset and len(ti) >= 3:
        std = _offset_std(ti, yi, t_imu, om_imu, d, s, R_ci, c)
    return om @ R_ci.T, yi - c, R_ci, c, d, std, at_end, (ti, t_imu, om_imu)


def _unobservable(
    n: int, s: float, std: float, rot: float, min_samples: int, max_relative_std: float
) -> str:
    """Why the fitted time scale ``s`` (std ``std``) from ``n`` samples of RMS rotation ``rot``
    (rad/s) is not a calibration, or ``""`` if it is."""
    if n < min_samples:
        return f"{n} samples (need {min_samples})"
    if not s > 0:
        return "the fitted time scale is not positive (wrong readout direction?)"
    if not std <= max_relative_std * s:
        return (
            f"too little rotation: relative std {std / abs(s):.3g} > "
            f"{max_relative_std:g} (rotation rms {rot:.3g} rad/s)"
        )
    return ""


def line_delay_verdict(line_delay: float, std: float, max_relative_std: float = 0.05) -> str:
    """Why a line delay (s) of standard deviation ``std`` (s) fitted elsewhere (the marker
    map's bundle adjustment) is not a calibration, or ``""`` if it is: the rule
    :func:`fit_line_delay` applies to its own fit (a positive value, a relative standard
    deviation within ``max_relative_std``, the same default)."""
    if not line_delay > 0:
        return "the fitted line delay is not positive (wrong readout direction?)"
    if not std <= max_relative_std * line_delay:
        return (
            f"too little rotation: relative std {std / abs(line_delay):.3g} > {max_relative_std:g}"
        )
    return ""


@dataclass(frozen=True)
class _Fit:
    """One fit's figures before the observability verdicts (see :func:`fit_line_delay`)."""

    s: float
    std: float
    rms: float
    samples: int
    frames_used: int
    rotation_rms: float
    R_ci: np.ndarray | None = None
    bias: np.ndarray | None = None
    rotation_std: np.ndarray | None = None
    rotation_worst_axis: np.ndarray | None = None
    bias_std: np.ndarray | None = None
    time_offset: float | None = None
    time_offset_std: float | None = None
    time_offset_reason: str = ""


def _checked_inputs(stamps_ns, orientations, w, max_time_offset, time_offset_step):
    """The inputs as arrays ((K,) int64, (K, 3, 3), (K, 3)); ValueError when they disagree."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    Os = np.asarray(orientations, dtype=float).reshape(-1, 3, 3)
    ws = np.asarray(w, dtype=float).reshape(-1, 3)
    if not (len(stamps) == len(Os) == len(ws)):
        raise ValueError(
            f"need as many stamps, orientations and w: {len(stamps)}, {len(Os)}, {len(ws)}"
        )
    if not (max_time_offset > 0 and time_offset_step > 0):
        raise ValueError(
            f"max_time_offset and time_offset_step must be > 0, got {max_time_offset}, "
            f"{time_offset_step}"
        )
    return stamps, Os, ws


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(x * x, axis=1)))) if len(x) else 0.0


def _fit_between_frames(stamps, Os, ws, max_dt: float, uniformity: float) -> _Fit | None:
    """The slope from Simpson triplets of the frames' own rotation; None below 2 triplets."""
    x, y, used = _simpson_samples(stamps, Os, ws, max_dt, uniformity)
    if len(x) < 2:
        return None
    s, std, rms = _robust_slope(x, y)
    return _Fit(s, std, rms, len(x), len(used), _rms(x))


def _huber_weights(r: np.ndarray) -> np.ndarray:
    """Huber weights (threshold 3 robust sigma) of (n, 3) residuals, as :func:`_robust_slope`."""
    rn = np.linalg.norm(r, axis=1)
    scale = 1.4826 * np.median(rn) / np.sqrt(2.0) + 1e-300
    k = 3.0 * scale * np.sqrt(3.0)
    return np.where(rn <= k, 1.0, k / np.maximum(rn, 1e-300))


def _sandwich(J: np.ndarray, r: np.ndarray, lags: int = 2) -> np.ndarray:
    """Sandwich covariance (p, p) of the parameters of a fit with Jacobian ``J`` (n, 3, p) and
    residuals ``r`` (n, 3): Huber weights, Newey-West (Bartlett kernel over ``lags``: nearby
    samples share frames), inflated by ``n / (n - p)``. A direction the data do not determine
    gets an infinite variance (:func:`~rs_localizer.calibration.marginal.loose_inverse`)."""
    n, p = len(r), J.shape[2]
    wts = _huber_weights(r)
    u = wts[:, None] * np.einsum("nip,ni->np", J, r)  # score per sample
    A = np.einsum("n,nip,niq->pq", wts, J, J)
    V = u.T @ u
    for lag in range(1, min(lags, n - 1) + 1):
        G = u[lag:].T @ u[:-lag]
        V += (1.0 - lag / (lags + 1.0)) * (G + G.T)
    V *= n / max(n - p, 1)
    Ainv, loose = loose_inverse(A)
    cov = Ainv @ V @ Ainv
    # the undetermined directions: infinite variance on every parameter they touch
    cov[loose, :] = cov[:, loose] = np.inf
    return cov


def _interval_rotations(t0_ns, t1_ns, t_imu, om_imu, bias, points: int = 17) -> np.ndarray:
    """(n, 3) rotation vector of the gyro's rotation over each interval ``[t0, t1]`` (ns, IMU
    clock), with ``bias`` (3,) subtracted, divided by the interval (rad/s): the interpolated
    rates composed over ``points - 1`` steps (SciPy rotations), so a turning axis costs no
    approximation."""
    from scipy.spatial.transform import Rotation

    u = np.linspace(0.0, 1.0, points)
    t = t0_ns[:, None] + (t1_ns - t0_ns)[:, None] * u[None, :]
    r = _rates_at(t.ravel(), t_imu, om_imu).reshape(len(t0_ns), points, 3) - bias
    step = (t1_ns - t0_ns) * 1e-9 / (points - 1)
    inc = 0.5 * (r[:, 1:] + r[:, :-1]) * step[:, None, None]  # (n, points - 1, 3)
    rot = Rotation.identity(len(t0_ns))
    for j in range(points - 1):
        rot = rot * Rotation.from_rotvec(inc[:, j])
    return rot.as_rotvec() / ((t1_ns - t0_ns) * 1e-9)[:, None]


def _mount_from_frame_rotations(
    t_ref, Os, t_imu, om_imu, d: float, max_dt: float, with_offset: bool = False
):
    """The camera-IMU rotation and the gyro bias from the rotation between consecutive frames'
    poses (which the images determine far better than one frame's angular velocity, whose
    readout-long fit trades it for the linear velocity) against the gyro's rotation over the
    same interval (:func:`_interval_rotations`): ``log(O_k^T O_{k+1}) = R_ci log(gyro rotation,
    bias removed)``. Kabsch with a centroid (the rotation of
    :func:`~rs_localizer.accuracy.umeyama_alignment`, Huber-reweighted), then the sandwich
    covariance of (phi (3) about the camera axes, bias (3)), with the time offset ``d`` as a
    nuisance parameter when ``with_offset`` (it was estimated from the same video). Returns
    (R_ci, bias, cov (6, 6), samples) or None below 10 pairs."""
    dt = np.diff(t_ref) * 1e-9
    d_ns = np.round(d * 1e9)
    t0, t1 = t_ref[:-1] - d_ns, t_ref[1:] - d_ns
    keep = (dt > 0) & (dt <= max_dt) & (t0 >= t_imu[0]) & (t1 <= t_imu[-1])
    if keep.sum() < 10:
        return None
    k = np.flatnonzero(keep)
    x = np.array([matrix_to_rotvec(Os[i].T @ Os[i + 1]) for i in k]) / dt[k][:, None]
    wts, bias = np.ones(len(k)), np.zeros(3)
    for _ in range(3):  # the gyro's rotation with the bias taken out, then the bias again
        g = _interval_rotations(t0[k], t1[k], t_imu, om_imu, bias)
        for _ in range(10):
            # (its rotation: x - mean x = R (g - mean g))
            R, _, _ = umeyama_alignment(g, x, weights=wts, any_on_line=True)
            W = wts / wts.sum()
            delta = W @ g - R.T @ (W @ x)  # x = R (g - delta): what is left of the bias
            r = x - (g - delta) @ R.T
            wts = _huber_weights(r)
        bias = bias + delta
    z = (g - delta) @ R.T
    cols = [-skew(z), np.broadcast_to(-R, (len(k), 3, 3))]
    if with_offset:  # the time offset as a nuisance parameter: d(mean gyro)/d(offset)
        dg = -(_rates_at(t1[k], t_imu, om_imu) - _rates_at(t0[k], t_imu, om_imu)) / dt[k][:, None]
        cols.append((dg @ R.T)[:, :, None])
    J = np.concatenate(cols, axis=2)
    return R, bias, _sandwich(J, r)[:6, :6], len(k)


def _fit_to_gyro(
    stamps,
    Os,
    ws,
    gyro,
    camera: CameraModel,
    stamp_row: float,
    estimate_time_offset: bool,
    max_time_offset: float,
    time_offset_step: float,
    max_time_offset_std: float,
    max_dt: float,
) -> _Fit:
    """The slope and the time offset from the frames' angular velocity against the gyro
    (:func:`_gyro_samples`), then the mount rotation and the bias from the rotation between
    frames (:func:`_mount_from_frame_rotations`), with their standard deviations and the time
    offset's verdict."""
    x, y, R_ci, c, d, d_std, at_end, (_, t_imu, om_imu) = _gyro_samples(
        stamps,
        ws,
        gyro,
        camera,
        stamp_row,
        estimate_time_offset,
        max_time_offset,
        time_offset_step,
    )
    d_reason = ""
    if not estimate_time_offset:
        d = d_std = None
    elif not d_std <= max_time_offset_std:
        d_reason = (
            f"the rotation rate barely changes: std {d_std * 1e3:.3g} ms > "
            f"{max_time_offset_std * 1e3:g} ms"
        )
    elif at_end:
        d_reason = f"the best offset is at the end of the search (+-{max_time_offset:g} s)"
    s, std, rms = _robust_slope(x, y)
    # y = s R_ci (omega_imu - bias) = s R_ci omega_imu + c
    bias = -R_ci.T @ c / s if s > 0 else None
    rot_std = worst = bias_std = None
    if s > 0:
        # the frames' reference-line times (camera clock) with the fitted line delay
        t_ref = stamps + np.round(_lines_to_reference(camera, stamp_row) * s / camera.focal * 1e9)
        mount = _mount_from_frame_rotations(
            t_ref.astype(np.int64), Os, t_imu, om_imu, d or 0.0, max_dt, d is not None
        )
        if mount is not None:
            R_ci, bias, cov, _ = mount
            P = cov[:3, :3]
            rot_std = np.sqrt(np.diag(P))
            if np.all(np.isfinite(P)):
                _, Q = np.linalg.eigh(P)
                worst = Q[:, -1] * (1 if Q[np.argmax(np.abs(Q[:, -1])), -1] > 0 else -1)
            else:  # the axis the camera never turned about: the smallest gyro spread
                g = x @ R_ci  # (IMU frame rates at the frames)
                _, _, Vt = np.linalg.svd(g - g.mean(0), full_matrices=False)
                worst = R_ci @ Vt[-1]
                worst = worst * (1 if worst[np.argmax(np.abs(worst))] > 0 else -1)
            bias_std = np.sqrt(np.diag(cov[3:, 3:]))
    return _Fit(
        s,
        std,
        rms,
        len(x),
        len(x),
        _rms(x),
        R_ci,
        bias,
        rot_std,
        worst,
        bias_std,
        d,
        d_std,
        d_reason,
    )


def fit_line_delay(
    stamps_ns: np.ndarray,
    orientations: np.ndarray,
    w: np.ndarray,
    camera: CameraModel,
    gyro: tuple[np.ndarray, np.ndarray] | None = None,
    stamp_row: float = 0.0,
    max_dt: float = 0.1,
    uniformity: float = 0.1,
    min_samples: int = 10,
    max_relative_std: float = 0.05,
    model_error: float = 0.002,
    frames_failed: int = 0,
    estimate_time_offset: bool = True,
    max_time_offset: float = 0.05,
    time_offset_step: float = 0.001,
    max_time_offset_std: float = 0.001,
    max_rotation_std: float = float(np.radians(0.5)),
    max_bias_std: float = 0.005,
) -> ReadoutCalibration:
    """Fit the line delay to per-frame RS rotation rates (see the module docstring).

    Args:
        stamps_ns: (K,) frame stamps (ns), increasing; any constant offset from the
            reference line's time is fine without a gyro.
        orientations: (K, 3, 3) camera -> world at the reference line.
        w: (K, 3) rotation per unit RS coordinate (``RSPoseEstimate.w``).
        camera: focal length along the readout axis and the number of lines (its line delay
            is ignored); with a gyro also the reference line.
        gyro: optional ``(t_ns (M,), omega (M, 3) rad/s)`` gyro samples in the IMU frame; the
            frame times are then the stamp plus the time from line ``stamp_row`` to the
            reference line at the fitted line delay (negative where the readout reaches the
            reference line first: ``bottom_to_top``, ``right_to_left``).
        stamp_row: line whose capture time is the stamp (gyro only).
        max_dt: seconds; frames farther apart do not form a Simpson triplet.
        uniformity: relative difference allowed between a triplet's two intervals.
        min_samples, max_relative_std: observability thresholds (on the statistical std).
        model_error: relative systematic error added in quadrature to the std.
        frames_failed: reported as is.
        estimate_time_offset: with a gyro, estimate its time offset (else assume 0).
        max_time_offset: s, the offsets searched are within +- this.
        time_offset_step: s, the search grid's step (then refined).
        max_time_offset_std: s; a larger standard deviation: the offset is not observable.
        max_rotation_std: rad; a camera-IMU rotation with a larger standard deviation about
            any axis is not observable (the motion did not turn enough about that axis). At
            1 rad/s a mount 0.5 deg off puts 0.009 rad/s into the angular velocity, twice the
            error of a typical gyro's measurement over one readout.
        max_bias_std: rad/s; a gyro bias with a larger standard deviation on any axis is not
            observable (the node's default ``imu.gyro_bias_sigma``).
    Returns:
        :class:`ReadoutCalibration`.
    Raises:
        ValueError: inconsistent array shapes, ``max_time_offset`` or ``time_offset_step``
            not > 0.
    """
    stamps, Os, ws = _checked_inputs(stamps_ns, orientations, w, max_time_offset, time_offset_step)
    if gyro is None:
        fit = _fit_between_frames(stamps, Os, ws, max_dt, uniformity)
        if fit is None:
            return ReadoutCalibration(
                None,
                None,
                len(_simpson_samples(stamps, Os, ws, max_dt, uniformity)[2]),
                False,
                samples=len(_simpson_samples(stamps, Os, ws, max_dt, uniformity)[0]),
                reason="too few consecutive frames",
                frames_failed=frames_failed,
            )
    else:
        fit = _fit_to_gyro(
            stamps,
            Os,
            ws,
            gyro,
            camera,
            stamp_row,
            estimate_time_offset,
            max_time_offset,
            time_offset_step,
            max_time_offset_std,
            max_dt,
        )
    reason = _unobservable(
        fit.samples, fit.s, fit.std, fit.rotation_rms, min_samples, max_relative_std
    )
    return _calibration(
        fit, camera, reason, model_error, frames_failed, max_rotation_std, max_bias_std
    )


def _mount_verdicts(
    fit: _Fit, max_rotation_std: float, max_bias_std: float
) -> tuple[bool | None, bool | None, str]:
    """Whether the gyro fit determines the camera-IMU rotation and the gyro bias, and a
    warning naming what the motion leaves undetermined and the motion that would determine
    it."""
    if fit.R_ci is None:
        return None, None, ""
    if fit.rotation_std is None or fit.bias_std is None:
        return False, False, "too few frames for the camera-IMU rotation and the gyro bias"
    rot_ok = bool(np.all(fit.rotation_std <= max_rotation_std))
    bias_ok = bool(np.all(fit.bias_std <= max_bias_std))
    msgs = []
    if not rot_ok:
        worst = fit.rotation_worst_axis
        about = (
            "about camera axis [" + ", ".join(f"{v:.2f}" for v in worst) + "]"
            if worst is not None
            else "about some axis"
        )
        msgs.append(
            f"the camera-IMU rotation {about} is not determined "
            f"(std {np.degrees(np.max(fit.rotation_std)):.3g} deg > "
            f"{np.degrees(max_rotation_std):.3g} deg)"
        )
    if not bias_ok:
        msgs.append(
            f"the gyro bias is not determined (std {np.max(fit.bias_std):.3g} rad/s > "
            f"{max_bias_std:.3g} rad/s)"
        )
    if msgs:
        msgs.append(
            "the camera turned about too few axes: record a video that rotates it about all "
            "three axes (pan, tilt and roll in turn)"
        )
    return rot_ok, bias_ok, "; ".join(msgs)


def _calibration(
    fit: _Fit,
    camera: CameraModel,
    reason: str,
    model_error: float,
    frames_failed: int,
    max_rotation_std: float,
    max_bias_std: float,
) -> ReadoutCalibration:
    """The :class:`ReadoutCalibration` of a fit: the systematic term added to the slope's
    std, the verdicts, the figures withheld where the line delay is not observable."""
    ok = not reason
    s = fit.s
    std = float(np.hypot(fit.std, model_error * abs(s)))
    rot_ok, bias_ok, mount_reason = _mount_verdicts(fit, max_rotation_std, max_bias_std)
    d = fit.time_offset
    return ReadoutCalibration(
        line_delay=s / camera.focal if ok else None,
        line_delay_std=std / camera.focal if ok else None,
        frames_used=int(fit.frames_used),
        observable=ok,
        seconds_per_unit_r=s,
        seconds_per_unit_r_std=std,
        readout_time=s / camera.focal * camera.lines if ok else None,
        samples=fit.samples,
        rotation_rms=fit.rotation_rms,
        reason=reason,
        camera_imu_rotation=fit.R_ci,
        gyro_bias=fit.bias if ok else None,
        residual_rms=fit.rms,
        frames_failed=frames_failed,
        time_offset=d if ok and d is not None and not fit.time_offset_reason else None,
        time_offset_std=fit.time_offset_std if ok and d is not None else None,
        time_offset_reason=fit.time_offset_reason if ok else "",
        camera_imu_rotation_std=fit.rotation_std,
        camera_imu_rotation_observable=(rot_ok and ok) if rot_ok is not None else None,
        gyro_bias_std=fit.bias_std if ok else None,
        gyro_bias_observable=(bias_ok and ok) if bias_ok is not None else None,
        mount_reason=mount_reason,
    )


def calibrate_line_delay(
    frames: Iterable[tuple],
    camera: CameraModel,
    solver: str = "r6p_1lin",
    options: EstimateOptions | None = None,
    gyro: tuple[np.ndarray, np.ndarray] | None = None,
    stamp_row: float = 0.0,
    **fit_args: float,
) -> ReadoutCalibration:
    """Estimate a rolling-shutter camera's line delay and its standard deviation from a video
    with rotation, ignoring the line delay ``camera`` states.

    Args:
        frames: iterable of ``(stamp_ns, points2d (N, 2), points3d (N, 3)[, scores])`` in
            time order (2D-3D correspondences per frame, as :func:`estimate_rs_pose` takes).
        camera: :class:`CameraModel` with the intrinsics, distortion and readout direction.
        solver, options: the per-frame estimator's.
        gyro: optional ``(t_ns (M,), omega (M, 3))`` gyro samples (IMU frame, rad/s) to use
            instead of the rotation between frames.
        stamp_row: line whose capture time is the frame stamp (gyro only).
        fit_args: :func:`fit_line_delay` thresholds.
    Returns:
        :class:`ReadoutCalibration` (``observable=False`` and no line delay when the rotation
        does not pin it).
    """
    stamps, Os, ws, failed = per_frame_rates(frames, camera, solver, options)
    return fit_line_delay(
        stamps, Os, ws, camera, gyro=gyro, stamp_row=stamp_row, frames_failed=failed, **fit_args
    )
