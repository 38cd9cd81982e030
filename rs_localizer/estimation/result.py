"""What :func:`~rs_localizer.estimation.estimate_rs_pose` returns: :class:`RSPoseEstimate`, its
failure reasons (a camera's and a rig's, documented once: :data:`FAILURE_REASONS`,
:data:`RIG_FAILURE_REASONS`, :data:`RIG_REFUSALS`), and the conversions of the model (R, C, w,
t per unit RS coordinate) to the camera's physical velocities and the output covariances, and
between a camera's model and the model of the body (a rig) it is mounted on
(:func:`camera_model_of_rig`, :func:`rig_model_of_camera`, :func:`camera_estimate`,
:func:`body_estimate`; a camera alone is the body at the identity mounting).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from ..camera import CameraModel
from ..frames import Mounting, base_twist_covariance
from ..geometry import rotvec_to_matrix, skew
from ..pose import (
    ROS_ORDER,
    PoseWithCovariance,
    RSModel,
    RSPose,
    frozen_instance,
    model_twist,
    model_twist_jacobian,
)
from .implementation import NUMPY
from .outputs import output_covariance_kernel, physical_velocities_kernel
from .plausibility import CHEIRALITY, IMPLAUSIBLE_MOTION

__all__ = [
    "AMBIGUOUS_TAG",
    "CAMERAS_DISAGREE",
    "CHEIRALITY",
    "CONTRADICTS_TRACK",
    "DEGENERATE_GEOMETRY",
    "FAILURE_REASONS",
    "GYRO_REJECTIONS",
    "IMPLAUSIBLE_MOTION",
    "INCONSISTENT_FIT",
    "NO_HYPOTHESIS",
    "PLANAR_SCENE",
    "RIG_FAILURE_REASONS",
    "RIG_REFUSALS",
    "TOO_FEW_INLIERS",
    "TOO_FEW_POINTS",
    "UNCONFIRMED",
    "EstimationFailed",
    "RSPoseEstimate",
    "body_estimate",
    "built_estimate",
    "camera_estimate",
    "camera_model_of_rig",
    "output_covariance",
    "per_view_fields",
    "physical_velocities",
    "rig_model_jacobian",
    "rig_model_of_camera",
]

# The reasons a frame (a camera's, or a rig's: :func:`~.rig.estimate_rig_pose`, the rig
# estimator, and :class:`~rs_localizer.tracking.video.Localizer`, its tracker) gives no pose,
# each documented here once. The velocity bounds and ``min_inliers`` are
# :class:`~.options.EstimateOptions`', the rig's as a camera's.

#: fewer valid rows than ``min_inliers`` (a rig: fewer than 6 over all cameras, or no camera
#: with 3)
TOO_FEW_POINTS = "too_few_points"
#: no minimal sample gave a model (a camera or a rig)
NO_HYPOTHESIS = "no_hypothesis"
#: the best model has fewer than ``min_inliers`` inliers (before or after the refinement; a
#: rig: over all cameras, after it)
TOO_FEW_INLIERS = "too_few_inliers"
#: the points, or the inliers, are identical or on one 3D line, or their pixels lie within the
#: inlier threshold of one image line (a rig: every camera's, or fewer than 3 in each: its
#: rays in one plane through its centre)
DEGENERATE_GEOMETRY = "degenerate_geometry"
#: a solver that cannot work on coplanar points (R9P) was given a planar scene
PLANAR_SCENE = "planar_scene"
#: the inliers are one plane of a 3D scene seen from behind it: most of the other points lie
#: beyond that plane, on the far side from the camera (:func:`~.finalize.final_estimate`)
INCONSISTENT_FIT = "inconsistent_fit"
#: a frame of a few coplanar points (one square marker's corners) whose two plane poses fit
#: them alike and no prediction tells apart (:mod:`.single_tag`)
AMBIGUOUS_TAG = "ambiguous_tag"
#: a rig's cameras with points contradict each other (each group explains its own points and
#: not the others', e.g. a wrong mounting or stamp) and neither the number of cameras on each
#: side nor the prediction tells which are right (:func:`~.rig.estimate_rig_pose`: the
#: cameras' consensus)
CAMERAS_DISAGREE = "cameras_disagree"
#: the rig's tracker refused a rig frame posed from one camera's points alone while other
#: cameras of the rig run, whose pose contradicts the rig's track (the prediction of the rig
#: frames before it): a camera whose clock or stamp is off, or whose matches are wrong, is not
#: posed alone
CONTRADICTS_TRACK = "contradicts_track"
#: the rig's tracker refused a rig frame posed from one camera's points alone with no track to
#: check it against (the rig's start, or after the track ended) while two or more other
#: cameras run: the track of a rig of three or more cameras starts from a rig frame of cameras
#: that agree with each other
UNCONFIRMED = "unconfirmed"
#: every reason an unsuccessful estimate can give, in the order the estimator checks them
FAILURE_REASONS = (
    TOO_FEW_POINTS,
    DEGENERATE_GEOMETRY,
    PLANAR_SCENE,
    AMBIGUOUS_TAG,
    NO_HYPOTHESIS,
    IMPLAUSIBLE_MOTION,
    TOO_FEW_INLIERS,
    CHEIRALITY,
    INCONSISTENT_FIT,
)
#: every reason an unsuccessful rig estimate (:func:`~.rig.estimate_rig_pose`) can give, in
#: the order the rig estimator checks them: the camera's of the same names (a rig's
#: implausible motion is its own angular and linear velocity's; its cheirality every
#: inlier's in its own camera), and ``cameras_disagree``
RIG_FAILURE_REASONS = (
    TOO_FEW_POINTS,
    DEGENERATE_GEOMETRY,
    NO_HYPOTHESIS,
    IMPLAUSIBLE_MOTION,
    TOO_FEW_INLIERS,
    CHEIRALITY,
    INCONSISTENT_FIT,
    CAMERAS_DISAGREE,
)
#: why the rig's tracker refused a rig frame the estimator posed (counted
#: ``rig.failed.<reason>``, as the estimator's failure reasons)
RIG_REFUSALS = (CONTRADICTS_TRACK, UNCONFIRMED)


#: why a gyro measurement was not used (``RSPoseEstimate.gyro_rejection``): ``contradicted``
#: (the gyro's rate disagrees with the image-alone refinement's), ``fewer_inliers`` (the aided
#: estimate explains markedly fewer points than the unaided one), ``aided_failed``
GYRO_REJECTIONS = ("contradicted", "fewer_inliers", "aided_failed")


class EstimationFailed(Exception):
    """A stage of the estimator found that the frame gives no pose; ``reason`` is one of
    :data:`FAILURE_REASONS`. Caught by the estimator, which returns its failed estimate
    (:meth:`estimate`; never raised to its caller). ``behind``: the frame's points
    behind their cameras where the last checks found them (``cheirality``), else 0."""

    def __init__(self, reason: str, behind: int = 0):
        super().__init__(reason)
        self.reason, self.behind = reason, int(behind)

    def estimate(
        self, per_view: tuple, num_valid_per_view: tuple, num_rows: int, **fields: object
    ) -> RSPoseEstimate:
        """The failed estimate of this failure, a camera's or a rig's
        (:func:`built_estimate`: no fit; ``per_view``, ``num_valid_per_view``, ``num_rows``
        and ``fields`` as there): its reason and, with ``cheirality``, the points the refused
        fit put behind their cameras (``num_behind``, also counted in ``num_dropped``)."""
        return built_estimate(
            self.reason, None, None, per_view, num_valid_per_view, num_rows,
            num_behind=self.behind, **fields,
        )  # fmt: skip


@dataclass(frozen=True)
class RSPoseEstimate(PoseWithCovariance):
    """Result of :func:`~rs_localizer.estimation.estimate_rs_pose` (one camera's frame) and of
    :func:`~rs_localizer.estimation.rig.estimate_rig_pose` (a rig frame: views of several
    cameras, each at its mounting): a :class:`~rs_localizer.pose.PoseWithCovariance`
    (``pose``, ``pose_covariance``, ``twist_covariance``: keyword arguments) with the solver's
    ``model`` and the estimator's record. Frames: world/map, and the body the estimate poses:
    the camera optical frame (REP 103) of one camera's estimate, the rig's frame (the frame of
    the mountings) of a rig's. A rig estimate's rows are its views' rows in order; its
    per-view fields say which view each count belongs to (one camera's estimate: its one
    view's).

    A failed estimate (``success`` False) has no fit, whatever its reason, also one found after
    a fit (``implausible_motion``, ``cheirality``, ``inconsistent_fit``, a rig's
    ``cameras_disagree``): the fields that describe a fit keep their defaults (``model`` and
    ``pose`` the identity and zeros; no covariances nor ``acceleration_sensitivity``;
    ``rmse_px``, ``planarity``, ``condition_number`` NaN; ``planar``, ``initial_used``,
    ``motion_prior_used``, ``gyro_used``, ``single_tag``, ``few_points`` False;
    ``initial_explained`` -1; ``motion_model`` ``"rolling_shutter"``), never what a fit that
    was refused had been fitted with. It reports the rows (``num_valid``,
    ``num_valid_per_view``, ``num_dropped``; with ``cheirality``, ``num_behind``: the rows the
    refused fit put behind their cameras, what the failure is about), the search (``solver``,
    ``ransac_iterations``, ``implementation``, ``ignored_inputs``) and the gyro's check where
    the gyro was judged (``gyro_rejected``, ``gyro_rejection``, ``gyro_chi2``: a gyro the image
    contradicted before the frame failed without it, or, with ``cameras_disagree``, the joint
    fit's check); a rig's ``cameras_disagree`` also the joint fit's ``num_inliers_per_view``
    and ``disagreeing``.

    Attributes:
        success: a pose was found with at least ``min_inliers`` inliers.
        failure: reason code when not successful, else ``None`` (a rig's:
            :data:`RIG_FAILURE_REASONS`): ``too_few_points`` (fewer
            valid rows than ``min_inliers``), ``no_hypothesis`` (no sample gave a model),
            ``too_few_inliers``, ``degenerate_geometry`` (the points, or the inliers, are
            identical or on one 3D line, or their pixels lie within the inlier threshold of
            one image line), ``planar_scene`` (a solver that cannot work on coplanar points,
            R9P, given a planar scene), ``implausible_motion`` (the best model, or every
            hypothesis, moves faster than ``max_angular_velocity`` / ``max_linear_velocity``),
            ``cheirality`` (an inlier of the best model is not in front of the camera at its
            capture time), ``inconsistent_fit`` (the inliers are one plane of a 3D scene
            and most other points lie beyond it, away from the camera: the plane is seen
            from behind, as mirrored or reflected correspondences make it),
            ``ambiguous_tag`` (a frame of a few coplanar points, too few for the solver, e.g.
            one marker's four corners, whose two plane poses fit them alike and no prediction
            tells apart: :mod:`.single_tag`).
        solver: solver name used (a rig's: ``gr6p_1lin``, whatever its ``motion_model``; a
            rig frame posed by one camera's few points alone: that camera's estimator's).
        model: the solvers' :class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)``: ``R`` (3, 3),
            ``C`` (3,) world -> camera at the reference row (``X_cam = R X + C``), ``w``, ``t``
            (3,) model velocities per unit RS coordinate (rad, m per normalized unit); a rig's:
            world -> rig at the rig's reference time (``x_rig = R X + C``), ``w``, ``t`` per
            second (rad/s, m/s; each view's own model:
            :meth:`~rs_localizer.estimation.view.View.camera_model`); the identity and zeros
            on failure.
        pose: the same as a :class:`~rs_localizer.pose.RSPose` (no stamp): ``orientation``
            (3, 3) camera -> world (``R^T``), ``position`` (3,) camera centre in the world (m),
            ``angular_velocity``, ``linear_velocity`` (3,) the camera's own velocity in its
            optical frame (rad/s, m/s), with ``angular_velocity_world`` and
            ``linear_velocity_world`` (3,) in the world frame; the identity and zeros on
            failure.
        inliers: (N,) bool over the input rows (invalid rows are False; a rig's: its views'
            rows in order, ``inliers_per_view`` split by view).
        num_valid: rows that passed validation (finite, undistortable, within
            ``max_point_norm``); num_behind: valid rows behind the camera at their capture
            time under the final model (0 without one; a ``cheirality`` failure's: under the
            refused final model); num_dropped: rows not used, those that failed validation
            plus ``num_behind``.
        ransac_iterations: hypotheses drawn. timings: stage -> seconds.
        covariance: (12, 12) over (rotation of the camera in the world [rad, world axes],
            position [m, world], angular velocity [rad/s, camera frame], linear velocity [m/s,
            camera frame]), or ``None``.
        pose_covariance: (6, 6) ROS order (x, y, z, rot x, rot y, rot z), world frame, or
            ``None``. twist_covariance: (6, 6) ROS order (vx, vy, vz, wx, wy, wz), camera
            frame, or ``None`` (global shutter).
        rmse_px: RMS reprojection error of the inliers (pixels).
        planar: the inliers' 3D points are coplanar (:func:`~.degeneracy.planarity` below
            :data:`~.degeneracy.PLANAR_TOLERANCE`): the per-frame RS model is near-degenerate
            and the velocities (and the rotation they trade against) lean on the motion prior.
        planarity: that thickness-to-extent ratio of the inliers' 3D points (NaN on failure).
        condition_number: unit-free condition number of the data's information matrix of the
            refined parameters (:func:`~.degeneracy.condition_number`; NaN without
            refinement): ~5-300 on 3D scenes, 1e4-1e6 on planar ones.
        motion_prior_used: the final refinement was maximum a posteriori (see
            ``EstimateOptions.motion_prior``; with ``gyro_used``, on the gyro's rate too, a
            rig's on the gyro's alone: the rig estimator takes no motion prior); on planar
            frames the velocities, and the rotation they trade against, lean on the prior.
        initial_explained: points within ``InitialModel.gate_px`` of the initial model (-1
            without one; failed estimates do not report it); initial_used: the initial model
            seeded RANSAC and pre-rotated its samples (False: too few points explained, the
            estimator ran as without it).
        acceleration_sensitivity: (12, 6) first-order change of (rotation, position, angular
            velocity, linear velocity) per (angular acceleration [rad/s^2], linear acceleration
            [m/s^2]) during the readout, camera frame; only with
            ``RefineOptions.acceleration_sensitivity``, else ``None``.
        gyro_used: the estimate used the gyro measurement passed to the estimator (its
            velocities, pose and covariance include it).
        gyro_rejected: a gyro measurement was passed but the image disagreed with it (or the
            aided estimate failed where an unaided one succeeded); the estimate is the unaided
            one.
        gyro_rejection: why, with ``gyro_rejected`` (:data:`GYRO_REJECTIONS`), else ``""``.
        implementation: the implementation that ran, ``"compiled"`` (the numba kernels) or
            ``"numpy"`` (:mod:`~rs_localizer.estimation.implementation`).
        motion_model: ``"rolling_shutter"`` (the pose and velocities of eq. 4) or
            ``"global_shutter"`` (``w = t = 0``: the global-shutter ``p3p``; a camera with no
            readout time, ``line_delay`` 0; or a frame whose points show no motion,
            :func:`~.finalize.still_final`, so the six velocity parameters would only fit its
            noise into the pose). A global-shutter estimate of a
            rolling-shutter solver reports zero velocities with the rolling-shutter fit's
            ``twist_covariance`` and velocity block of ``covariance`` (what the frame says of
            the motion: none, within it), or ``None`` and zero rows and columns where the
            camera has no readout time (unobserved); or
            ``"predicted_motion"``: a frame of a few points (one marker's corners, or a few
            markers', :mod:`.single_tag`) posed on the rolling-shutter model with the
            velocities held at the tracker's prediction or the gyro's (not estimated from the
            frame: no ``twist_covariance``; the (12, 12) ``covariance`` gives them the motion
            prior's).
            Such a frame without either is ``"global_shutter"``.
        single_tag: the frame had too few points for the solver and was posed from a few
            coplanar ones, e.g. one square marker's four corners (:mod:`.single_tag`).
        few_points: the frame had too few points for the solver and was posed from them
            alone, without RANSAC (:func:`~.single_tag.few_points_estimate`): a few coplanar
            ones (``single_tag`` too) or a few on more than one plane, e.g. two markers'
            corners.
        ignored_inputs: the inputs given that this implementation could not use, by name
            (:data:`~rs_localizer.estimation.implementation.NUMPY_UNUSED` on the NumPy
            implementation; ``"gyro"`` for a gyro given to a global-shutter solver or camera);
            ``()``: every input given was used.
        model_covariance: (12, 12) over the model's ``(delta, C, w, t)`` (``R =
            expm([delta]x) R_0``; rad, m, and the velocities in the units of ``model``), what
            ``covariance`` is converted from, or ``None`` (no refinement, or a singular
            information matrix). A global-shutter estimate's velocity rows and columns are its
            rolling-shutter fit's, or zero where the frame was taken at one time or posed by
            the global-shutter fallback (:func:`~.finalize.still_fallback`, whose fit's
            velocities are in ``twist_covariance`` and ``covariance`` alone).
        gyro_chi2: chi-square (3 dof) of the gyro measurement against the angular velocity the
            image alone gives near the aided estimate
            (:func:`~rs_localizer.estimation.gyro.gyro_image_chi2`; ``inf`` when the image
            alone gives no angular velocity; NaN when no gyro was checked or the aided
            estimate failed).
        inliers_per_view: ``inliers`` split by view: one (N_c,) bool per view over its input
            rows (one camera's estimate: its one view's, ``(inliers,)``).
        num_inliers_per_view: (M,) the inliers of each view (zeros on failure, but with a
            rig's ``cameras_disagree``: the joint fit's; one camera's: ``(num_inliers,)``).
        num_valid_per_view: (M,) the valid rows of each view (one camera's:
            ``(num_valid,)``).
        disagreeing: a rig's voting views (at least
            :data:`~rs_localizer.estimation.rig.VOTE_MIN_POINTS` points) the cameras' consensus
            left out: on success those outvoted by the cameras that posed the rig (their points
            are no inliers, their ``num_inliers_per_view`` zero); with ``cameras_disagree``
            every view of the groups that contradict each other.
    """

    success: bool
    failure: str | None = None
    solver: str = ""
    model: RSModel = field(default_factory=RSModel.identity)
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    num_valid: int = 0
    num_dropped: int = 0
    num_behind: int = 0
    ransac_iterations: int = 0
    timings: dict = field(default_factory=dict)
    covariance: np.ndarray | None = None
    rmse_px: float = float("nan")
    planar: bool = False
    planarity: float = float("nan")
    condition_number: float = float("nan")
    motion_prior_used: bool = False
    initial_explained: int = -1
    initial_used: bool = False
    acceleration_sensitivity: np.ndarray | None = None
    gyro_used: bool = False
    gyro_rejected: bool = False
    gyro_rejection: str = ""
    implementation: str = "compiled"
    ignored_inputs: tuple[str, ...] = ()
    motion_model: str = "rolling_shutter"
    single_tag: bool = False
    few_points: bool = False
    model_covariance: np.ndarray | None = None
    gyro_chi2: float = float("nan")
    inliers_per_view: tuple[np.ndarray, ...] = ()
    num_inliers_per_view: tuple[int, ...] = ()
    num_valid_per_view: tuple[int, ...] = ()
    disagreeing: tuple[int, ...] = ()

    @property
    def num_inliers(self) -> int:
        """Inliers of the final model (0 on failure)."""
        return int(np.count_nonzero(self.inliers))

    @classmethod
    def _trusted(cls, **values) -> RSPoseEstimate:
        """The estimate of these fields by name (``success`` given, every other field not
        given at its default), as the constructor builds it (no copies, no checks), by
        :func:`~rs_localizer.pose.frozen_instance` (an estimate per frame: its construction
        costs a few attribute stores).

        Raises:
            TypeError: a name that is no field, or no ``success``."""
        return frozen_instance(cls, values)

    def _replaced(self, **changes) -> RSPoseEstimate:
        """This estimate with the fields ``changes`` (by name) replaced: what
        ``dataclasses.replace`` returns, built as :meth:`_trusted` builds an estimate (no
        copies, no checks; an estimate per rig frame of one camera's points)."""
        d = self.__dict__
        return frozen_instance(type(self), {n: d[n] for n in _FIELD_NAMES} | changes)

    def _with_model_covariance(
        self,
        cov: np.ndarray | None,
        seconds_per_unit: float = 1.0,
        mounting: Mounting | None = None,
        **changes,
    ) -> RSPoseEstimate:
        """This estimate with the fields ``changes`` (by name; ``model`` among them, if it
        changes) and the (12, 12) covariance ``cov`` over that model's ``(delta, C, w, t)``,
        or None (no covariances), and the output covariances derived of it
        (:func:`output_covariance` at ``seconds_per_unit`` s per unit of the model's time; a
        twist covariance only where this estimate has one): a camera's estimate as its
        body's (:func:`body_estimate`), a rig's covariance widened by its cameras'
        disagreement (:func:`~.rig.estimate_rig_pose`).

        A global-shutter estimate of a frame that shows no motion, posed by the global-shutter
        fallback (:func:`~.finalize.still_fallback`), holds its velocities at zero (``cov``'s
        velocity rows and columns zero, or ``seconds_per_unit`` 0) but carries the twist
        covariance its rolling-shutter fit measured (:func:`~.finalize.unobserved_twist`):
        it keeps that one, in ``twist_covariance`` and in the velocity block of
        ``covariance``, never the zeros (or None) of velocities that were held. As it is
        (``mounting`` None: the model's velocities neither widened nor moved, as where only
        the pose is widened), or in the frame of the body the camera is mounted on with
        ``mounting`` (:func:`~rs_localizer.frames.base_twist_covariance`, exact at zero
        velocities). Such an estimate whose ``cov`` is None keeps its twist covariance too.

        Raises:
            ValueError: a measured twist covariance that is not (6, 6) (``mounting`` given).
        """
        out = (None, None, None)
        if cov is not None:
            R, C, w, _ = changes.get("model", self.model)
            out = output_covariance(cov, R, C, w, seconds_per_unit, self.implementation != NUMPY)
        twist = out[2] if self.twist_covariance is not None else None
        held = self.twist_covariance is not None and (
            cov is None or seconds_per_unit <= 0 or not np.any(cov[6:, 6:])
        )
        full = out[0]
        if held:  # (the fit's measured twist, not the held velocities' zeros)
            twist = self.twist_covariance
            if mounting is not None:
                twist = base_twist_covariance(twist, mounting)
            if full is not None:
                full = np.array(full, dtype=float)
                # (ROS (v, omega) -> the covariance's (omega, v))
                full[6:, 6:] = twist[np.ix_(ROS_ORDER, ROS_ORDER)]
        return self._replaced(
            model_covariance=cov, covariance=full, pose_covariance=out[1],
            twist_covariance=twist, **changes,
        )  # fmt: skip


#: the names of :class:`RSPoseEstimate`'s fields (:meth:`RSPoseEstimate._replaced`)
_FIELD_NAMES = tuple(f.name for f in fields(RSPoseEstimate) if f.init)


def built_estimate(
    failure: str | None,
    model: RSModel | None,
    pose: RSPose | None,
    per_view: tuple,
    num_valid_per_view: tuple,
    num_rows: int,
    covariances: tuple | None = None,
    **fields: object,
) -> RSPoseEstimate:
    """The :class:`RSPoseEstimate` of one camera's frame or of a rig frame (its views' rows in
    order), posed or failed: the one builder of both estimators' results
    (:func:`~.estimate.estimate_rs_pose`, :func:`~.rig.estimate_rig_pose`).

    Args:
        failure: None (a pose) or the reason there is none (:data:`FAILURE_REASONS`,
            :data:`RIG_FAILURE_REASONS`).
        model: the final ``(R, C, w, t)`` (its arrays taken, not copied), or None: the
            identity and zeros (a failure's).
        pose: the :class:`~rs_localizer.pose.RSPose` of ``model``, or None: the identity and
            zeros.
        per_view, num_valid_per_view, num_rows: each view's inliers over its input rows and
            its valid rows, the input rows of all (:func:`per_view_fields`, with ``fields``'
            ``num_behind``, 0 if not given).
        covariances: ``(covariance (12, 12), pose (6, 6), twist (6, 6) or None)`` in ROS order
            (:func:`output_covariance`), or None.
        fields: the estimate's other fields by name; they also replace those set here.

    Raises:
        ValueError: ``failure`` is not a known reason.
    """
    if failure is not None and failure not in _REASONS:
        raise ValueError(f"unknown failure reason {failure!r}; expected one of {_REASONS}")
    values = {"success": failure is None, "failure": failure}
    values |= per_view_fields(per_view, num_valid_per_view, num_rows, fields.get("num_behind", 0))
    if model is not None:
        values["model"] = model
    if pose is not None:
        values["pose"] = pose
    if covariances is not None:
        cov = covariances
        values["covariance"], values["pose_covariance"], values["twist_covariance"] = cov
    return RSPoseEstimate._trusted(**(values | fields))


def per_view_fields(
    per_view: tuple, num_valid_per_view: tuple, num_rows: int, num_behind: int = 0
) -> dict:
    """The fields of an estimate's rows by view (a camera's one view, a rig's cameras in
    order), from each view's (N_c,) bool inliers over its input rows ``per_view`` and its
    valid rows ``num_valid_per_view``: ``inliers`` (every view's rows in order),
    ``inliers_per_view``, ``num_inliers_per_view``, ``num_valid_per_view``, ``num_valid``,
    and ``num_dropped`` (of the ``num_rows`` input rows those not valid, plus the
    ``num_behind`` valid ones behind their cameras)."""
    if len(per_view) == 1:  # (one view's inliers are the estimate's own)
        inliers = per_view[0]
    else:
        inliers = np.concatenate(per_view) if per_view else np.zeros(0, dtype=bool)
    num_valid = sum(num_valid_per_view)
    return {
        "inliers": inliers,
        "inliers_per_view": per_view,
        "num_inliers_per_view": tuple(int(np.count_nonzero(m)) for m in per_view),
        "num_valid_per_view": num_valid_per_view,
        "num_valid": num_valid,
        "num_dropped": num_rows - num_valid + num_behind,
    }


#: every failure reason of a camera's or a rig's estimate (:func:`built_estimate`)
_REASONS = FAILURE_REASONS + tuple(r for r in RIG_FAILURE_REASONS if r not in FAILURE_REASONS)


def physical_velocities(
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    seconds_per_unit_r: float,
    compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Model velocities (per unit r) -> the camera's own velocities.

    With ``X_cam = R(tau) X + C(tau)``, ``R(tau) = (I + tau [w]x) R``, ``C(tau) = C + tau t`` and
    ``tau = time / seconds_per_unit_r``, the camera orientation ``R^T`` changes as
    ``d(R^T)/dtau = -R^T [w]x``, so its angular velocity in its own frame is ``-w`` per unit r,
    and the centre ``c = -R^T C`` moves with ``dc/dtau = R^T (w x C - t)``.

    Args:
        R: (3, 3) world -> camera at the reference row; C, w, t: (3,) the model (paper eq. 4).
        seconds_per_unit_r: the camera's readout time per unit RS coordinate (s).

    Returns:
        (omega_cam rad/s, v_cam m/s, omega_world, v_world), each (3,); zeros for a global
        shutter (``seconds_per_unit_r == 0``). ``compiled=False``: in NumPy (the estimator's
        NumPy implementation).
    """
    if seconds_per_unit_r <= 0:
        z = np.zeros(3)
        return z, z.copy(), z.copy(), z.copy()
    if not compiled:
        z = model_twist.py_func(C, w, t, seconds_per_unit_r)
        om, vc = z[3:6], z[0:3]
        return om, vc, R.T @ om, R.T @ vc
    f64 = np.float64
    return physical_velocities_kernel(
        np.ascontiguousarray(R, dtype=f64),
        np.ascontiguousarray(C, dtype=f64),
        np.ascontiguousarray(w, dtype=f64),
        np.ascontiguousarray(t, dtype=f64),
        float(seconds_per_unit_r),
    )


def output_covariance(
    cov12: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    seconds_per_unit_r: float,
    compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Propagate the (delta, C, w, t) covariance (12, 12) to (camera rotation in world,
    position, omega_cam, v_cam) and to the ROS pose/twist blocks.

    With ``R = expm(delta) R0`` the camera orientation ``R^T = R0^T expm(-delta)`` has the
    world-axis rotation perturbation ``phi = -R^T delta``; the position ``c = -R^T C`` has
    ``dc/ddelta = -R^T [C]x`` and ``dc/dC = -R^T``; the velocities follow
    :func:`physical_velocities` (``omega = -w / s``, ``v = (w x C - t) / s``).

    Returns:
        (the (12, 12) covariance, the (6, 6) ROS pose block, the (6, 6) ROS twist block or
        ``None`` for a global shutter); computed in :func:`.outputs.output_covariance_kernel`
        (``compiled=False``: in NumPy, the estimator's NumPy implementation).
    """
    s = float(seconds_per_unit_r)
    if not compiled:
        return _output_covariance_numpy(cov12, R, C, w, s)
    out, pose, twist = output_covariance_kernel(np.ascontiguousarray(cov12), R, C, w, s)
    return out, pose, (twist if s > 0 else None)


def _output_covariance_numpy(cov12, R, C, w, s: float):
    """:func:`output_covariance` in NumPy."""
    Rt = R.T
    J = np.zeros((12, 12))
    J[0:3, 0:3] = -Rt  # phi = -R^T delta
    J[3:6, 0:3] = -Rt @ skew(C)  # dc/ddelta
    J[3:6, 3:6] = -Rt  # dc/dC
    if s > 0:  # (omega, v) rows: the twist's Jacobian, (v, omega)
        Jz = model_twist_jacobian.py_func(C, w, s)
        J[6:9], J[9:12] = Jz[3:6], Jz[0:3]
    out = J @ cov12 @ J.T
    out = 0.5 * (out + out.T)
    pose = out[np.ix_(ROS_ORDER, ROS_ORDER)]
    tw = 6 + ROS_ORDER
    return out, pose, (out[np.ix_(tw, tw)] if s > 0 else None)


def camera_model_of_rig(
    model: RSModel | tuple,
    mounting: Mounting,
    stamp_offset: float,
    seconds_per_unit_r: float,
) -> RSModel:
    """Camera c's single-camera model at its reference line from the rig's model.

    With the rig's ``(R, C, w, t)`` (:mod:`~.rig`'s; ``w``, ``t`` per second) and
    ``s = stamp_offset``, the rig at ``s + sigma`` sees ``expm(sigma [w]x) R' X + C' + sigma t``
    with ``R' = expm(s [w]x) R``, ``C' = C + s t``; camera c sees that through its mounting,
    and per unit RS coordinate (``sigma = seconds_per_unit_r (r - r0)``)::

        R_cam = R_c R', C_cam = R_c C' + c_c, w_cam = spr R_c w, t_cam = spr R_c t

    Args:
        model: the rig's ``(R (3, 3), C (3,) m, w (3,) rad/s, t (3,) m/s)``.
        mounting: the camera's :class:`~rs_localizer.frames.Mounting` (``x_cam = R_c x_rig +
            c_c``: its ``R``, ``c``).
        stamp_offset: the camera's reference line's capture time minus the rig's reference
            time (s). seconds_per_unit_r: the camera's ``seconds_per_unit_r`` (s).
    Returns:
        the camera's :class:`~rs_localizer.pose.RSModel` (``w``, ``t`` per unit r), what
        :func:`~rs_localizer.estimation.estimate_rs_pose` estimates for that camera alone.
    """
    R, C, w, t = (np.asarray(a, dtype=float) for a in model)
    Rc, cc = mounting.R, mounting.c
    s, spr = float(stamp_offset), float(seconds_per_unit_r)
    a = s * w
    # (expm(0) = I exactly, and R_c I = R_c: a mounting's rotation is finite)
    Rs = Rc @ rotvec_to_matrix(a) if a.any() else Rc
    return RSModel(Rs @ R, Rc @ (C + s * t) + cc, spr * (Rc @ w), spr * (Rc @ t))


def camera_estimate(
    est: RSPoseEstimate,
    index: int,
    camera: CameraModel,
    mounting: Mounting,
    stamp_offset: float,
    points2d: np.ndarray,
    points3d: np.ndarray | None = None,
) -> RSPoseEstimate:
    """Camera ``index``'s part of the rig estimate ``est`` as that camera's own estimate: what
    its front end is told (:class:`~rs_localizer.correspondences.FrameFeedback`) and its
    debug image draws.

    Args:
        est: a rig frame's estimate (:func:`~.rig.estimate_rig_pose`).
        index: the camera's view in the rig frame. camera: its model.
        mounting (:class:`~rs_localizer.frames.Mounting`), stamp_offset (s): its mounting
            and its reference line's time after the rig's (:class:`~.view.View`).
        points2d: (N, 2) px, the rows the camera gave the rig; points3d: (N, 3) m, their
            world points, for ``rmse_px`` (None: NaN).
    Returns:
        an :class:`~.result.RSPoseEstimate` with the rig's ``success``, ``failure``,
        ``solver``, ``motion_model``; ``model`` the camera's at its reference line
        (:func:`camera_model_of_rig`, per unit r; the identity and zeros on failure),
        ``pose`` its optical frame's; ``inliers`` (N,) the view's
        (``est.inliers_per_view[index]``; none where the rig frame has no such view);
        ``rmse_px`` the RMS error of those inliers under that model (px, the camera's
        projection at each row's capture time, NaN without ``points3d`` or inliers); its one
        view's per-view fields (``inliers_per_view`` ``(inliers,)``, ``num_inliers_per_view``
        their count, ``num_valid_per_view`` ``(N,)``, as ``num_valid``). The covariances stay
        the rig's own: None here.
    """
    n = len(points2d)
    per = est.inliers_per_view
    inl = np.asarray(per[index], bool) if index < len(per) else np.zeros(n, bool)
    inl = inl if len(inl) == n else np.zeros(n, bool)
    spr = camera.seconds_per_unit_r
    model = RSModel.identity()
    if est.success:
        model = RSModel(*camera_model_of_rig(est.model, mounting, stamp_offset, spr))
    rmse = float("nan")
    if points3d is not None and inl.any():
        uv = np.asarray(points2d, float)[inl]
        e = camera.project_rs(np.asarray(points3d, float)[inl], *model) - uv
        rmse = float(np.sqrt(np.nanmean(np.sum(e * e, axis=1))))
    return RSPoseEstimate(
        success=est.success,
        failure=est.failure,
        solver=est.solver,
        model=model,
        pose=RSPose.from_model(model, spr),
        rmse_px=rmse,
        motion_model=est.motion_model,
        implementation=est.implementation,
        **per_view_fields((inl,), (n,), n),
    )


def rig_model_of_camera(
    model: RSModel | tuple,
    mounting: Mounting,
    stamp_offset: float,
    seconds_per_unit_r: float,
) -> RSModel:
    """The inverse of :func:`camera_model_of_rig`: the rig's model ``(R, C, w, t)`` (per
    second, at the rig's reference time) of one camera's single-camera model (per unit r at its
    reference line); a global-shutter camera (``seconds_per_unit_r <= 0``) gives zero ``w``
    and ``t``. Arguments as :func:`camera_model_of_rig`."""
    Rk, Ck, wk, tk = (np.asarray(a, dtype=float) for a in model)
    Rc, cc = mounting.R, mounting.c
    spr = float(seconds_per_unit_r)
    w = Rc.T @ wk / spr if spr > 0 else np.zeros(3)
    t = Rc.T @ tk / spr if spr > 0 else np.zeros(3)
    s = float(stamp_offset)
    R1, C1 = Rc.T @ Rk, Rc.T @ (Ck - cc)
    a = -s * w
    # (expm(0) = I exactly, and I R1 = R1 when R1 is finite: a global shutter's, or a camera
    # at the rig's reference time)
    if a.any() or not np.isfinite(R1).all():
        R1 = rotvec_to_matrix(a) @ R1
    return RSModel(R1, C1 - s * t, w, t)


def rig_model_jacobian(
    model: RSModel | tuple, mounting: Mounting, stamp_offset: float, spr: float
) -> np.ndarray:
    """(12, 12) the derivative of :func:`rig_model_of_camera`'s ``(delta, C, w, t)`` (the
    rig's rotation perturbed on the left, ``R = expm([delta]x) R_0``) over the camera model's
    ``(delta, C, w, t)`` at ``model``, analytic: with ``E = expm(-s [w]x)`` (``s`` the
    stamp offset, ``w`` the rig's angular velocity) and the mounting's ``R_c``, ``delta =
    E R_c^T delta_cam - (s / spr) J_l(-s w) R_c^T dw_cam``, ``dC = R_c^T (dC_cam - (s / spr)
    dt_cam)``, ``dw = R_c^T dw_cam / spr``, ``dt = R_c^T dt_cam / spr`` (``J_l`` the left
    Jacobian of SO(3): ``expm([a + d]x) = expm([J_l(a) d]x) expm([a]x)`` to first order); a
    global-shutter camera (``spr <= 0``): the velocities' rows and columns zero."""
    Rt = np.asarray(mounting.R, dtype=float).T
    J = np.zeros((12, 12))
    J[3:6, 3:6] = Rt
    spr, s = float(spr), float(stamp_offset)
    if spr <= 0:
        J[0:3, 0:3] = Rt
        return J
    a = -s * (Rt @ np.asarray(model[2], dtype=float) / spr)  # (-s w, the rig's w)
    J[0:3, 0:3] = rotvec_to_matrix(a) @ Rt
    th2 = float(a @ a)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    if th2 < 1e-12:  # (Taylor: 1/2 - t^2/24, 1/6 - t^2/120)
        c2, c3 = 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        th = math.sqrt(th2)
        c2, c3 = (1.0 - math.cos(th)) / th2, (th - math.sin(th)) / (th2 * th)
    Jl = np.eye(3) + c2 * K + c3 * (K @ K)
    J[0:3, 6:9] = (-s / spr) * (Jl @ Rt)
    J[3:6, 9:12] = (-s / spr) * Rt
    J[6:9, 6:9] = J[9:12, 9:12] = Rt / spr
    return J


def body_estimate(
    est: RSPoseEstimate, mounting: Mounting, stamp_offset: float, seconds_per_unit_r: float
) -> RSPoseEstimate:
    """The estimate of the body (a rig) that a camera is mounted on, of that camera's own
    estimate ``est`` (:func:`~.estimate.estimate_rs_pose` of a
    :class:`~rs_localizer.estimation.view.View`'s points; the view's mounting, stamp offset and
    its camera's ``seconds_per_unit_r``, as :func:`rig_model_of_camera` takes them): ``model``
    the body's (:func:`rig_model_of_camera`: ``w``, ``t`` per second), ``pose`` its
    :class:`~rs_localizer.pose.RSPose` (one second per unit), ``model_covariance`` mapped to
    first order (:func:`rig_model_jacobian`) and the output covariances of it
    (:func:`output_covariance`; the twist's where ``est`` has one, the measured twist of a
    global-shutter fallback's held velocities carried to the body:
    :meth:`RSPoseEstimate._with_model_covariance`); every other field,
    among them the inliers and the per-view fields of the view, ``est``'s own. The
    ``acceleration_sensitivity`` (in the camera's frame) is not carried: None. A failed
    estimate is returned as it is (the identity and zeros are every failure's).
    """
    if not est.success:
        return est
    model = rig_model_of_camera(est.model, mounting, stamp_offset, seconds_per_unit_r)
    cov = None
    if est.model_covariance is not None:
        J = rig_model_jacobian(est.model, mounting, stamp_offset, seconds_per_unit_r)
        cov = J @ est.model_covariance @ J.T
    compiled = est.implementation != NUMPY
    return est._with_model_covariance(
        cov, 1.0, mounting, model=model, pose=RSPose.from_model(model, 1.0, compiled=compiled),
        acceleration_sensitivity=None,
    )  # fmt: skip
