"""Marker maps from a rolling-shutter video: the model, the input and the result.

Input: per frame the detected corners of square fiducial markers (ArUco/AprilTag order TL, TR,
BR, BL, measured pixels) and the frame's capture time. Output: each marker's 6-DoF pose and
world corners, with a gauge-fixed covariance, and each frame's pose and twist.

Model. Every corner observation is explained by the estimator's model (paper eq. 4 with the exact
rotation, docs/architecture.md "Conventions"; :mod:`rs_localizer.estimation.refine`) written in
a world centred on the frame's camera at its reference line::

    x_i ~ pi( expm(tau_i [w]x) (R X_i + C) + tau_i t ),   tau_i = r_i - r0 (measured line)

with ``x_i`` the undistorted normalized corner and ``X_i`` a marker corner: the point in the
camera at the reference line, turned by the rotation over ``tau_i`` and moved by the camera's
velocity. With ``C = 0`` this is eq. 4; written so, it is the same for every world frame (a rigid
change of the world changes ``R`` and ``C`` only, never ``w`` or ``t``), where eq. 4 with the exact
rotation depends on the world's origin at second order in ``tau |w|`` (``expm`` acting on ``R X``
but not on ``C``). Here the velocities are per second: ``w = s * w_s``, ``t = s * t_s`` with
``s = line_delay * focal`` (:attr:`CameraModel.seconds_per_unit_r`), so that one global line
delay can be calibrated and consecutive frames can be tied by the same velocities. A marker is a
square of known side: its corners are ``R_m c_k + p_m`` with ``c_k`` the corners of OpenCV's
``SOLVEPNP_IPPE_SQUARE`` (``(-h, h, 0), (h, h, 0), (h, -h, 0), (-h, -h, 0)``, ``h`` half the
side; z out of the face). The adjustment's world frame is the gauge marker's (the anchor at its
pose when given, else the most detected marker in its own frame; not adjusted); the motion tie
is written on the camera centres, so the whole cost does not depend on that frame, and the
output frame (``MappingOptions``: an anchor, surveyed markers, gravity-aligned) is applied
after the adjustment (:mod:`~rs_localizer.mapping.marker_frame`).

The solver is SciPy's ``least_squares`` (trust-region reflective with a sparse Jacobian from
``jac_sparsity``; a robust loss, then outlier rejection), and a last plain least-squares
adjustment run to convergence with exact sparse solves
(:meth:`~rs_localizer.mapping.marker_problem.MarkerProblem.polish`): the map, the line delay and
the velocities are then the same, up to a rigid motion of the map, in every output frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..pose import model_twist

__all__ = [
    "FrameDetections",
    "MappingOptions",
    "MarkerMapResult",
    "OutputFrame",
    "fit_rigid",
    "frame_velocities",
    "marker_corners_local",
]


def frame_velocities(W: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera's own velocities of the adjustment's frames: ``(omega (N, 3) rad/s, v (N, 3)
    m/s)`` in each camera's frame, ``omega = -W``, ``v = -T``, from the per-second velocities
    ``W`` (N, 3) rad/s and ``T`` (N, 3) m/s of the corner model (module docstring: the
    estimator's model in a world centred on the camera). The estimator's conversion
    :func:`~rs_localizer.pose.model_twist` with ``C = 0`` and ``s = 1``; like the model, it
    does not depend on the world frame."""
    z = np.array([model_twist(np.zeros(3), W[k], T[k], 1.0) for k in range(len(W))])
    z = z.reshape(-1, 6)
    return z[:, 3:], z[:, :3]


def marker_corners_local(side: float) -> np.ndarray:
    """(4, 3) corners of a square marker of side ``side`` (m) in its own frame, in ArUco order
    TL, TR, BR, BL: ``(-h, h, 0), (h, h, 0), (h, -h, 0), (-h, -h, 0)``, ``h = side / 2``, z out
    of the face (the object points of OpenCV's ``SOLVEPNP_IPPE_SQUARE``).

    Raises:
        ValueError: for a side that is not finite and positive.
    """
    if not np.isfinite(side) or side <= 0:
        raise ValueError(f"marker side must be finite and > 0, got {side}")
    h = 0.5 * float(side)
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def fit_rigid(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) minimizing ``|R src + t - dst|`` over (N, 3)
    points (Kabsch; SciPy ``Rotation.align_vectors`` on the centred points)."""
    from scipy.spatial.transform import Rotation

    cs, cd = src.mean(0), dst.mean(0)
    rot, _ = Rotation.align_vectors(dst - cd, src - cs)
    R = rot.as_matrix()
    return R, cd - R @ cs


@dataclass(frozen=True)
class FrameDetections:
    """One frame's marker detections.

    Attributes:
        stamp: capture time of the frame's reference line (s).
        corners: marker id -> (4, 2) measured (distorted) pixel corners in ArUco order.
    """

    stamp: float
    corners: dict = field(default_factory=dict)


@dataclass(frozen=True)
class MappingOptions:
    """Options of :func:`~rs_localizer.mapping.marker_map.map_markers`.

    Attributes:
        marker_size: default side length of the markers' black square (m).
        marker_sizes: marker id -> side (m) for markers of another size.
        anchor: id of the marker that fixes the world frame; ``None`` (and no ``anchors``):
            the most detected marker (the best-observed one, whose pose the video fixes best).
        anchor_pose: ``(R, p)``: the anchor's rotation (3, 3, marker -> world) and centre (3,)
            (m) in the world; ``None``: the anchor's own frame is the world.
        anchors: id -> (4, 3) surveyed world corners (m) of several markers: the world frame
            is the rigid best fit of their mapped corners to these (a frame several markers
            fix); excludes ``anchor``.
        max_anchor_residual: RMS corner residual (m) of the surveyed anchors after the fit
            that is always accepted; above it and above 3 times the position std the map
            states for them, the anchors disagree with the video (an error).
        shared_errors: weight the detections in the covariance for the detector's errors that repeat
            when a marker is seen again from the same viewpoint
            (:func:`~rs_localizer.mapping.marker_covariance.covariance_in_gauge`); False: every
            detection independent.
        planar_ambiguity: widen each marker's rotation covariance along its mirrored tilt where the
            cost says the mirror fits
            (:func:`~rs_localizer.mapping.marker_covariance.covariance_in_gauge`).
        view_cluster_rad: viewing directions within this angle (rad; and distances within
            30 %) count as one viewpoint for ``shared_errors``.
        coverage_std: markers whose stated position std (largest axis, m) exceeds this are
            named in ``MarkerMapResult.coverage`` with what would help.
        max_frame_rotation_deg, max_frame_position_mm: bounds on the output frame's own
            uncertainty above which the map tools warn.
        global_shutter: adjust with the global-shutter model (velocities fixed at 0, no motion
            tie): for global-shutter cameras and for comparison.
        calibrate_readout: estimate one line delay for the whole video (needs the motion tie).
        corner_offset: estimate one corner offset (pixels) for the whole video: the detected
            corners lie this far inside the marker's projected square, along its diagonals.
            OpenCV's subpixel refinement of the outer corner of a blurred black square is
            biased inwards (about 0.2 px on rendered images); left in, it makes every marker
            look smaller, so further away, by a fixed fraction.
        corner_offset_sigma_px: standard deviation (pixels) of a zero-mean prior on the
            corner offset: where the video's views fix it poorly (markers seen from a narrow
            range of distances) it stays near zero instead of wandering.
        motion_sigma_rot, motion_sigma_pos: standard deviations (rad, m) of the motion-model tie
            between consecutive frames (the change of rotation and of camera centre between
            their reference lines against the mean of their velocities times the time between
            them; independent of the world frame); ``None``
            (either): no tie.
        motion_sigma_angular_accel: standard deviation of the camera's angular acceleration
            (rad/s^2) between tied frames: their angular velocities differ by about this times
            the time between them (hand-held: ~10 rad/s^2).
        max_frame_gap: consecutive frames further apart than this multiple of the median frame
            interval are not tied (a gap in the video).
        loss, f_scale_px: robust loss of ``least_squares`` and its scale (pixels).
        reject_px: a detection whose four corners' RMS reprojection error exceeds this (pixels)
            after the robust adjustment is rejected (counted) and the map adjusted again.
        min_views: a marker seen in fewer frames with a pose is left out of the map (reported
            in ``MarkerMapResult.unmapped``): its planar two-fold ambiguity and its depth are
            not fixed by one view.
        max_nfev: function-evaluation budget of each ``least_squares`` call but the last.
        final_max_iter: steps of the last, plain least-squares adjustment (the map, the line
            delay and their stds are its solution: Levenberg-Marquardt with exact sparse solves,
            :meth:`~rs_localizer.mapping.marker_problem.MarkerProblem.polish`, run to
            convergence; a few steps from the robust adjustment's end point).
        frame: the output frame when neither ``anchor_pose`` nor ``anchors`` is given:
            ``anchor`` (the anchor's own frame, z out of its face), ``auto`` (gravity-aligned,
            z up, from the first of the accelerometer, markers on two or more walls, floor
            markers that the video offers; the anchor's frame with a note when none), or
            ``imu``, ``walls``, ``floor`` (that source only);
            :func:`~rs_localizer.mapping.marker_frame.find_up`.
        floor_markers: ids of markers lying on the floor (up = their normal).
    """

    marker_size: float
    marker_sizes: dict = field(default_factory=dict)
    anchor: int | None = None
    anchor_pose: tuple | None = None
    anchors: dict | None = None
    max_anchor_residual: float = 0.05
    shared_errors: bool = True
    planar_ambiguity: bool = True
    view_cluster_rad: float = 0.35
    coverage_std: float = 0.01
    max_frame_rotation_deg: float = 0.5
    max_frame_position_mm: float = 20.0
    global_shutter: bool = False
    calibrate_readout: bool = False
    corner_offset: bool = True
    corner_offset_sigma_px: float = 0.2
    motion_sigma_rot: float | None = 2e-3
    motion_sigma_pos: float | None = 5e-3
    motion_sigma_angular_accel: float = 10.0
    max_frame_gap: float = 1.5
    loss: str = "huber"
    f_scale_px: float = 1.0
    reject_px: float = 3.0
    min_views: int = 2
    max_nfev: int = 60
    final_max_iter: int = 50
    frame: str = "anchor"
    floor_markers: tuple = ()

    def side(self, marker_id: int) -> float:
        """Side length (m) of marker ``marker_id``."""
        return float(self.marker_sizes.get(int(marker_id), self.marker_size))


@dataclass
class OutputFrame:
    """How the map's output frame is fixed and how well.

    Attributes:
        kind: ``anchor`` (one marker at its pose), ``surveyed`` (best fit to surveyed
            markers), ``best-observed`` (the most detected marker) or ``gravity`` (z up,
            origin at the anchor's centre, x out of its wall:
            :func:`~rs_localizer.mapping.marker_frame.gravity_transform`).
        anchors: the markers that fix it.
        rotation_std_deg, position_std_mm: the frame's own uncertainty against the map as a
            whole (the rigid best fit of all mapped markers' centres): standard deviation of
            its rotation (largest axis, deg) and of its origin (largest axis, mm).
        covariance: (6, 6) that uncertainty (rotation rad, position m; map axes).
        residual_mm: RMS corner residual of the surveyed markers after the fit (0 else).
        shared_error_correlation: correlation of the detections' errors from one viewpoint
            (:func:`~rs_localizer.mapping.marker_covariance.covariance_in_gauge`) used in the
            covariances.
        up_source: for ``gravity``, where up comes from: ``imu``, ``walls`` or ``floor``
            (:func:`~rs_localizer.mapping.marker_frame.find_up`); else ``""``.
        up_markers: the markers that fix up (walls, floor).
        note: what fixed up, or why the map is not gravity-aligned (none of the sources).
    """

    kind: str
    anchors: list
    rotation_std_deg: float
    position_std_mm: float
    covariance: np.ndarray
    residual_mm: float = 0.0
    shared_error_correlation: float = 0.0
    up_source: str = ""
    up_markers: list = field(default_factory=list)
    note: str = ""


@dataclass
class MarkerMapResult:
    """Result of :func:`~rs_localizer.mapping.marker_map.map_markers`. World frame: the output frame
    (see ``MappingOptions`` and ``frame``).

    Attributes:
        anchor: the anchor's id (the first of the markers that fix the frame).
        corners: id -> (4, 3) world corners (m), ArUco order.
        marker_poses: id -> ``(R, p)``: (3, 3) marker -> world rotation, (3,) centre (m).
        marker_covariance: id -> (6, 6) covariance of (rotation [rad, world axes, left
            perturbation], centre [m]) in the output frame, the frame's own uncertainty
            included; zeros for a single anchor (exact in its own frame).
        marker_std: id -> (6,) square roots of that diagonal.
        observations: id -> number of detections used in the adjustment.
        frame_ids: (K,) indices into the input frames of the frames with a pose.
        orientation, position: (K, 3, 3) camera -> world, (K, 3) camera centre (m), at each
            frame's reference line.
        angular_velocity, linear_velocity: (K, 3) the camera's own velocities in its optical
            frame (rad/s, m/s); zeros with ``global_shutter``.
        line_delay: seconds between lines (calibrated or the camera's).
        line_delay_std: its standard deviation (s) with ``calibrate_readout`` (the line
            delay's marginal of the adjustment's ``(J^T J)^-1``, weighted as the markers'
            covariance), NaN otherwise. Neither depends on the output frame (``--anchor-pose``,
            ``frame``; module docstring): the same to the solver's precision.
        readout_verdict: with ``calibrate_readout``, why the line delay is not observable
            (the rule of ``rs-localizer calibrate-readout``:
            :func:`~rs_localizer.calibration.readout.line_delay_verdict`), ``""`` when it is;
            ``None`` without ``calibrate_readout``.
        rmse_px: RMS reprojection error of the detections kept (pixels).
        num_rejected: detections rejected as outliers.
        num_frames_skipped: frames without detections or without a pose.
        unmapped: id -> why the marker is not in the map: seen in too few frames, or never
            detected (an id missing between the detected ids 0..max, named when few are).
        inconsistent: id -> two (3,) world positions (m): one id detected at two places
            (left out of the map, never averaged).
        timings: stage -> seconds.
        global_shutter: the global-shutter model was used.
        corner_offset_px: the detector's corner offset found (pixels, inwards along the
            diagonals; ``MappingOptions.corner_offset``), 0 when not estimated.
        corner_offset_std_px: its standard deviation (pixels; every detection independent),
            NaN when not estimated.
        frame: :class:`OutputFrame`: how the output frame is fixed, and how well.
        coverage: id -> why the marker's stated std exceeds ``MappingOptions.coverage_std``
            and what would help.
        marker_shape_std: id -> (4,) each corner's shape-only std (m, rms per axis): its uncertainty
            relative to the other markers' corners, the frame's and the map's rigid motion as a
            whole left out (:func:`~rs_localizer.mapping.marker_covariance.shape_covariance`). A
            camera localized against the map sees these, not ``marker_std``: the latter also holds
            where the whole map sits in the output frame, which is common to all markers.
        refused_videos: video index (0-based, ``videos`` of ``map_markers``) -> why the video
            was refused (another place: no marker in common, or its markers in common lie
            elsewhere; the message names it); the map is built from the others.
    """

    anchor: int
    corners: dict
    marker_poses: dict
    marker_covariance: dict
    marker_std: dict
    observations: dict
    frame_ids: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    line_delay: float
    rmse_px: float
    num_rejected: int
    num_frames_skipped: int
    unmapped: dict
    inconsistent: dict
    timings: dict
    global_shutter: bool
    corner_offset_px: float = 0.0
    corner_offset_std_px: float = float("nan")
    frame: OutputFrame | None = None
    coverage: dict = field(default_factory=dict)
    marker_shape_std: dict = field(default_factory=dict)
    refused_videos: dict = field(default_factory=dict)
    line_delay_std: float = float("nan")
    readout_verdict: str | None = None
