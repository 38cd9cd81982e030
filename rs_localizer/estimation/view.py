"""A view: one camera's correspondences with the camera, its mounting and its time; and the
views of one frame stacked (:class:`StackedViews`).

The estimators take views: :func:`~rs_localizer.estimation.rig.estimate_rig_pose` one or many
(a rig frame), the video (:class:`~rs_localizer.tracking.tracker.FrameViews`) a camera's own
view or a rig frame's. A frame's views stacked are one point set (a camera alone: one view at
the identity mounting): each point seen through its camera's mounting at its own time, its
error in its camera's pixels; their checks, degeneracy, MSAC scoring, minimal samples over
the views and the final stage's :class:`~.frame.RefinementView`.
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraModel
from ..frames import Mounting
from ..pose import RSModel
from .degeneracy import coplanar
from .frame import Frame, camera_values, kept_per_objects, prepare_frame
from .numpy_impl import errors2
from .options import EstimateOptions
from .refine import KernelMountings, Mountings, kernel_mountings
from .result import camera_model_of_rig
from .sampling import batch_samples, draw_samples_numpy, view_sampling
from .scoring import best_mounted

__all__ = ["StackedViews", "View"]


@dataclass(frozen=True, eq=False)
class View:
    """One camera's part of a frame: its correspondences, its camera, its mounting on the
    body posed (a rig's cameras) and its time: a camera alone is one view at the identity
    mounting.

    Attributes:
        uv: (N, 2) measured (distorted) pixels. X: (N, 3) world points (m).
        camera: the camera's intrinsics and RS timing.
        mounting: the camera's :class:`~rs_localizer.frames.Mounting` on the rig (``x_cam =
            mounting.R x_rig + mounting.c``; default: the identity mounting). Its
            ``covariance`` (rotation of the camera on the rig [rad, rig axes], its optical
            centre in the rig frame [m]), when given, enters the rig pose's covariance to
            first order: the refined model's sensitivity to the mounting times this
            covariance; None takes the mounting as exact. ``mounting=None`` stands for a
            camera whose mounting is unknown:
            :func:`~rs_localizer.estimation.rig.estimate_rig_pose` refuses it, naming the
            camera.
        stamp_offset: capture time of the camera's reference line (``camera.reference_line``)
            minus the rig's reference time (s).
        name: the camera's name in error messages (default: its index in the rig frame).
        groups: (N,) int, each correspondence's group, or None: points of one group share a
            part of their image error, as one marker's 4 corners share a shift of the tag's
            image (give the marker's id); the covariance then includes that shared error,
            estimated from the frame's residuals (:mod:`~.noise_model`). The estimate itself
            is unchanged.
    """

    uv: np.ndarray
    X: np.ndarray
    camera: CameraModel
    mounting: Mounting | None = field(default_factory=lambda: Mounting(np.eye(3), np.zeros(3)))
    stamp_offset: float = 0.0
    name: str = ""
    groups: np.ndarray | None = None

    def camera_model(self, model: RSModel | tuple) -> RSModel:
        """This view's camera's own model at its reference line (per unit r, as its own
        estimate's ``model``) from the rig's ``model`` (``w``, ``t`` per second, an
        estimate's ``model``): :func:`~.result.camera_model_of_rig` at this view's mounting
        and stamp offset."""
        return camera_model_of_rig(
            model, self.mounting, self.stamp_offset, self.camera.seconds_per_unit_r
        )


def _label(c: int, v: View) -> str:
    return f"camera {c}" + (f" ({v.name!r})" if v.name else "")


def _view_part(c: int, v: View, compiled: bool, max_norm: float) -> tuple:
    """Camera ``c``'s view checked (the errors :func:`~.rig.estimate_rig_pose` raises) and
    prepared for :class:`StackedViews`: ``(R (3, 3), c (3,), mounting covariance or None,
    frame, tau (n,), A (n, 4))``. ``frame``: the :class:`~.frame.Frame` a single camera's
    estimator prepares of the view's correspondences and groups
    (:func:`~.frame.prepare_frame`, unshuffled: its n valid rows in their order, every
    coordinate of a point within ``max_norm`` m of the origin (the options'
    ``plausibility.max_point_norm``), undistorted and normalized); ``tau``: each point's
    capture time from the rig's reference time (s, the view's stamp offset plus its row's
    time from the camera's reference line); ``A``: each point's pixel Jacobian, row-major
    (the frame's whitening times its focal length; the focal length times the identity
    where the frame has none)."""
    if not isinstance(v, View):
        raise ValueError(f"estimate_rig_pose: view {c} is a {type(v).__name__}, not a View")
    m = v.mounting
    if m is None:
        raise ValueError(
            f"estimate_rig_pose: {_label(c, v)} has no mounting (View.mounting is None: the "
            "camera's pose on the rig is unknown)"
        )
    if not isinstance(m, Mounting):
        raise ValueError(
            f"estimate_rig_pose: {_label(c, v)}: mounting is a {type(m).__name__}, not a Mounting"
        )
    if not isinstance(v.camera, CameraModel):
        raise ValueError(f"estimate_rig_pose: {_label(c, v)} has no CameraModel")
    if not math.isfinite(float(v.stamp_offset)):
        raise ValueError(f"estimate_rig_pose: {_label(c, v)}: stamp_offset not finite")
    Rm, cm, mc = m.R, m.c, m.covariance  # (checked by Mounting; the covariance symmetric)
    mc = None if mc is None or not mc.any() else mc
    uv = np.asarray(v.uv, dtype=float)
    X = np.asarray(v.X, dtype=float)
    try:  # (an empty view of any shape: no rows)
        fr = prepare_frame(
            uv.reshape(0, 2) if uv.size == 0 else uv, X.reshape(0, 3) if X.size == 0 else X,
            v.camera, max_norm, compiled=compiled, groups=v.groups,
        )  # fmt: skip
    except ValueError as e:
        raise ValueError(f"estimate_rig_pose: {_label(c, v)}: {e}") from None
    # (a global shutter, spr 0: every point at the stamp)
    tau = float(v.stamp_offset) + (fr.r - fr.r0) * camera_values(v.camera).spr
    if len(fr.W):
        A = fr.W * fr.f
    else:
        A = np.zeros((len(fr.x), 4))
        A[:, 0] = A[:, 3] = fr.f
    return Rm, cm.reshape(3), mc, fr, tau, A


#: the mountings' stacks of :class:`StackedViews`: (0, ids) -> (mountings, (R (M, 3, 3), c (M, 3)))
_MOUNTING_STACKS: dict = {}


def _stacked(counts: Sequence[int]) -> list[slice]:
    """The slices of consecutive blocks of ``counts`` rows each (the views of a stack)."""
    out, a = [], 0
    for n in counts:
        out.append(slice(a, a + int(n)))
        a += int(n)
    return out


class StackedViews:
    """The valid correspondences of one frame's views stacked by view (a camera alone: one
    view at the identity mounting; a rig frame: one per camera): normalized points ``x``
    (N, 2), world points ``X`` (N, 3), ``tau`` (N,) each point's capture time from the
    frame's reference time (s), ``cam`` (N,) its view, ``focal`` (N,) its camera's focal
    length (px per normalized unit), ``u_px`` (N, 2) its measured pixels, and ``A`` (N, 4):
    each point's row-major 2x2 pixel Jacobian of its camera
    (:meth:`~rs_localizer.camera.CameraModel.pixel_jacobian`, px per normalized unit: the
    normalized error times it is to first order the error in the measured, distorted image;
    the focal length times the identity for a camera without distortion and with fx = fy);
    ``compiled`` False: every step in NumPy/SciPy (the ``"numpy"`` implementation,
    :mod:`~.implementation`); ``max_norm`` (m): a point with a coordinate farther from the
    origin is dropped, as a single camera's frame drops it (the options'
    ``plausibility.max_point_norm``).

    It is the final stage's :class:`~.frame.RefinementView` of the frame (the refinements of
    :mod:`~.finalize` a single camera's frame takes): time ``r = tau`` (s, ``r0 = 0``, one
    second per unit), the errors in px through each camera's mounting.

    Raises:
        ValueError: a view that is not a :class:`View`, a camera without a mounting
            (``mounting`` None; the message names it) or with a mounting that is not a
            :class:`~rs_localizer.frames.Mounting`, no :class:`~rs_localizer.camera.CameraModel`,
            a stamp offset not finite, mismatched pixel and point counts or shapes, groups
            that are not one integer per correspondence."""

    #: the time of :class:`~.frame.RefinementView`: tau itself, in seconds
    r0 = 0.0
    spr = 1.0
    #: no planar motion prior in the final stage (:class:`~.frame.RefinementView`)
    planar = False
    #: the share of a grouped point's error variance its group shares where the frame's
    #: residuals cannot tell it (the options' ``correlated_noise.shift_share``)
    shift_share = 0.0
    #: the rig's ``(w (3,) rad/s, t (3,) m/s)`` known from outside the frame (a tracker's
    #: prediction) for the time offsets' share of a global-shutter rig frame's covariance,
    #: whose model has no twist (:func:`~.finalize.final_covariance`); None: none
    twist = None

    def __init__(
        self,
        views: Sequence[View],
        compiled: bool = True,
        cache: dict | None = None,
        max_norm: float = EstimateOptions().plausibility.max_point_norm,
    ):
        self.compiled = bool(compiled)
        # ``cache``: each view's checked and normalized part per view object and index, shared
        # by the stacks of one frame (a rig's consensus solves again on some of its cameras:
        # their views are the same objects, checked and undistorted once)
        cache = {} if cache is None else cache
        parts = [
            kept_per_objects(
                cache, (v,), functools.partial(_view_part, c, v, self.compiled, max_norm), c
            )
            for c, v in enumerate(views)
        ]
        # (the mountings stacked, kept per tuple of mounting objects: frozen, a rig's frames
        # share them; read only, as every stack's)
        self.R_mount, self.c_mount = kept_per_objects(
            _MOUNTING_STACKS,
            tuple([v.mounting for v in views]),
            lambda: (np.array([q[0] for q in parts]).reshape(-1, 3, 3),
                     np.array([q[1] for q in parts]).reshape(-1, 3)),
        )  # fmt: skip
        self.mount_cov = [q[2] for q in parts]
        #: each camera's time offset std (s, its mounting's ``time_offset_std``)
        self.time_std = [v.mounting.time_offset_std for v in views]
        #: some camera's mounting has a covariance or a time offset std
        self.has_mount_cov = any(mc is not None for mc in self.mount_cov) or any(self.time_std)
        #: each view's :class:`~.frame.Frame` (its valid rows, their groups, its input rows)
        self.frames = frames = [q[3] for q in parts]
        self.sizes = [fr.num_rows for fr in frames]
        n = [len(fr.x) for fr in frames]
        #: each view's points in the stack
        self.slices = _stacked(n)
        self._sizes_valid = tuple(n)
        #: (M,) each view's focal length (px)
        self.view_focal = np.array([fr.f for fr in frames], dtype=float)
        if len(parts) == 1:  # (one view: its arrays copied, as concatenated alone)
            (fr,) = frames
            self.cam, self.focal = np.zeros(n[0], dtype=np.int64), np.empty(n[0])
            self.focal.fill(fr.f)
            self.x, self.X, self.u_px = fr.x.copy(), fr.X.copy(), fr.u_px.copy()
            self.tau, self.A = parts[0][4].copy(), parts[0][5].copy()
        else:
            if not parts:
                raise ValueError("StackedViews: needs at least one view")
            self.cam = np.arange(len(parts), dtype=np.int64).repeat(n)
            self.focal = self.view_focal.repeat(n)
            self.x, self.X, self.u_px = [
                np.concatenate([getattr(fr, k) for fr in frames]) for k in ("x", "X", "u_px")
            ]
            self.tau, self.A = [np.concatenate([q[k] for q in parts]) for k in (4, 5)]
        #: s: the observation times' spread (np.ptp of tau; 0 without points)
        self.tau_spread = float(self.tau.max() - self.tau.min()) if len(self.tau) else 0.0

    @functools.cached_property
    def row(self) -> np.ndarray:
        """(N,) int64: each point's row in its view's input rows (stacked by view)."""
        return np.concatenate([fr.rows for fr in self.frames]).astype(np.int64, copy=False)

    @property
    def r(self) -> np.ndarray:
        return self.tau

    @functools.cached_property
    def groups(self) -> np.ndarray | None:
        """(N,) int64 each point's group (:attr:`View.groups`; one marker seen by two cameras
        is a group in each, a view without groups a group per point), or None when no view
        has groups (:class:`~.frame.RefinementView`)."""
        if all(fr.groups is None for fr in self.frames):
            return None
        out, first = [], 0  # (each view's groups numbered on from the last view's)
        for fr, n in zip(self.frames, self._sizes_valid, strict=True):
            g = fr.groups
            if g is None:
                ids = np.arange(n, dtype=np.int64)
            else:
                _, ids = np.unique(g, return_inverse=True)
            out.append(ids.reshape(-1) + first)
            first += int(ids.max()) + 1 if n else 0
        return np.concatenate(out).astype(np.int64, copy=False)

    @functools.cached_property
    def bounds(self) -> np.ndarray:
        """(M, 2) int64: each view's first and end row in the stack."""
        return np.array([(s.start, s.stop) for s in self.slices], np.int64).reshape(-1, 2)

    @functools.cached_property
    def plain_mountings(self) -> Mountings:
        """The points as the refinement's :class:`~.refine.Mountings`: each camera's mounting,
        errors in px (its pixel Jacobian at each point, ``A``, as the scale)."""
        return Mountings(
            np.ascontiguousarray(self.cam, dtype=np.int64),
            np.ascontiguousarray(self.R_mount),
            np.ascontiguousarray(self.c_mount),
            self.A.reshape(-1, 2, 2),
        )

    @functools.cached_property
    def compiled_mountings(self) -> KernelMountings:
        """:attr:`plain_mountings` checked and converted once into the refinement kernel's
        form (:func:`~.refine.kernel_mountings`, as a camera's refinement converts its
        frame's): every refinement and the covariance of a frame take it."""
        return kernel_mountings(self.plain_mountings, len(self.cam))

    @functools.cached_property
    def kernel_arrays(self) -> tuple:
        """``(X, x, tau, mountings)`` as the compiled kernels take them (contiguous float64
        arrays, :attr:`compiled_mountings`' views): a frame refines and scores several times."""
        f = np.float64
        return (np.ascontiguousarray(self.X, dtype=f), np.ascontiguousarray(self.x, dtype=f),
                np.ascontiguousarray(self.tau, dtype=f), self.compiled_mountings.views)  # fmt: skip

    def views(self) -> tuple:
        """The cameras of :class:`~.frame.RefinementView`: ``(R_mount (M, 3, 3), c_mount (M,
        3), rows (M, 2))``, each camera's mounting and its rows in the stack."""
        return self.R_mount, self.c_mount, self.bounds

    def mounting_covariances(self) -> tuple | None:
        """``(the stack's :class:`~.refine.Mountings`, each camera's mounting covariance
        (6, 6) or None, each camera's time offset std (s, 0: none), :attr:`twist`)`` when
        some camera's mounting has either, else None
        (:meth:`~.frame.RefinementView.mounting_covariances`)."""
        if not self.has_mount_cov:
            return None
        return self.plain_mountings, self.mount_cov, self.time_std, self.twist

    def mountings(self) -> Mountings | KernelMountings:
        """The refinement's mountings of every point (:attr:`plain_mountings`, checked for the
        compiled kernel: :attr:`compiled_mountings`)."""
        return self.compiled_mountings if self.compiled else self.plain_mountings

    def errors(self, model: RSModel | tuple) -> np.ndarray:
        """(N,) errors (px) of one model ``(R, C, w, t)`` (:meth:`best_scored`)."""
        return self.scored(model, np.inf)[0]

    def scored(self, model: RSModel | tuple, th2: float) -> tuple[np.ndarray, float]:
        """``(errors (N,) px, MSAC cost)`` of one model ``(R, C, w, t)`` (:meth:`best_scored`;
        the squared errors capped at ``th2`` px^2 and summed)."""
        _, cost, e = self.best_scored(*(np.asarray(a)[None] for a in model), th2)
        return e, cost

    def best_scored(
        self, R: np.ndarray, C: np.ndarray, w: np.ndarray, t: np.ndarray, th2: float
    ) -> tuple[int, float, np.ndarray]:
        """The model of the lowest MSAC cost among H models R (H, 3, 3), C, w, t (H, 3) on the
        stack's points (each squared reprojection error (px^2) capped at ``th2``, the exact
        rotation ``expm(tau [w]x)`` at each observation's measured capture time, inf for a
        point behind its camera): ``(h, its cost, its (N,) errors px)``, ``h`` the first
        minimum as ``np.argmin`` picks it. Compiled: the camera's
        :func:`~.scoring.msac_scores` with the mountings, every point in index order
        (:func:`~.scoring.best_mounted`); NumPy: the NumPy implementation's
        :func:`~.numpy_impl.errors2` of the stacked views, a camera's errors with its
        mounting."""
        if not self.compiled:
            e2 = errors2(self, *(np.asarray(a, dtype=float) for a in (R, C, w, t)))
            cost = np.minimum(e2, th2).sum(axis=1)
            h = int(np.argmin(cost))
            return h, float(cost[h]), np.sqrt(e2[h])
        f = [np.ascontiguousarray(a, dtype=np.float64) for a in (R, C, w, t)]
        X, x, tau, (cam, Rm, cm, A) = self.kernel_arrays
        mount = (cam, Rm, cm, tau, False, np.arange(len(cam)))
        h, cost, e = best_mounted(*f, np.ones(len(f[0]), dtype=bool), X, x, A, mount, th2,
                                  np.inf, 0, 0)  # fmt: skip
        return int(h), float(cost), e

    def per_camera(self, mask: np.ndarray) -> tuple:
        """(N,) bool -> one (N_c,) bool per view over its input rows (its frame's
        :meth:`~.frame.Frame.input_mask`)."""
        return tuple(fr.input_mask(mask[s]) for fr, s in zip(self.frames, self.slices, strict=True))

    def counts(self, mask: np.ndarray | None = None) -> tuple[int, ...]:
        """(M,) number of the stack's points (``mask`` (N,) bool: of those selected) per view
        (:func:`numpy.bincount` of their views, as :func:`~.sampling.view_sampling` counts)."""
        if mask is None:
            return self._sizes_valid
        return tuple(np.bincount(self.cam[mask], minlength=len(self.slices)).tolist())

    def view_planar(self, c: int) -> bool:
        """View c's points are coplanar (:func:`~.degeneracy.coplanar`)."""
        return coplanar(self.X[self.slices[c]], self.compiled)

    #: ``degenerate(mask, threshold_px, compiled)``: the points ``mask`` selects fix no pose,
    #: a camera's frame's test on every view (:meth:`~.frame.Frame.degenerate`: each view's
    #: points of :attr:`bounds` at its :attr:`view_focal`; fewer than 3: each camera's rays in
    #: one plane through its centre)
    degenerate = Frame.degenerate

    def repeated(self, copies: Sequence[int]) -> StackedViews:
        """The stack with view c's points repeated ``copies[c]`` times (a least-squares fit on
        it weighs the views so). Only for fitting: its rows no longer map to the views'."""
        idx = np.concatenate(
            [
                np.tile(np.arange(s.start, s.stop), k)
                for s, k in zip(self.slices, copies, strict=True)
            ]
        )
        out = copy.copy(self)
        for cached in ("plain_mountings", "compiled_mountings", "kernel_arrays", "bounds"):
            out.__dict__.pop(cached, None)
        for name in ("x", "X", "u_px", "tau", "row", "focal", "A", "cam"):
            setattr(out, name, np.ascontiguousarray(getattr(self, name)[idx]))
        sizes = [k * (s.stop - s.start) for s, k in zip(self.slices, copies, strict=True)]
        out.slices = _stacked(sizes)
        out._sizes_valid = tuple(sizes)
        return out

    def samples(
        self, rng: np.random.Generator, n_samples: int, subset: np.ndarray | None = None
    ) -> np.ndarray:
        """n_samples samples of 6 indices of the stack: 3 from one view with >= 3 points
        (chosen in proportion to its points), then 3 distinct others from all views;
        ``subset`` (sorted indices, at least 3 of one view and 6 in all): drawn among those
        only. Returns (S, 6). Compiled: :func:`~.sampling.batch_samples` (on the same 7
        draws per sample); NumPy: a camera's draws (:func:`~.sampling.draw_samples_numpy`)
        with the first three in the chosen view's range of the stack, on
        :func:`~.sampling.view_sampling`'s distribution."""
        u = rng.random(7 * n_samples).reshape(7, n_samples)
        no = np.zeros(0, dtype=np.int64)
        if self.compiled:
            counts = np.array(self.counts(), dtype=np.int64)
            return batch_samples(u, self.cam, counts, no if subset is None else subset)
        cam = self.cam if subset is None else self.cam[subset]
        counts, starts, eligible, cdf, n = view_sampling(cam, len(self.sizes))
        cams = eligible[cdf.searchsorted(u[0], side="right")]
        size, offset = np.full((n_samples, 6), n), np.zeros((n_samples, 6), dtype=np.int64)
        size[:, :3], offset[:, :3] = counts[cams][:, None], starts[cams][:, None]
        out = draw_samples_numpy(u[1:].T, size, offset)
        return out if subset is None else subset[out]
