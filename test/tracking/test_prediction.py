"""The one prediction of a video and its one time rule: the image front end of
``SequenceLocalizer.process_image`` is handed the tracker's prediction (the model its estimator
tests first; against the synthetic video's true projections), or without tracking the last
solved frame carried at its own twist; nothing after a stamp going back or a gap longer than
the video's ``max_gap``, which the gyro check and the gyro-bias estimator are given too."""

from dataclasses import replace

import numpy as np
import pytest

from rs_localizer.correspondences import Correspondences, FrontendHooks
from rs_localizer.estimation.estimate import EstimateOptions, RansacOptions
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence, make_trajectory
from rs_localizer.tracking.gyro_bias import GyroBiasOptions
from rs_localizer.tracking.gyro_check import MountCheckOptions
from rs_localizer.tracking.sequence import GyroSettings, SequenceLocalizer, SequenceSettings
from rs_localizer.tracking.tracker import RSTracker, TrackerOptions, model_from_state

OPTS = EstimateOptions(ransac=RansacOptions(seed=0))


@pytest.fixture(scope="module")
def video():
    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=12, seed=3), trajectory=make_trajectory("walk")
    )
    return frames, cam


class Recorder(FrontendHooks):
    """A video front end giving the frame's correspondences and keeping what it is handed."""

    def __init__(self):
        self.frame = None
        self.got = []

    def process(self, image, camera=None, encoding="bgr8", prediction=None):
        self.got.append(prediction)
        return Correspondences(self.frame.uv, self.frame.xyz)


def _true_px_error(cam, model, f):
    """Median distance (px) of the frame's true inliers' projections under ``model`` to their
    noise-free pixels."""
    uv = cam.project_rs(f.xyz[f.inlier], *model, iterations=5)
    return float(np.median(np.linalg.norm(uv - f.uv_clean[f.inlier], axis=1)))


def test_the_front_end_is_handed_the_trackers_prediction(video):
    frames, cam = video
    image = np.zeros((cam.height, cam.width), np.uint8)
    fe = Recorder()
    seq = SequenceLocalizer(SequenceSettings(options=OPTS), frontend=fe)
    tracker = RSTracker(options=OPTS)  # (driven directly beside it: the same predictions)
    last = last_ref = None
    err_pred, err_carried = [], []
    for k, f in enumerate(frames):
        fe.frame = f
        out = seq.process_image(f.stamp_ns, image, cam)
        r = tracker.process(f.t_ref_ns, f.uv, f.xyz, cam)
        assert out.estimate.success
        pred = fe.got[-1]
        if k == 0:
            assert pred is None and r.predicted is None
        else:
            assert out.path == "tracked"
            for a, b in zip(pred, model_from_state(r.predicted, cam), strict=True):
                np.testing.assert_array_equal(a, b)
            # the last solved frame carried at its own twist (what front ends used to do)
            R, C, w, t = last.model
            dT = (f.t_ref_ns - last_ref) * 1e-9 / cam.seconds_per_unit_r
            carried = (rotvec_to_matrix(dT * w) @ R, C + dT * t, w, t)
            err_pred.append(_true_px_error(cam, pred, f))
            err_carried.append(_true_px_error(cam, carried, f))
        last, last_ref = out.estimate, f.t_ref_ns
    # against the truth: a few pixels, and closer than the last frame carried
    assert max(err_pred) < 5.0, err_pred
    assert np.median(err_pred) < np.median(err_carried), (err_pred, err_carried)


def test_without_tracking_the_last_solved_frame_is_carried(video):
    frames, cam = video
    image = np.zeros((cam.height, cam.width), np.uint8)
    fe = Recorder()
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, tracking=None), frontend=fe)
    last = None
    for f in frames[:5]:
        fe.frame = f
        out = seq.process_image(f.stamp_ns, image, cam)
        pred = fe.got[-1]
        if last is None:
            assert pred is None
        else:
            est, ref = last
            dT = (f.t_ref_ns - ref) * 1e-9 / cam.seconds_per_unit_r
            want = (
                rotvec_to_matrix(dT * est.model.w) @ est.model.R,
                est.model.C + dT * est.model.t,
                est.model.w,
                est.model.t,
            )
            for a, b in zip(pred, want, strict=True):
                np.testing.assert_array_equal(a, b)
            assert _true_px_error(cam, pred, f) < 10.0
        last = (out.estimate, f.t_ref_ns)


@pytest.mark.parametrize("tracking", [TrackerOptions(max_gap=0.2), None])
def test_no_prediction_across_a_gap_or_a_stamp_going_back(video, tracking):
    frames, cam = video
    image = np.zeros((cam.height, cam.width), np.uint8)
    fe = Recorder()
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, tracking=tracking), frontend=fe)
    gap = seq.settings.max_gap
    assert gap == (0.2 if tracking is not None else TrackerOptions().max_gap)
    period = frames[1].stamp_ns - frames[0].stamp_ns
    f0 = frames[0]
    stamps = [
        f0.stamp_ns,  # the first frame: no prediction
        f0.stamp_ns + period,  # predicted
        f0.stamp_ns + period + int(gap * 1e9) + 1,  # just over the gap: none
        f0.stamp_ns + period + int(gap * 1e9) + 1 + int(gap * 1e9),  # just within: predicted
        f0.stamp_ns,  # back in time: none
        f0.stamp_ns,  # the same stamp again: none
    ]
    for stamp in stamps:
        fe.frame = f0  # (the same correspondences: every frame solves)
        out = seq.process_image(stamp, image, cam)
        assert out.estimate.success
    assert [p is not None for p in fe.got] == [False, True, False, True, False, False]
    if tracking is not None:  # (the tracker restarts on the same frames)
        assert seq.tracking_values()["resets"] == 3


def test_the_gap_is_passed_to_the_gyro_check_and_bias_estimator():
    imu = GyroSettings(estimate_bias=True)
    seq = SequenceLocalizer(SequenceSettings(imu=imu))
    # (the defaults agree: the video's gap is the check's and the estimator's own default)
    assert seq.settings.max_gap == TrackerOptions().max_gap
    assert seq.gyro_bias.options.max_interval == GyroBiasOptions().max_interval == 0.5
    assert seq.gyro_check.options.max_interval == MountCheckOptions().max_interval == 0.5
    seq.configure(SequenceSettings(imu=imu, tracking=TrackerOptions(max_gap=0.3)))
    assert seq.gyro_bias.options.max_interval == seq.gyro_check.options.max_interval == 0.3
    seq.configure(replace(seq.settings, tracking=None))
    assert seq.gyro_bias.options.max_interval == 0.5
