"""The first stage of the estimator: one frame's correspondences validated, undistorted and
normalized (:func:`prepare_frame`), then checked and configured for its solver
(:func:`configure_frame`: degeneracy, planarity, timing, velocity bounds, motion prior).
"""

from __future__ import annotations

import operator
from collections.abc import Callable
from typing import NamedTuple, Protocol, TypeVar

import numpy as np

from ..camera import READOUT_DIRECTIONS, CameraModel
from ..correspondences import checked_groups
from ..pose import RSModel
from ..solvers.registry import sample_size, solver_info
from .degeneracy import coplanar
from .plausibility import (
    degenerate_points,
    degenerate_points_numpy,
    motion_bounds,
    plausible_motion,
)
from .prior import MotionPrior
from .refine import KernelMountings, Mountings, exact_errors
from .result import (
    DEGENERATE_GEOMETRY,
    PLANAR_SCENE,
    TOO_FEW_POINTS,
    EstimationFailed,
)
from .sampling import valid_rows
from .scoring import exact_errors2_numpy, msac_evaluate

T = TypeVar("T")

__all__ = [
    "SCORE_AT_MEASURED_TIME",
    "CameraValues",
    "Frame",
    "RefinementView",
    "camera_values",
    "configure_frame",
    "correspondences",
    "kept_per_objects",
    "kernel_ready",
    "normalized_rows",
    "prepare_frame",
    "valid_correspondences",
    "varying_pixel_jacobian",
]

#: RANSAC and local optimization score points at their measured capture times
#: (:func:`.scoring.measured_error2`, the refinement's residual) instead of at the capture
#: row predicted by the first-order model (:func:`.scoring.project_error2`)
SCORE_AT_MEASURED_TIME = True

#: the solvers' model ``(R, C, w, t)`` (a tuple: the kernels take its arrays)
Model = RSModel


class RefinementView(Protocol):
    """What the final stage (:mod:`~.finalize`: the refinements, the covariance, the
    sensitivity, the last checks) reads of the points it fits: one camera's :class:`Frame`,
    one view at the identity mounting, or a rig frame's cameras stacked (:mod:`~.rig`), each
    camera a view with its mounting and its rows.

    Attributes:
        X: (N, 3) world points (m). x: (N, 2) normalized undistorted image points (a rig's:
            each in its own camera). r: (N,) each point's time coordinate, r0 the reference
            one: ``tau = r - r0`` is the model's time (rows of one camera, or seconds of a
            rig). spr: seconds per unit of that time (0: global shutter). planar: the world
            points are coplanar (the motion prior's planar case). compiled: the refinement
            runs compiled (:func:`~.refine.refine_rs_pose`), else in NumPy and SciPy
            (:func:`~.refine.refine_rs_pose_numpy`).
    """

    X: np.ndarray
    x: np.ndarray
    r: np.ndarray
    r0: float
    spr: float
    planar: bool
    compiled: bool

    #: (N,) int64 each point's group (points of one group share a part of their image error,
    #: e.g. one marker's corners, :mod:`~.noise_model`), or None: every point's error its own
    groups: np.ndarray | None
    #: the share of a grouped point's error variance its group shares, for a frame whose
    #: residuals cannot tell it (the options' ``correlated_noise.shift_share``)
    shift_share: float

    def mountings(self) -> Mountings | KernelMountings | None:
        """The refinement's mountings of every point (None: one camera's plain errors)."""
        ...

    @property
    def plain_mountings(self) -> Mountings | None:
        """:meth:`mountings` as :class:`~.refine.Mountings` (the NumPy functions' form)."""
        ...

    def errors(self, model: Model) -> np.ndarray:
        """(N,) image errors of ``model`` at every point at its measured capture time, in the
        units of the refinement's threshold; ``inf`` behind the camera."""
        ...

    def views(self) -> tuple | None:
        """The cameras that see the points: ``None``, one camera at the identity mounting
        (:class:`Frame`), or a rig's ``(R_mount (M, 3, 3), c_mount (M, 3), rows (M, 2)
        int64)``, camera m's mounting and its points ``rows[m, 0]:rows[m, 1]`` (stacked by
        camera; :func:`~.plausibility.final_check`)."""
        ...

    def mounting_covariances(self) -> tuple | None:
        """``(the points' :class:`~.refine.Mountings`, each camera's mounting covariance
        (6, 6) over its rotation on the rig (rad) and its centre (m), or None, each camera's
        time offset std (s, 0: none), the rig's twist ``(w, t)`` per second known from
        outside the frame or None)`` where some camera's mounting has either
        (:func:`~.finalize.final_covariance` adds their share), else None (a camera alone)."""
        ...


class Frame:
    """Validated, normalized correspondences of one frame (rows shuffled, see
    :func:`prepare_frame`).

    Attributes:
        x: (N, 2) normalized undistorted image points; X: (N, 3) world points (m);
        r: (N,) RS coordinate of each point's capture (measured, distorted line); r0e: (N,)
            the row coordinate the scoring kernels use; r0: the reference row's coordinate;
        d: (2,) the camera's readout direction; f: mean focal length (px), the scale from
            normalized units to pixels.
        rows: (N,) input row of each point; u_px: (N, 2) their measured pixels;
            num_rows: rows given to the estimator (valid or not).
        spr: the camera's seconds per unit r (0: global shutter).
        threshold: the inlier threshold in normalized image units (``threshold_px / f``), set
            once by :func:`configure_frame` for RANSAC, its hypotheses and the final
            refinement.
        planar: the 3D points are coplanar.
        prior: the motion prior of local optimization and the refinement (``None``: maximum
            likelihood); regularize: the hypotheses use it too (planar scene); final_prior:
            the prior the final refinement may add after its maximum-likelihood fit (``None``:
            none applies to this solver and camera).
        motion_bounds: the velocity bounds per unit r
            (:func:`~rs_localizer.estimation.plausibility.motion_bounds`; ``None``: none).
        W: (N, 4) each point's whitening of its image error, row-major 2x2: ``A_i / f``,
            ``A_i`` the camera's :meth:`~rs_localizer.camera.CameraModel.pixel_jacobian` at
            ``x_i``, so ``|W_i e_i| f`` is, to first order, the error ``e_i`` (normalized)
            in px of the measured (distorted) image; RANSAC's scoring, local optimization,
            the refinement and its covariance use it. (0, 4) for a camera without distortion
            with ``fx == fy`` and no skew (``W_i`` the identity: the plain errors). The NumPy
            implementation (:mod:`.numpy_impl`) does not use it.
        known_w: (3,) the angular velocity a gyro measured, in the model's units (rad per
            unit r, camera frame): RANSAC's samples are then solved with it known
            (:func:`~rs_localizer.solvers.r5p_w.r5p_w_batch`); ``None``: no gyro.
        groups: (N,) int64 each point's group (its input row's, :func:`prepare_frame`):
            points of one group share a part of their image error (one marker's corners),
            which the final covariance includes (:mod:`~.noise_model`); ``None``: none.
        shift_share: the options' ``correlated_noise.shift_share`` (set by the estimator).

    The NumPy implementation (:mod:`.numpy_impl`) prepares its frames here too and adds its
    own ``tau`` ((N,) ``r - r0``).
    """

    spr = 0.0
    planar = False
    prior: MotionPrior | None = None
    regularize = False
    final_prior: MotionPrior | None = None
    motion_bounds = None
    known_w: np.ndarray | None = None
    W: np.ndarray = np.zeros((0, 4))
    groups: np.ndarray | None = None
    shift_share = 0.0
    threshold: float
    #: the frame was prepared for the compiled implementation (:func:`prepare_frame`); False:
    #: the NumPy one's, whose final-stage refinements and errors run in NumPy and SciPy
    #: (:class:`RefinementView`)
    compiled = True

    def __init__(
        self,
        x: np.ndarray,
        X: np.ndarray,
        r: np.ndarray,
        r0e: np.ndarray,
        r0: float,
        d: np.ndarray,
        f: float,
    ):
        self.x, self.X, self.r, self.r0e, self.r0, self.d, self.f = x, X, r, r0e, r0, d, f

    @property
    def bearings(self) -> np.ndarray:
        """(N, 3) unit rays of the normalized points (for P3P), computed once."""
        if not hasattr(self, "_bearings"):
            b = np.concatenate([self.x, np.ones((len(self.x), 1))], axis=1)
            self._bearings = b / np.linalg.norm(b, axis=1, keepdims=True)
        return self._bearings

    def mountings(self, idx: np.ndarray | None = None) -> Mountings | None:
        """The refinement's :class:`~.refine.Mountings` of the points ``idx`` (all: ``None``):
        the camera at the identity mounting with each point's 2x2 whitening :attr:`W` as its
        scale, so that :func:`~.refine.refine_rs_pose` minimizes the errors of the measured
        image in its cost, rows and covariance; ``None`` (the plain errors) without
        whitening, and on a frame of the NumPy implementation (which measures the plain
        normalized errors, as its scoring does)."""
        if not len(self.W) or not self.compiled:
            return None
        W = self.W if idx is None else self.W[idx]
        n = len(W)
        return Mountings(
            np.zeros(n, dtype=np.int64), np.eye(3)[None], np.zeros((1, 3)), W.reshape(n, 2, 2)
        )

    @property
    def plain_mountings(self) -> Mountings | None:
        """:meth:`mountings` of every point (:attr:`RefinementView.plain_mountings`)."""
        return self.mountings()

    def errors(self, model: Model, compiled: bool | None = None) -> np.ndarray:
        """(N,) image errors of ``model`` at every point at its measured capture time
        (:func:`~.refine.exact_errors`: normalized units, in pixels of the measured image over
        the focal length with the whitening :attr:`W`; on a frame of the NumPy implementation,
        or with ``compiled`` False, the plain normalized errors in NumPy,
        :func:`~.scoring.exact_errors2_numpy`); ``inf`` behind the camera."""
        R, C, w, t = model
        tau = self.r - self.r0
        if self.compiled if compiled is None else compiled:
            return exact_errors(R, C, w, t, self.X, self.x, tau, self.W)
        m = (np.asarray(a, dtype=float)[None] for a in (R, C, w, t))
        return np.sqrt(exact_errors2_numpy(*m, self.X, self.x, tau)[0])

    def views(self) -> None:
        """One camera at the identity mounting (:meth:`RefinementView.views`)."""
        return None

    def mounting_covariances(self) -> None:
        """A camera alone: no mounting (:meth:`RefinementView.mounting_covariances`)."""
        return None

    def take(self, idx: slice | np.ndarray) -> Frame:
        """The frame's points ``idx`` (a slice or an index array) with the same camera, timing
        and prior: LO-RANSAC's bounded inner sample (the first points, a random subset: the
        rows are shuffled), an initial model's explained points (its pull)."""
        x, X, r, r0e = self.x[idx], self.X[idx], self.r[idx], self.r0e[idx]
        sub = Frame(x, X, r, r0e, self.r0, self.d, self.f)
        sub.spr, sub.planar, sub.prior, sub.regularize, sub.known_w = (
            self.spr,
            self.planar,
            self.prior,
            self.regularize,
            self.known_w,
        )
        sub.threshold, sub.compiled = self.threshold, self.compiled
        if len(self.W):
            sub.W = self.W[idx]
        return sub

    def evaluate(
        self, model: Model, th2: float, errors: np.ndarray | None = None
    ) -> tuple[float, np.ndarray]:
        """(MSAC score, (N,) inlier mask) of one model (R, C, w, t) on all points of the frame;
        ``(inf, all False)`` for a model with implausible motion (:attr:`motion_bounds`).
        ``th2``: squared inlier threshold (normalized units). ``errors``: the model's (N,)
        squared errors at every point when they are at hand (:func:`.scoring.errors2` as
        scored; finite parameters), instead of computing them again."""
        R, C, w, t = (np.ascontiguousarray(a, dtype=np.float64) for a in model)
        if self.motion_bounds is not None and not plausible_motion(R, C, w, t, self.motion_bounds):
            return np.inf, np.zeros(len(self.x), dtype=bool)
        if errors is not None:
            return float(np.minimum(errors, th2).sum()), errors < th2
        sc, inl, _ = msac_evaluate(
            self.x, self.X, self.r0e, self.d, R, C, w, t, th2, SCORE_AT_MEASURED_TIME, self.W
        )
        return sc, inl

    @property
    def bounds(self) -> np.ndarray:
        """(1, 2) int64: the frame's one view's first and end row (every row)."""
        return np.array([[0, len(self.x)]], dtype=np.int64)

    @property
    def view_focal(self) -> np.ndarray:
        """(1,): the frame's one view's focal length :attr:`f` (px)."""
        return np.array([float(self.f)])

    def degenerate(self, mask: np.ndarray, threshold_px: float, compiled: bool = True) -> bool:
        """True if the points ``mask`` (N,) selects fix no pose: identical or collinear 3D
        points, or each view's pixels (measured ``u_px`` or undistorted ``x`` times its focal
        length) within ``threshold_px`` of one image line (see
        :func:`~.plausibility.degenerate_points`; ``compiled=False``:
        :func:`~.plausibility.degenerate_points_numpy`). The views are :attr:`bounds` and
        :attr:`view_focal`: one here, a rig frame's cameras in
        :class:`~.view.StackedViews`, which tests its points with this method."""
        test = degenerate_points if compiled else degenerate_points_numpy
        f, rows = self.view_focal, self.bounds
        return bool(test(self.X, self.u_px, self.x, mask, f, rows, float(threshold_px)))

    def input_mask(self, mask: np.ndarray) -> np.ndarray:
        """(num_rows,) bool: the points ``mask`` (N,) selects over the rows given to the
        estimator (the rows it left out False): an estimate's inliers over its input rows
        (a camera's, a rig camera's view)."""
        out = np.zeros(self.num_rows, dtype=bool)
        out[self.rows] = mask
        return out


def varying_pixel_jacobian(camera: CameraModel) -> bool:
    """Whether the camera's pixel Jacobian
    (:meth:`~rs_localizer.camera.CameraModel.pixel_jacobian`) varies from point to point or
    is not the focal length times the identity: lens
    distortion, ``fx != fy`` or a skew. Then each point's error is whitened by its own
    Jacobian (a frame's :attr:`Frame.W`, a rig camera's ``A``); else the plain errors times the
    focal length are the errors in px."""
    K = camera.K
    return bool(camera.has_distortion or K[0, 0] != K[1, 1] or K[0, 1] != 0)


def prepare_frame(
    points2d: np.ndarray,
    points3d: np.ndarray,
    camera: CameraModel,
    max_point_norm: float,
    rng: np.random.Generator | None = None,
    compiled: bool = True,
    groups: np.ndarray | None = None,
) -> Frame:
    """Validate and normalize one frame's correspondences (both implementations of the
    estimator; ``compiled=False``: NumPy only, the same rule and formulas), with each point's
    group (:attr:`Frame.groups`) from ``groups``, (N,) one per input row, or None.

    Rows with a non-finite pixel or point, a point farther than ``max_point_norm`` (m) from the
    origin, or a pixel the camera cannot undistort are left out; the rest are shuffled by
    ``rng`` (so that any prefix is a random subset, for the pre-test and local optimization;
    anything with a generator's ``permutation``: :class:`~.ransac.SeededShuffle`; None: in
    their order, as a rig frame's views take them, :mod:`~.view`)
    and normalized with :meth:`CameraModel.normalize` (OpenCV undistortion; the RS time from
    the measured, distorted line), with each point's whitening :attr:`Frame.W`.

    Args:
        points2d: (N, 2) measured (distorted) pixels; points3d: (N, 3) world points (m).
    Raises:
        ValueError: arrays that are not (N, 2) and (N, 3) with the same N, or ``groups``
            that are not (N,) integers
            (:func:`~rs_localizer.correspondences.checked_groups`).
    """
    u, X = correspondences(points2d, points3d)
    g = checked_groups(groups, len(u))
    rows = np.flatnonzero(valid_correspondences(u, X, max_point_norm, compiled))
    if rng is not None:
        rows = rng.permutation(rows)
    # (``take``: NumPy's fancy indexing costs ~10x more at this size)
    u_px = u.take(rows, axis=0)
    x, r, r0e = camera.normalize(u_px, compiled)
    fr = _frame(u, X, rows, u_px, x, r, r0e, camera, compiled)
    if g is not None:
        fr.groups = g.take(fr.rows)
    return fr


def correspondences(points2d: np.ndarray, points3d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A frame's measured pixels ``points2d`` and world points ``points3d`` as float64 arrays,
    checked to be (N, 2) and (N, 3) with the same N (:func:`prepare_frame`: a camera's frame
    and each camera's of a rig frame, :mod:`~.view`).

    Raises:
        ValueError: arrays of other shapes or of different lengths, naming both shapes.
    """
    u = np.asarray(points2d, dtype=np.float64)
    X = np.asarray(points3d, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] != 2 or X.ndim != 2 or X.shape[1] != 3 or len(u) != len(X):
        raise ValueError(f"expected (N, 2) pixels and (N, 3) points, got {u.shape} and {X.shape}")
    return u, X


def valid_correspondences(
    u: np.ndarray, X: np.ndarray, max_point_norm: float, compiled: bool = True
) -> np.ndarray:
    """(N,) bool: the rows of (N, 2) pixels ``u`` and (N, 3) world points ``X`` (float64) a
    frame takes (:func:`prepare_frame`, of a camera or a rig's camera): a finite pixel and a
    point with every coordinate within ``max_point_norm`` (m) of the origin (NaN and points at
    infinity fail); ``compiled=False``, or arrays that are not :func:`kernel_ready` (a
    read-only or strided input: the compiled test would compile another specialization during
    the frame): in NumPy, the same rule (:func:`~.sampling.valid_rows`)."""
    if compiled and kernel_ready(u) and kernel_ready(X):
        return valid_rows(u, X, max_point_norm)
    with np.errstate(invalid="ignore"):
        return np.isfinite(u).all(axis=1) & (np.abs(X) <= max_point_norm).all(axis=1)


def normalized_rows(x: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """The rows of :meth:`~rs_localizer.camera.CameraModel.normalize`'s (N, 2) points ``x`` and
    (N,) RS coordinates ``r`` a frame takes (:func:`prepare_frame`, of a camera or a rig's
    camera): None when every one is finite, else the (N,) bool mask of those that are
    (undistortion can fail far outside the image)."""
    if np.isfinite(x).all() and np.isfinite(r).all():
        return None
    return np.isfinite(x.sum(axis=1) + r)


def kernel_ready(a: np.ndarray) -> bool:
    """Whether ``a`` is a C-contiguous, writeable float64 or bool array: the array type the
    small kernels of a frame's preparation (:func:`valid_correspondences`) are compiled for
    and warmed up with (another layout or a read-only array would compile another
    specialization during a frame)."""
    f = a.flags
    return bool(f.c_contiguous and f.writeable and a.dtype in (np.float64, np.bool_))


class CameraValues(NamedTuple):
    """A camera's values the estimators read on every frame (its properties' values, kept per
    camera object by :func:`camera_values`): ``r0`` (its reference RS coordinate), ``focal``
    (its mean focal length, px), ``varying`` (:func:`varying_pixel_jacobian`), ``readout``
    (its readout direction's ``d`` of :data:`~rs_localizer.camera.READOUT_DIRECTIONS`),
    ``spr`` (its seconds per unit r, s), ``jacobian`` (its
    :attr:`~rs_localizer.camera.CameraModel.jacobian_arguments`, None without
    distortion)."""

    r0: float
    focal: float
    varying: bool
    readout: tuple
    spr: float
    jacobian: tuple | None


#: the cameras' values of :func:`camera_values`: (0, id) -> ((camera,), values)
_CAMERA_VALUES: dict = {}


def camera_values(camera: CameraModel) -> CameraValues:
    """The camera's :class:`CameraValues`, kept per camera object (:func:`kept_per_objects`: a
    frozen dataclass that a camera's frames and a rig's frames share; its properties cost as
    much as a frame's arrays)."""
    return kept_per_objects(
        _CAMERA_VALUES,
        (camera,),
        lambda: CameraValues(
            camera.r0,
            camera.mean_focal,
            varying_pixel_jacobian(camera),
            READOUT_DIRECTIONS[camera.readout][2],
            camera.seconds_per_unit_r,
            camera.jacobian_arguments,
        ),
    )


def kept_per_objects(cache: dict, objects: tuple, build: Callable[[], T], tag: int = 0) -> T:
    """``build()`` kept in ``cache`` per tuple of ``objects`` and ``tag``: by their ids,
    returned again only for the same objects (frozen ones that many frames share: a camera, a
    rig's mountings, :func:`camera_values` and :class:`~.view.StackedViews`; a view, at its
    index ``tag`` in a rig frame); at most 64 kept, the cache emptied when full."""
    key = (tag, *map(id, objects))
    hit = cache.get(key)
    if hit is not None and all(map(operator.is_, hit[0], objects)):
        return hit[1]
    out = build()
    if len(cache) >= 64:
        cache.clear()
    cache[key] = (objects, out)
    return out


def _frame(u, X, rows, u_px, x, r, r0e, camera: CameraModel, compiled: bool) -> Frame:
    """The :class:`Frame` of :func:`prepare_frame` from its (N, 2) pixels ``u``, (N, 3) points
    ``X``, valid rows ``rows`` (shuffled) and their pixels ``u_px``, normalized points ``x``,
    RS coordinates ``r``, ``r0e`` (:meth:`~rs_localizer.camera.CameraModel.normalize`)."""
    good = normalized_rows(x, r)
    if good is not None:
        rows, x, r, r0e, u_px = rows[good], x[good], r[good], r0e[good], u_px[good]
    r0, focal, varying, d, _, _ = camera_values(camera)
    fr = Frame(
        np.ascontiguousarray(x),
        X.take(rows, axis=0),
        np.ascontiguousarray(r),
        np.ascontiguousarray(r0e),
        r0,
        np.array(d),  # (camera.readout_vector)
        focal,
    )
    fr.rows, fr.num_rows, fr.compiled = rows, len(u), bool(compiled)
    fr.u_px = u_px
    if varying:
        J = camera.pixel_jacobian_exact(fr.x) if compiled else camera.pixel_jacobian(fr.x)
        fr.W = np.ascontiguousarray(J.reshape(-1, 4) / fr.f)
    return fr


def configure_frame(
    fr: Frame,
    camera: CameraModel,
    solver: str,
    min_inliers: int,
    threshold_px: float,
    velocity_bounds: tuple[float, float],
    prior: MotionPrior | None,
    compiled: bool = True,
) -> None:
    """Check that ``fr`` can fix a pose with ``solver`` and set its timing, velocity bounds
    (rad/s, m/s), planarity and motion prior (both implementations of the estimator;
    ``compiled=False``: the tests in NumPy).

    On planar scenes the RS solvers' hypotheses use the motion prior (damped solves for w, t:
    the plain ones let w, t absorb the noise); elsewhere the prior enters local optimization
    and the refinement only with ``prior.always``.

    Raises:
        EstimationFailed: ``too_few_points`` (fewer valid points than ``min_inliers``),
            ``degenerate_geometry`` (identical points, points on a 3D line, pixels on one
            image line: RANSAC would only find absurd rolling-shutter "fits" of them),
            ``planar_scene`` (coplanar points and a solver that cannot take them, R9P).
    """
    if max(min_inliers, sample_size(solver) + 1) > len(fr.x):
        raise EstimationFailed(TOO_FEW_POINTS)
    if fr.degenerate(np.ones(len(fr.x), dtype=bool), threshold_px, compiled):
        raise EstimationFailed(DEGENERATE_GEOMETRY)
    info = solver_info(solver)
    fr.threshold = threshold_px / fr.f
    fr.spr = spr = camera.seconds_per_unit_r
    fr.motion_bounds = motion_bounds(*velocity_bounds, spr)
    fr.planar = coplanar(fr.X, compiled)
    if fr.planar and not info.coplanar:
        raise EstimationFailed(PLANAR_SCENE)
    prior_on = bool(prior is not None and prior.enabled and spr > 0 and info.rolling)
    fr.prior = prior if prior_on and (fr.planar or prior.always) else None
    fr.regularize = bool(fr.prior is not None and fr.planar)
    fr.final_prior = prior if prior_on else None
