"""Localizer.search_image and Localizer.frame_time: one image search and one frame time for a
camera alone (a rig of one, SequenceLocalizer) and each camera of a rig, with the rules only a
camera alone has (too few correspondences, a frozen image restarting its track, any stamp
going back a time reset)."""

import numpy as np

from rs_localizer.camera import CameraModel, FrameTime, reference_stamp_ns
from rs_localizer.estimation.options import EstimateOptions, points_needed
from rs_localizer.frames import Mounting
from rs_localizer.tracking.sequence import SequenceLocalizer, SequenceSettings
from rs_localizer.tracking.video import Localizer, LocalizerSettings

CAMERA = CameraModel(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), line_delay=3e-5)
T0 = 1_700_000_000_000_000_000
# five correspondences of points off any plane: fewer than a rolling-shutter solver needs
XYZ = np.array([[0.0, 0, 4], [1, 0, 5], [0, 1, 6], [1, 1, 3], [-1, 0.5, 7]])
UV = np.array([[320.0, 240], [420, 240], [320, 323], [487, 407], [249, 276]])


class FivePoints:
    """A per-image front end that finds the same five correspondences in every image."""

    def process(self, image, camera, encoding="bgr8"):
        return UV.copy(), XYZ.copy(), np.arange(5)


def _image(seed):
    return np.random.default_rng(seed).integers(0, 255, (480, 640), dtype=np.uint8)


def _localizer(names, shift=0.0):
    mounts = {n: Mounting(np.eye(3), np.array([shift * k, 0, 0])) for k, n in enumerate(names)}
    rig = Localizer(LocalizerSettings(mounts, options=EstimateOptions()))
    for n in names:
        rig.set_frontend(n, FivePoints(), "five")
    return rig


def test_too_few_correspondences_fail_a_camera_alone_but_join_a_rig_frame():
    need = points_needed(LocalizerSettings({"": Mounting(np.eye(3), np.zeros(3))}).solver,
                         EstimateOptions())  # fmt: skip
    assert need > len(XYZ)
    alone = _localizer([""]).search_image("", T0, _image(0), CAMERA)
    assert (alone.failure, alone.need, len(alone.found)) == ("frontend_too_few_points", need, 5)
    rig = _localizer(["a", "b"], shift=0.1)
    both = rig.search_image("a", T0, _image(0), CAMERA)
    assert (both.failure, both.need, len(both.found)) == (None, None, 5)
    # (the same rule through SequenceLocalizer.process_image: dropped before the estimator)
    seq = SequenceLocalizer(SequenceSettings(), frontend=FivePoints(), frontend_name="five")
    out = seq.process_image(T0, _image(0), CAMERA)
    assert out.failure == "frontend_too_few_points" and out.estimate is None
    assert out.detail == f"five front end found 5 matches: 5 correspondences, {need} needed"


def test_a_frozen_image_is_skipped_by_both_and_the_stamp_going_back_resets_a_camera_alone():
    for names in ([""], ["a", "b"]):
        rig = _localizer(names, shift=0.1)
        n = names[0]
        assert rig.search_image(n, T0, _image(1), CAMERA).failure != "frozen_image"
        again = rig.search_image(n, T0 + 33_000_000, _image(1), CAMERA)
        assert again.failure == "frozen_image" and again.found is None
        assert rig.search_image(n, T0 + 66_000_000, _image(2), CAMERA).failure != "frozen_image"
    one = _localizer([""])
    assert one.settings.back_tolerance_ns == 0
    assert one.check_time(T0) is None and one.check_time(T0 - 1_000_000) is not None
    rig = _localizer(["a", "b"], shift=0.1)
    assert rig.settings.back_tolerance_ns == rig.settings.time_reset_ns == 10**9


def test_frame_time_is_the_reference_line_plus_the_camera_offset():
    mounts = {"a": Mounting(np.eye(3), np.zeros(3)), "b": Mounting(np.eye(3), np.ones(3))}
    rig = Localizer(LocalizerSettings(mounts, stamp_row=100.0, time_offsets={"b": 0.002}))
    ref = reference_stamp_ns(T0, CAMERA, 100.0)
    assert rig.frame_time("a", T0, CAMERA) == FrameTime(T0, ref)
    assert rig.frame_time("b", T0, CAMERA) == FrameTime(T0, ref + 2_000_000)
    assert rig.frame_time("b", T0, None) == FrameTime(T0, T0 + 2_000_000)
    seq = SequenceLocalizer(SequenceSettings(stamp_row=100.0))
    assert seq.frame_time(T0, CAMERA) == FrameTime.of(T0, CAMERA, 100.0)
    # (the reference line, the centre row 239.5, read 139.5 rows of 30 us after row 100)
    assert ref - T0 == round(139.5 * 3e-5 * 1e9)


def _spy(monkeypatch):
    """The times each frame is noted on a video's clock and the stamps whose reference time is
    computed (``reference_stamp_ns`` with a camera model, the one rule of it; without one it
    puts a stamp on the rig's clock)."""
    from rs_localizer.tracking import video
    from rs_localizer.tracking.clock import VideoClock

    steps, refs = [], []
    step, ref = VideoClock.step, video.reference_stamp_ns
    monkeypatch.setattr(VideoClock, "step", lambda c, t, p: steps.append(t) or step(c, t, p))

    def spy(s, camera, *a):
        if camera is not None:
            refs.append(s)
        return ref(s, camera, *a)

    monkeypatch.setattr(video, "reference_stamp_ns", spy)
    return steps, refs


def test_a_frames_time_is_noted_once_and_its_reference_time_made_once(monkeypatch):
    """A camera's frame, cloud or image, noted on its video's clock once and its reference time
    computed once, whether the caller notes its stamp first (``check_time``, as the node does
    before it looks up the frame's camera) or not; the time resets the same either way."""
    from rs_localizer.camera import checked_stamp
    from rs_localizer.tracking.localizer import CameraFrame

    rng = np.random.default_rng(3)
    xyz = np.c_[rng.uniform(-1, 1, (12, 2)), rng.uniform(4, 8, 12)]
    uv = xyz[:, :2] / xyz[:, 2:] * 500 + [320, 240]
    # (a step back and a jump ahead of more than time_reset_ns: two time resets)
    stamps = [T0, T0 + 33_000_000, T0 - 10**9, T0 - 10**9 + 33_000_000, T0 + 20 * 10**9]
    resets = {}
    for kind in ("cloud", "image"):
        for noted_first in (True, False):
            steps, refs = _spy(monkeypatch)
            seq = SequenceLocalizer(SequenceSettings(), frontend=FivePoints(), frontend_name="f")
            why = []
            for k, s in enumerate(stamps):
                stamp = checked_stamp(s)  # (the node's entry)
                if noted_first:
                    why.append(seq.check_time(stamp))
                ft = seq.frame_time(stamp, CAMERA)
                if kind == "image":
                    seq.process_image(ft, _image(k), CAMERA)
                else:
                    seq.process(CameraFrame(stamp, CAMERA, uv, xyz), ft)
                assert steps == stamps[: k + 1] and refs == stamps[: k + 1]
            if noted_first:
                assert [w is not None for w in why] == [False, False, True, False, True]
            resets[kind, noted_first] = seq._rig.counts["rig.time_resets"]
    assert set(resets.values()) == {2}


def test_a_camera_videos_image_failure_is_its_callers_a_rig_of_ones_is_counted():
    # a rig of one camera at the identity mounting counts a skipped image as received and
    # skipped; a camera's own video (its camera named "": SequenceLocalizer's, a camera's bag
    # replayed) returns it to its caller uncounted, its failure to read from last_search
    rig = _localizer(["cam"])
    assert rig.process_image("cam", T0, _image(0), CAMERA) == []
    assert rig.counts["cam.received"] == 1
    assert rig.counts["cam.skipped.frontend_too_few_points"] == 1
    seq = SequenceLocalizer(SequenceSettings(), frontend=FivePoints(), frontend_name="five")
    for video in (seq.rig, _localizer([""])):
        assert video.process_image("", T0, _image(0), CAMERA) == []
        assert video.last_search("").failure == "frontend_too_few_points"
        assert len(video.last_search("").found) == 5 and sum(video.counts.values()) == 0
        assert video.process_image("", T0 + 33_000_000, _image(0), CAMERA) == []
        assert video.last_search("").failure == "frozen_image" and sum(video.counts.values()) == 0
    out = seq.image_output(seq.frame_time(T0 + 33_000_000, CAMERA), [])
    assert out.failure == "frozen_image" and out.detail.startswith("the image is the previous")
    assert out.stamp_ns == reference_stamp_ns(T0 + 33_000_000, CAMERA, 0.0)
