"""Camera intrinsics, lens distortion and rolling-shutter timing.

A :class:`CameraModel` turns measured (distorted) pixel coordinates into what the solvers take:
calibrated image points ``x`` (undistorted, normalized) and the RS coordinate ``r`` of each
observation. ``r`` is the **measured** pixel coordinate along the readout axis, in normalized
units: for top-to-bottom readout ``r = (v_px - cy) / fy``. So ``r - r0`` is proportional to the
capture time relative to the reference row::

    t_i - t_ref = (r_i - r0) * seconds_per_unit_r,   seconds_per_unit_r = line_delay * fy

(``fx`` for horizontal readout). Without distortion ``r = d . x`` exactly (``d`` the readout
direction of :mod:`rs_localizer.geometry`); with distortion ``r`` differs from ``d . x`` by a
per-point offset that :meth:`CameraModel.normalize` returns.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ._jit import kernel
from .geometry import rotvec_to_matrix

__all__ = [
    "DISTORTION_MODELS",
    "MAX_LINE_DELAY",
    "MAX_READOUT_TIME",
    "MAX_STAMP_NS",
    "READOUT_DIRECTIONS",
    "CameraModel",
    "FrameTime",
    "Stamp",
    "checked_stamp",
    "reference_stamp_ns",
]

#: s/line: the largest ``line_delay`` a :class:`CameraModel` takes (the node's
#: ``rs.line_delay`` range). Rolling-shutter sensors read a line in about 5-100 us; 10 ms
#: leaves room for slow sensors and for the readout calibration's stand-in camera of one
#: second per unit of ``r`` (``1 / focal`` s/line, focal >= 100 px), and refuses delays of
#: seconds per line, which give readout times of minutes
MAX_LINE_DELAY = 0.01

#: s: the largest ``readout_time`` (a whole frame's) :meth:`CameraModel.from_readout_time`
#: takes (the node's ``rs.readout_time`` range)
MAX_READOUT_TIME = 1.0

#: the largest stamp (ns) a frame or a gyro sample may carry: an int64 nanosecond count
MAX_STAMP_NS = 2**63 - 1

#: readout direction name -> (image axis: 0 = u/columns, 1 = v/rows; sign; direction vector d)
#: undistortion stops when the point re-distorts to within this many pixels of the measured
#: one (OpenCV's TERM_CRITERIA_EPS of ``undistortPoints``; at most 20 iterations)
UNDISTORT_EPS_PX = 1e-6

READOUT_DIRECTIONS = {
    "top_to_bottom": (1, 1.0, (0.0, 1.0)),
    "bottom_to_top": (1, -1.0, (0.0, -1.0)),
    "left_to_right": (0, 1.0, (1.0, 0.0)),
    "right_to_left": (0, -1.0, (-1.0, 0.0)),
}

#: sensor_msgs/CameraInfo distortion models we support and their coefficient counts.
DISTORTION_MODELS = {
    "plumb_bob": (0, 4, 5, 8),
    "rational_polynomial": (0, 4, 5, 8),
    "equidistant": (0, 4),
    "none": (0,),
}


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera with OpenCV distortion and rolling-shutter timing.

    Attributes:
        K: (3, 3) intrinsic matrix in pixels.
        D: (n,) distortion coefficients in the order of sensor_msgs/CameraInfo (OpenCV order):
            plumb_bob / rational_polynomial ``k1 k2 p1 p2 [k3 [k4 k5 k6]]``, equidistant
            ``k1 k2 k3 k4``. Empty or all zeros: no distortion.
        width, height: image size in pixels.
        line_delay: seconds between the exposure of consecutive lines (rows for vertical
            readout), in ``[0, MAX_LINE_DELAY]`` (:data:`MAX_LINE_DELAY`: 0.01 s). 0 means a
            global shutter.
        readout: one of ``top_to_bottom`` (default), ``bottom_to_top``, ``left_to_right``,
            ``right_to_left``.
        reference_row: pixel coordinate along the readout axis (a row for vertical readout) at
            which the pose is estimated (``r0``); ``None`` means the image centre line.
        distortion_model: ``plumb_bob``, ``rational_polynomial``, ``equidistant`` or ``none``.

    Raises:
        ValueError: for a non-finite or singular K, non-positive size, a line delay that is
            negative, not finite or above :data:`MAX_LINE_DELAY`, unknown readout or
            distortion model, or a coefficient count the model does not take.
    """

    K: np.ndarray
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))
    width: int = 640
    height: int = 480
    line_delay: float = 0.0
    readout: str = "top_to_bottom"
    reference_row: float | None = None
    distortion_model: str = "plumb_bob"

    def __post_init__(self):
        K = np.array(self.K, dtype=np.float64).reshape(3, 3)
        D = np.array(self.D, dtype=np.float64).ravel()
        if not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] != 1.0:
            raise ValueError(f"invalid camera matrix K={K.tolist()}: need fx, fy > 0, K[2,2] = 1")
        if not np.isfinite(D).all():
            raise ValueError("distortion coefficients contain NaN or inf")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"invalid image size {self.width}x{self.height}")
        if not 0.0 <= float(self.line_delay) <= MAX_LINE_DELAY:
            raise ValueError(
                f"line_delay must be in [0, {MAX_LINE_DELAY:g}] s/line (finite; rolling "
                f"shutters read a line in about 5-100 us), got {self.line_delay}"
            )
        if self.readout not in READOUT_DIRECTIONS:
            raise ValueError(
                f"unknown readout direction {self.readout!r}; "
                f"expected one of {sorted(READOUT_DIRECTIONS)}"
            )
        model = self.distortion_model or "plumb_bob"
        if model not in DISTORTION_MODELS:
            raise ValueError(
                f"unsupported distortion model {model!r}; "
                f"expected one of {sorted(DISTORTION_MODELS)}"
            )
        if np.any(D != 0) and len(D) not in DISTORTION_MODELS[model]:
            raise ValueError(f"{model} takes {DISTORTION_MODELS[model]} coefficients, got {len(D)}")
        if self.reference_row is not None and not np.isfinite(self.reference_row):
            raise ValueError("reference_row must be finite or None")
        K.setflags(write=False)
        D.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "line_delay", float(self.line_delay))
        object.__setattr__(self, "distortion_model", model)
        # derived once (the per-frame path reads them): not dataclass fields
        object.__setattr__(self, "_distorted", bool(np.any(D != 0)) and model != "none")

    # ---------------------------------------------------------------- construction helpers
    @classmethod
    def from_readout_time(
        cls, K: np.ndarray, readout_time: float, width: int, height: int, **kw: object
    ) -> CameraModel:
        """Build from the time to read one whole frame (s): ``line_delay = readout_time / lines``,
        ``lines`` = height for vertical readout, width for horizontal.

        Raises:
            ValueError: a ``readout_time`` that is negative, not finite or above
                :data:`MAX_READOUT_TIME` (1 s), and as the constructor.
        """
        readout = kw.get("readout", "top_to_bottom")
        if readout not in READOUT_DIRECTIONS:
            raise ValueError(f"unknown readout direction {readout!r}")
        lines = height if READOUT_DIRECTIONS[readout][0] == 1 else width
        if not 0.0 <= float(readout_time) <= MAX_READOUT_TIME:
            raise ValueError(
                f"readout_time must be in [0, {MAX_READOUT_TIME:g}] s (finite; a frame's "
                f"rolling-shutter readout), got {readout_time}"
            )
        return cls(K=K, width=width, height=height, line_delay=readout_time / lines, **kw)

    # ---------------------------------------------------------------- properties
    @property
    def has_distortion(self) -> bool:
        return self._distorted

    @property
    def readout_vector(self) -> np.ndarray:
        """(2,) direction ``d`` with ``r = d . x`` for undistorted normalized points ``x``."""
        return np.array(READOUT_DIRECTIONS[self.readout][2])

    @property
    def _axis(self) -> int:
        return READOUT_DIRECTIONS[self.readout][0]

    @property
    def focal(self) -> float:
        """Focal length (px) along the readout axis: the pixel size of one unit of ``r``."""
        return float(self.K[self._axis, self._axis])

    @property
    def mean_focal(self) -> float:
        """Mean of fx and fy (px): converts normalized reprojection errors to pixels."""
        return 0.5 * float(self.K[0, 0] + self.K[1, 1])

    @property
    def lines(self) -> int:
        """Number of lines read out (rows for vertical readout, columns for horizontal)."""
        return self.height if self._axis == 1 else self.width

    @property
    def readout_time(self) -> float:
        """Seconds to read the whole frame (``line_delay * lines``)."""
        return self.line_delay * self.lines

    @property
    def reference_line(self) -> float:
        """Reference pixel coordinate along the readout axis (default: image centre line)."""
        return (self.lines - 1) / 2.0 if self.reference_row is None else float(self.reference_row)

    @property
    def r0(self) -> float:
        """Reference RS coordinate in normalized units (see :meth:`rs_coordinate`)."""
        return float(self.rs_coordinate_of_line(self.reference_line))

    @property
    def seconds_per_unit_r(self) -> float:
        """Capture-time difference (s) per unit of ``r``: ``line_delay * focal``."""
        return self.line_delay * self.focal

    # ---------------------------------------------------------------- conversions
    def rs_coordinate_of_line(self, line: float | np.ndarray) -> float | np.ndarray:
        """Pixel coordinate along the readout axis -> RS coordinate ``r`` (normalized)."""
        a = self._axis
        sign = READOUT_DIRECTIONS[self.readout][1]
        return sign * (np.asarray(line, dtype=float) - self.K[a, 2]) / self.K[a, a]

    def rs_coordinate(self, points_px: np.ndarray) -> np.ndarray:
        """(N, 2) measured pixels -> (N,) RS coordinates of their capture lines (normalized)."""
        return self.rs_coordinate_of_line(np.asarray(points_px, dtype=float)[:, self._axis])

    def line_time(self, line: float | np.ndarray) -> np.ndarray:
        """Capture time (s) of a pixel line relative to the first line read out."""
        sign = READOUT_DIRECTIONS[self.readout][1]
        n = self.lines
        line = np.asarray(line, dtype=float)
        return (line if sign > 0 else (n - 1) - line) * self.line_delay

    def time_offset(self, from_line: float, to_line: float) -> float:
        """Capture time of ``to_line`` minus that of ``from_line`` (s): :meth:`line_time`'s
        arithmetic on two floats (no arrays: every frame's output stamp goes through here)."""
        a, b = float(from_line), float(to_line)
        if READOUT_DIRECTIONS[self.readout][1] < 0:
            n = self.lines
            a, b = (n - 1) - a, (n - 1) - b
        d = self.line_delay
        return float(b * d - a * d)

    def undistort(self, points_px: np.ndarray, compiled: bool = True) -> np.ndarray:
        """(N, 2) measured pixels -> (N, 2) undistorted normalized coordinates (OpenCV).
        ``compiled=False``: without the compiled pinhole kernel (the same formula in NumPy;
        for code that compiles nothing)."""
        p = np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 1, 2)
        if len(p) == 0:
            return np.zeros((0, 2))
        if not self.has_distortion:
            if not compiled:
                K, q = self.K, p.reshape(-1, 2)
                y = (q[:, 1] - K[1, 2]) / K[1, 1]
                return np.stack([(q[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0], y], axis=1)
            return _pinhole_normalize(p.reshape(-1, 2), self.K)
        if self.distortion_model == "equidistant":
            return cv2.fisheye.undistortPoints(p, self.K, self.D[:4]).reshape(-1, 2)
        # (OpenCV stops when the point reprojects within eps pixels: 1e-6 px is far below any
        # detector's noise and takes ~half the iterations of 1e-10 on mild distortion)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, UNDISTORT_EPS_PX)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
            return cv2.undistortPointsIter(p, self.K, self.D, None, None, crit).reshape(-1, 2)
        return cv2.undistortPoints(p, self.K, self.D, None, None, None, crit).reshape(-1, 2)

    def distort(self, xn: np.ndarray) -> np.ndarray:
        """(N, 2) undistorted normalized coordinates -> (N, 2) pixels (OpenCV projection)."""
        xn = np.ascontiguousarray(xn, dtype=np.float64)
        if len(xn) == 0:
            return np.zeros((0, 2))
        if not self.has_distortion:
            return xn @ self.K[:2, :2].T + self.K[:2, 2]
        P = np.concatenate([xn, np.ones((len(xn), 1))], axis=1).reshape(-1, 1, 3)
        z = np.zeros(3)
        if self.distortion_model == "equidistant":
            out, _ = cv2.fisheye.projectPoints(P, z, z, self.K, self.D[:4])
        else:
            out, _ = cv2.projectPoints(P, z, z, self.K, self.D)
        return out.reshape(-1, 2)

    def pixel_jacobian(self, xn: np.ndarray, compiled: bool = False) -> np.ndarray:
        """(N, 2, 2) ``A_i = d(distorted pixel) / d(undistorted normalized point)`` at each of
        the (N, 2) undistorted normalized points ``xn`` (px per normalized unit; analytic, for
        every model of :data:`DISTORTION_MODELS`): ``A_i (x' - x_i)`` is, to first order, the
        image error in the measured (distorted) image of a projection ``x'`` near ``x_i``.
        Without distortion every ``A_i`` is ``K[:2, :2]``; with distortion the skew
        ``K[0, 1]`` is not used (OpenCV's projections ignore it). Equidistant points are taken in
        front of the camera (``z = 1``, as :meth:`distort`). ``compiled``: the same formulas in
        one compiled call (:func:`distortion_jacobian`; equal up to rounding)."""
        xn = np.asarray(xn, dtype=np.float64).reshape(-1, 2)
        n = len(xn)
        if not self.has_distortion:
            return np.broadcast_to(self.K[:2, :2], (n, 2, 2)).copy()
        if compiled:
            return distortion_jacobian(np.ascontiguousarray(xn), *self.jacobian_arguments)
        x, y = xn[:, 0], xn[:, 1]
        r2 = x * x + y * y
        J = np.empty((n, 2, 2))
        if self.distortion_model == "equidistant":
            k = np.zeros(4)
            k[: min(4, len(self.D))] = self.D[:4]
            r = np.sqrt(r2)
            th = np.arctan(r)
            t2 = th * th
            poly = 1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))
            dpoly = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
            small = r < 1e-8
            rs = np.where(small, 1.0, r)
            # xd = s(r) x with s = theta_d / r; d xd / d x = s I + (s'(r) / r) x x^T
            s = np.where(small, 1.0, th * poly / rs)
            ds = (dpoly / (1 + rs * rs) * rs - th * poly) / (rs * rs)  # s'(r)
            g = np.where(small, 0.0, ds / rs)
            J[:, 0, 0] = s + g * x * x
            J[:, 0, 1] = g * x * y
            J[:, 1, 0] = g * x * y
            J[:, 1, 1] = s + g * y * y
        else:
            d = np.zeros(8)
            d[: min(8, len(self.D))] = self.D[:8]
            k1, k2, p1, p2, k3, k4, k5, k6 = d
            num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
            dnum = k1 + r2 * (2 * k2 + r2 * 3 * k3)
            dden = k4 + r2 * (2 * k5 + r2 * 3 * k6)
            rad = num / den
            drad = (dnum * den - num * dden) / (den * den)  # d rad / d r^2
            cross = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            J[:, 0, 0] = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            J[:, 0, 1] = cross
            J[:, 1, 0] = cross
            J[:, 1, 1] = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
        # (OpenCV's projections with distortion ignore the skew K[0, 1], as :meth:`distort`)
        J[:, 0] *= self.K[0, 0]
        J[:, 1] *= self.K[1, 1]
        return J

    @property
    def jacobian_arguments(self) -> tuple | None:
        """The arguments after the points of :func:`distortion_jacobian` for this camera's
        compiled :meth:`pixel_jacobian`: ``(d (8,) the distortion coefficients (the first 4
        of an ``equidistant`` model's, the rest zero), whether the model is ``equidistant``,
        fx, fy (px))``; None without distortion. Built once per camera (read only: every
        call shares the array)."""
        cached = self.__dict__.get("_jacobian_arguments", False)
        if cached is False:
            cached = None
            if self.has_distortion:
                fisheye = self.distortion_model == "equidistant"
                d = np.zeros(8)
                m = 4 if fisheye else 8
                d[: min(m, len(self.D))] = np.ravel(self.D)[:m]
                cached = (d, fisheye, float(self.K[0, 0]), float(self.K[1, 1]))
            object.__setattr__(self, "_jacobian_arguments", cached)
        return cached

    def pixel_jacobian_exact(self, xn: np.ndarray) -> np.ndarray:
        """:meth:`pixel_jacobian` (its NumPy formulas, the same numbers to the bit), faster on a
        few points: the equidistant model's arctangent in NumPy, the rest in one compiled
        call (:func:`fisheye_jacobian`; the other models' formulas have no transcendental
        function: :func:`distortion_jacobian`). (N, 2, 2) px per normalized unit at the (N, 2)
        undistorted normalized points ``xn``."""
        xn = np.ascontiguousarray(xn, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion or len(xn) == 0:
            return self.pixel_jacobian(xn)
        fx, fy = float(self.K[0, 0]), float(self.K[1, 1])
        if self.distortion_model == "equidistant":
            k = np.zeros(4)
            k[: min(4, len(self.D))] = self.D[:4]
            x, y = xn[:, 0], xn[:, 1]
            return fisheye_jacobian(xn, np.arctan(np.sqrt(x * x + y * y)), k, fx, fy)
        d = np.zeros(8)
        d[: min(8, len(self.D))] = self.D[:8]
        return distortion_jacobian(xn, d, False, fx, fy)

    @property
    def field_limit(self) -> float:
        """The edge of the lens model's field of view: for ``equidistant`` the largest angle
        from the optical axis (rad, beyond 90 degrees where the model says the lens sees
        it), elsewhere the largest undistorted normalized radius ``sqrt(x^2 + y^2)`` (``inf``
        without distortion). Beyond it the model's radial distortion stops growing with the
        angle (its polynomial turns back), so points there have no image: :meth:`project`
        gives them none. Computed once per camera."""
        cached = self.__dict__.get("_field_limit")
        if cached is None:
            cached = _field_limit(self.distortion_model, self.D, self.has_distortion)
            object.__setattr__(self, "_field_limit", cached)
        return cached

    def project(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) points in the camera's optical frame (m) -> (N, 2) distorted pixels, over
        the lens model's whole field of view (:attr:`field_limit`): the ``equidistant`` model
        from the angle to the optical axis, so also beyond 90 degrees where the lens sees
        there (OpenCV's fisheye projection divides by z first); the others in front of the
        camera. Rows outside the field of view (or behind a non-fisheye camera) are ``nan``.
        The same pixels as OpenCV's ``projectPoints`` / ``fisheye.projectPoints`` where
        those are valid."""
        P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
        out = np.full((len(P), 2), np.nan)
        if len(P) == 0:
            return out
        rho = np.hypot(P[:, 0], P[:, 1])
        K = self.K
        if self.distortion_model == "equidistant" and self.has_distortion:
            theta = np.arctan2(rho, P[:, 2])
            ok = np.isfinite(theta) & (theta <= self.field_limit)
            k = np.zeros(4)
            k[: min(4, len(self.D))] = self.D[:4]
            t2 = theta * theta
            td = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
            scale = np.where(
                rho > 0, td / np.where(rho > 0, rho, 1.0), 1.0 / np.where(P[:, 2] > 0, P[:, 2], 1.0)
            )
            xd = P[:, :2] * scale[:, None]
        else:
            ok = P[:, 2] > 1e-12
            z = np.where(ok, P[:, 2], 1.0)
            xn = P[:, :2] / z[:, None]
            ok &= np.hypot(xn[:, 0], xn[:, 1]) <= self.field_limit
            xd = np.where(ok[:, None], xn, 0.0)
            if self.has_distortion and ok.any():
                out[ok] = self.distort(xn[ok])
                return out
        uv = np.stack(
            [K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2], K[1, 1] * xd[:, 1] + K[1, 2]],
            axis=1,
        )
        out[ok] = uv[ok]
        return out

    def normalize(
        self, points_px: np.ndarray, compiled: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Everything the solvers need from measured pixels (``compiled=False``: in NumPy,
        for code that compiles nothing; the same formulas).

        Returns:
            (x, r, r0_eff): (N, 2) undistorted normalized points, (N,) RS coordinates of the
            measured lines, and (N,) per-point reference coordinate ``r0 - (r - d.x)`` to pass to
            :func:`rs_localizer.geometry.rs_project_first_order` so that the closed-form
            projection uses the distorted line as the capture time (equal to ``r0`` without
            distortion).
        """
        p = np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 2)
        x = self.undistort(p, compiled)
        return (x, *self.rs_coordinates(p, x, compiled))

    def rs_coordinates(
        self, points_px: np.ndarray, x: np.ndarray, compiled: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(r, r0_eff)`` of :meth:`normalize` for pixels ``points_px`` (N, 2) float64 whose
        undistorted normalized points ``x`` (N, 2) are known (``compiled=False``: in NumPy, the
        same formulas): (N,) RS coordinates of the measured lines and (N,) ``r0 - (r - d.x)``."""
        axis, sign, d = READOUT_DIRECTIONS[self.readout]
        if not compiled:
            K = self.K
            r = sign * (points_px[:, axis] - K[axis, 2]) / K[axis, axis]
            return r, self.r0 - (r - (d[0] * x[:, 0] + d[1] * x[:, 1]))
        return _rs_coordinates(points_px, x, self.K, axis, sign, d[0], d[1], self.r0)

    def project_rs(
        self,
        X: np.ndarray,
        R: np.ndarray,
        C: np.ndarray,
        w: np.ndarray | None = None,
        t: np.ndarray | None = None,
        iterations: int = 30,
    ) -> np.ndarray:
        """Forward rolling-shutter projection of world points with a constant-velocity pose.

        Each point is imaged at its own capture line: ``X_cam(tau) = expm(tau [w]x) R X + C +
        tau t`` with ``tau = r - r0`` the RS coordinate of the point's own *measured*
        (distorted) line (:meth:`rs_coordinate_of_line`), the model the estimator fits (paper
        eq. 4 with the exact rotation). The line is found by fixed-point iteration from the
        reference line (a contraction: the image moves far less than one line per line delay).
        ``w = t = 0`` (the default) is the global-shutter projection of the same pose.

        Args:
            X: (N, 3) world points (m). R: (3, 3), C: (3,) world -> camera at the reference
                line (``RSPoseEstimate.R``, ``.C``). w, t: (3,) model velocities per unit r
                (``RSPoseEstimate.w``, ``.t``: rad, m).
            iterations: fixed-point iterations on the line (stops earlier once every line
                moves by less than 1e-6 px).
        Returns:
            (N, 2) distorted pixels (:meth:`project`: over the lens model's whole field of
            view); ``nan`` rows for points outside it at their capture time (behind a
            non-fisheye camera, or where the model's distortion turns back:
            :attr:`field_limit`).
        Raises:
            ValueError: if ``X`` cannot be reshaped to (N, 3).
        """
        X = np.asarray(X, dtype=float).reshape(-1, 3)
        w = np.zeros(3) if w is None else np.asarray(w, dtype=float).reshape(3)
        t = np.zeros(3) if t is None else np.asarray(t, dtype=float).reshape(3)
        RX = X @ np.asarray(R, dtype=float).T
        C = np.asarray(C, dtype=float).reshape(3)
        axis = self._axis
        line = np.full(len(X), self.reference_line)
        uv = np.full((len(X), 2), np.nan)
        for _ in range(max(int(iterations), 1)):
            tau = self.rs_coordinate_of_line(line) - self.r0
            Rt = rotvec_to_matrix(tau[:, None] * w[None, :])
            p = np.einsum("nij,nj->ni", Rt, RX) + C + tau[:, None] * t
            uv = self.project(p)
            seen = np.isfinite(uv[:, axis])
            new = np.where(seen, np.clip(uv[:, axis], -self.lines, 2 * self.lines), line)
            done = np.all(np.abs(new - line) < 1e-6)
            line = new
            if done:
                break
        return uv

    def in_image(self, points_px: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: pixel inside ``[-margin, size - 1 + margin]``."""
        p = np.asarray(points_px, dtype=float)
        return (
            (p[:, 0] >= -margin)
            & (p[:, 0] <= self.width - 1 + margin)
            & (p[:, 1] >= -margin)
            & (p[:, 1] <= self.height - 1 + margin)
        )


# ---------------------------------------------------------------------- stamps
class Stamp(int):
    """A stamp (ns, int) that :func:`checked_stamp` accepted: a frame's header stamp (the
    capture time of row ``stamp_row``) or a gyro sample's. The type says it was checked: the
    stages after the entry that checked it take it as it is (:func:`checked_stamp` returns
    it unchanged). Arithmetic on it gives plain ints. Made by :func:`checked_stamp` (and
    :func:`rs_localizer.ros.conversions.checked_stamp_ns` for ROS messages), not directly."""

    __slots__ = ()


def checked_stamp(stamp_ns: Any, what: str = "frame") -> Stamp:
    """``stamp_ns`` (ns) as a :class:`Stamp` (a float is truncated, as ``int`` does), checked;
    a :class:`Stamp` is returned as it is (checked already).

    Raises:
        ValueError: a stamp that is not a finite number, or outside the int64 nanosecond
            range ``[-2**63, 2**63 - 1]`` (:data:`MAX_STAMP_NS`, about the year 2262): no
            ROS message, bag or clock carries it (e.g. a stamp in ns converted twice).
    """
    if type(stamp_ns) is Stamp:
        return stamp_ns
    if isinstance(stamp_ns, (int, np.integer)) and not isinstance(stamp_ns, (bool, np.bool_)):
        value = int(stamp_ns)
    else:
        try:
            f = float(stamp_ns)
        except (TypeError, ValueError):
            raise ValueError(f"{what} stamp must be a number of ns, got {stamp_ns!r}") from None
        if not np.isfinite(f):
            raise ValueError(f"{what} stamp must be finite, got {stamp_ns!r}")
        value = int(f)
    if not -MAX_STAMP_NS - 1 <= value <= MAX_STAMP_NS:
        raise ValueError(
            f"{what} stamp {stamp_ns!r} ns is beyond the int64 range [-2**63, 2**63 - 1] ns"
        )
    return Stamp(value)


def reference_stamp_ns(stamp_ns: int, camera: CameraModel | None, stamp_row: float,
                       clock_offset: float = 0.0) -> int:  # fmt: skip
    """The reference row's capture time (ns): the time of a frame's estimate, from its stamp
    ``stamp_ns`` (ns, the capture time of row ``stamp_row``, px along the readout):
    ``stamp_ns + (capture time of camera.reference_line - that of stamp_row)``, rounded to
    the ns (without a ``camera`` model, the stamp itself), plus ``clock_offset`` s rounded to
    the ns (a rig camera's time offset onto the rig's clock). The one computation of a
    frame's reference time: the single-camera and the rig localizers, the rig's grouping,
    the rig node's queue and the rig's calibration take it from here."""
    t = int(stamp_ns)
    if camera is not None:
        t += int(round(camera.time_offset(stamp_row, camera.reference_line) * 1e9))
    return t + int(round(clock_offset * 1e9))


@dataclass(frozen=True)
class FrameTime:
    """A frame's times (ns), made once where the frame enters a localizer
    (:meth:`FrameTime.of`) and handed on: ``stamp_ns``, its stamp, checked (:class:`Stamp`:
    the capture time of row ``stamp_row``); ``reference_ns``, the capture time of its
    camera's reference line (:func:`reference_stamp_ns`), the time of its pose."""

    stamp_ns: Stamp
    reference_ns: int

    @classmethod
    def of(cls, stamp_ns: Any, camera: CameraModel, stamp_row: float) -> FrameTime:
        """The times of a frame stamped ``stamp_ns`` (ns, row ``stamp_row``, px) seen by
        ``camera``.

        Raises:
            ValueError: a stamp :func:`checked_stamp` refuses.
        """
        stamp = checked_stamp(stamp_ns)
        return cls(stamp, reference_stamp_ns(stamp, camera, stamp_row))


def _field_limit(model: str, D: np.ndarray, distorted: bool) -> float:
    """:attr:`CameraModel.field_limit` of a distortion ``model`` with coefficients ``D``: the
    first angle (equidistant, up to 180 degrees) or normalized radius (others, up to 1e3)
    where the radial distortion stops increasing, found on a fine grid and refined by
    bisection; ``pi`` / ``inf`` where it never does."""
    if not distorted:
        return np.pi if model == "equidistant" else np.inf
    d = np.zeros(8)
    d[: min(8, len(D))] = D[:8]
    if model == "equidistant":

        def radial(a):
            a2 = a * a
            return a * (1 + a2 * (d[0] + a2 * (d[1] + a2 * (d[2] + a2 * d[3]))))

        top = np.pi
    else:
        k1, k2, _, _, k3, k4, k5, k6 = d

        def radial(a):
            a2 = a * a
            num = 1 + a2 * (k1 + a2 * (k2 + a2 * k3))
            den = 1 + a2 * (k4 + a2 * (k5 + a2 * k6))
            with np.errstate(divide="ignore", invalid="ignore"):
                return a * num / den

        top = 1e3
    grid = np.concatenate(
        [np.linspace(0.0, min(top, 10.0), 20001)[1:], np.geomspace(10.0, top, 2001)]
    )
    grid = grid[grid <= top]
    r = radial(grid)
    bad = ~(np.isfinite(r) & (np.diff(np.concatenate([[0.0], r])) > 0))
    if not bad.any():
        return float(top)
    k = int(np.argmax(bad))
    lo, hi = (grid[k - 2] if k > 1 else 0.0), grid[k]
    for _ in range(60):  # (the last point where the radius still grows)
        mid = 0.5 * (lo + hi)
        h = 1e-7 * max(mid, 1e-9)
        up, down = radial(mid + h), radial(mid - h)
        if np.isfinite(up) and up > down:
            lo = mid
        else:
            hi = mid
    return float(lo)


@kernel
def _pinhole_normalize(p, K):
    """(N, 2) pixels -> normalized coordinates ``K^-1 [u, v, 1]`` (upper-triangular K)."""
    out = np.empty((p.shape[0], 2))
    for i in range(p.shape[0]):
        y = (p[i, 1] - K[1, 2]) / K[1, 1]
        out[i, 0] = (p[i, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        out[i, 1] = y
    return out


@kernel
def _rs_coordinates(p, x, K, axis, sign, d0, d1, r0):
    """RS coordinates ``r`` of the measured pixels p (N, 2) and the per-point reference
    ``r0 - (r - d . x)`` of :meth:`CameraModel.normalize` (x the undistorted points)."""
    n = p.shape[0]
    r = np.empty(n)
    r0e = np.empty(n)
    for i in range(n):
        r[i] = sign * (p[i, axis] - K[axis, 2]) / K[axis, axis]
        r0e[i] = r0 - (r[i] - (d0 * x[i, 0] + d1 * x[i, 1]))
    return r, r0e


@kernel
def _fisheye_scales(r, th, k):
    """``(s, g)`` of the equidistant model's distortion Jacobian ``s I + g x x^T`` at a point
    of undistorted radius ``r`` and angle ``th = arctan(r)`` from the optical axis, ``k`` its
    k1..k4 (first four entries): ``s = theta_d / r``, ``g = s'(r) / r`` (1, 0 at the axis)."""
    t2 = th * th
    poly = 1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))
    dpoly = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
    if r < 1e-8:
        return 1.0, 0.0
    return th * poly / r, ((dpoly / (1 + r * r) * r - th * poly) / (r * r)) / r


@kernel
def distortion_jacobian(xn, d, fisheye, fx, fy):
    """:meth:`CameraModel.pixel_jacobian` with distortion, compiled: (N, 2, 2) at the (N, 2)
    undistorted normalized points ``xn``; ``d`` (8,) the equidistant model's k1..k4
    (``fisheye``) or OpenCV's k1, k2, p1, p2, k3, k4, k5, k6 (zeros beyond the model's)."""
    n = xn.shape[0]
    J = np.empty((n, 2, 2))
    for i in range(n):
        x, y = xn[i, 0], xn[i, 1]
        r2 = x * x + y * y
        if fisheye:
            r = np.sqrt(r2)
            sc, g = _fisheye_scales(r, np.arctan(r), d)
            a00, a01, a11 = sc + g * x * x, g * x * y, sc + g * y * y
            a10 = a01
        else:
            k1, k2, p1, p2, k3, k4, k5, k6 = d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
            num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
            dnum = k1 + r2 * (2 * k2 + r2 * 3 * k3)
            dden = k4 + r2 * (2 * k5 + r2 * 3 * k6)
            rad = num / den
            drad = (dnum * den - num * dden) / (den * den)
            cross = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            a00 = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            a01 = a10 = cross
            a11 = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
        J[i, 0, 0], J[i, 0, 1] = a00 * fx, a01 * fx
        J[i, 1, 0], J[i, 1, 1] = a10 * fy, a11 * fy
    return J


@kernel
def fisheye_jacobian(xn, th, k, fx, fy):
    """:meth:`CameraModel.pixel_jacobian` of the equidistant model: (N, 2, 2) at the (N, 2)
    undistorted normalized points ``xn`` with ``th`` (N,) their angles from the optical axis
    (``arctan`` of their radius, given: NumPy's, so that the result is the NumPy formulas'
    to the bit), ``k`` (4,) k1..k4, ``fx``, ``fy`` the focal lengths (px)."""
    n = xn.shape[0]
    J = np.empty((n, 2, 2))
    for i in range(n):
        x, y = xn[i, 0], xn[i, 1]
        sc, g = _fisheye_scales(np.sqrt(x * x + y * y), th[i], k)
        J[i, 0, 0], J[i, 0, 1] = (sc + g * x * x) * fx, (g * x * y) * fx
        J[i, 1, 0], J[i, 1, 1] = (g * x * y) * fy, (sc + g * y * y) * fy
    return J
