"""The staged estimator of one view or many: one camera's frame
(:func:`~.estimate.estimate_rs_pose`) and a rig frame's cameras
(:func:`~.rig.estimate_rig_pose`) run the same stages in the same order, as PoseLib's
``estimate_absolute_pose`` and ``estimate_generalized_absolute_pose`` run one ``ransac<>``
template with their own estimator.

The stages (:func:`staged_estimate`):

1. input checks and degeneracy (:meth:`Stages.prepared`): too few valid points, points that
   fix no pose; a frame posed without RANSAC (a camera's few points,
   :mod:`~.single_tag`) ends here;
2. the initial-model seed and RANSAC through the view's search object
   (:meth:`Stages.searched`: :class:`~.ransac.Ransac`, its NumPy twin, or the rig's search,
   each a :class:`~.ransac.RansacLoop`), the best model or ``no_hypothesis``,
   ``implausible_motion``, ``too_few_inliers``;
3. local optimization after the search (:meth:`Stages.polished`,
   :func:`~.local_optimization.polish`; a camera's runs on every new best inside its search);
4. the final refinement, the final inliers and the covariance (:meth:`Stages.final`:
   :func:`~.finalize.chosen_refinement` or :func:`~.finalize.final_refinement`,
   :func:`~.finalize.selected_final`, :func:`~.finalize.frame_refinement`,
   :func:`~.finalize.with_covariance`);
5. the last checks and the result (:meth:`Stages.finished`: :func:`~.finalize.checked_outputs`,
   :func:`~.result.built_estimate`);
6. a stage's failure (:class:`~.result.EstimationFailed`) tried once more where the view's
   estimator has a second way (:meth:`Stages.retried`: the global-shutter model of a frame
   that shows no motion, :func:`~.finalize.still_fallback`; a rig frame taken at one time
   searched again with its samples corrected across the cameras), else the failed estimate
   with its reason (:meth:`Stages.failed`).

With a gyro (:func:`gyro_checked_estimate`) the stages run aided by it, then the gyro is
judged by the image alone (:func:`~.gyro.gyro_checked`) and the frame solved again without it
when they disagree.

What differs between one view and many is the :class:`Stages` object: its search (the
minimal solver, the samples, the scoring), its model's time unit (a camera's rows, a rig's
seconds), its refinement (a camera's maximum likelihood then maximum a posteriori, a rig's
choice among refinements with :data:`~.rig.CONTRADICTION_GATE`), the views that support a
fit (:data:`~.rig.AGREE_SHARE`) and its second ways.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from .finalize import FinalModel, ImageAlone
from .frame import Model
from .gyro import GyroMeasurement, gyro_checked
from .options import EstimateOptions, InitialModel
from .result import EstimationFailed, RSPoseEstimate

__all__ = ["Stages", "checked_inputs", "gyro_checked_estimate", "staged_estimate"]


class Stages(Protocol):
    """One view's or many views' estimator: the stages :func:`staged_estimate` runs in order.
    Each stage raises :class:`~.result.EstimationFailed` when the frame gives no pose."""

    def prepared(self) -> RSPoseEstimate | None:
        """Check the inputs and that they can fix a pose; an estimate when the frame is posed
        without RANSAC (a few points), else None."""
        ...

    def searched(self) -> Model:
        """The initial-model seed and RANSAC: the best model ``(R, C, w, t)``."""
        ...

    def polished(self, model: Model) -> Model:
        """Local optimization of the search's best model."""
        ...

    def final(self, model: Model) -> FinalModel:
        """The final refinement of ``model``, its inliers and covariance."""
        ...

    def finished(self, final: FinalModel) -> RSPoseEstimate:
        """The last checks on ``final`` and the successful estimate."""
        ...

    def retried(self, failure: EstimationFailed) -> RSPoseEstimate | None:
        """The frame estimated a second way after ``failure``, or None (none applies)."""
        ...

    def failed(self, failure: EstimationFailed) -> RSPoseEstimate:
        """The failed estimate of ``failure``'s reason."""
        ...

    def gyro_evidence(
        self, est: RSPoseEstimate
    ) -> tuple[ImageAlone | None, Callable[[], bool], int]:
        """For a gyro-aided ``est``: what the image alone says near it
        (:func:`~.finalize.image_alone`, None when it failed), whether its inliers are
        coplanar, the number of valid points (:func:`~.gyro.gyro_checked`'s arguments)."""
        ...


def checked_inputs(
    who: str,
    options: EstimateOptions | None,
    default: EstimateOptions,
    initial_model: object,
    gyro: object,
) -> tuple[EstimateOptions, InitialModel | None]:
    """The inputs every estimator checks alike (``who``: its name, for the messages):
    ``options`` (None: ``default``) and ``initial_model`` as an
    :class:`~.options.InitialModel` (a bare model ``(R, C, w, t)``: one with the default
    gate; None stays None).

    Raises:
        ValueError: ``options`` that are not an :class:`~.options.EstimateOptions`, a ``gyro``
            that is not a :class:`~.gyro.GyroMeasurement` (None: none)."""
    options = default if options is None else options
    if not isinstance(options, EstimateOptions):
        raise ValueError(f"{who}: options must be an EstimateOptions, got {type(options).__name__}")
    if gyro is not None and not isinstance(gyro, GyroMeasurement):
        raise ValueError(f"{who}: gyro must be a GyroMeasurement, got {gyro!r}")
    if initial_model is not None and not isinstance(initial_model, InitialModel):
        initial_model = InitialModel(initial_model)
    return options, initial_model


def staged_estimate(stages: Stages) -> RSPoseEstimate:
    """The estimate of ``stages``' frame: its stages in order (module docstring), a stage's
    failure turned into the second way's estimate or the failed estimate in one place."""
    try:
        early = stages.prepared()
        if early is not None:
            return early
        model = stages.polished(stages.searched())
        return stages.finished(stages.final(model))
    except EstimationFailed as failure:
        again = stages.retried(failure)
        return stages.failed(failure) if again is None else again


def gyro_checked_estimate(
    aided: Stages,
    gyro: GyroMeasurement,
    unaided: Callable[[], RSPoseEstimate],
    compiled: bool = True,
) -> RSPoseEstimate:
    """The estimate of the gyro-aided ``aided`` stages (:func:`staged_estimate`), the gyro
    judged by the image alone (:meth:`Stages.gyro_evidence`, :func:`~.gyro.gyro_checked`):
    ``unaided()`` (the frame without the gyro) when they disagree or the aided estimate
    fails. A frame posed from a few points is returned as it is (a few points cannot judge
    the gyro: its rate is held, not checked)."""
    est = staged_estimate(aided)
    if est.few_points:
        return est
    image, planar, num_valid = aided.gyro_evidence(est)
    return gyro_checked(est, gyro, image, planar, num_valid, unaided, compiled)
