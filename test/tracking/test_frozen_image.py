"""A frozen image (a driver re-sending its last frame, a USB stall) in a rendered
rolling-shutter video of ``textured_room`` tracked with the feature front end: the repeated
images are refused as ``frozen_image`` and no pose published after them is wrong (within
1 deg and 5 cm of the renderer's truth). The background refresh is joined after every frame,
so every run is the same."""

import numpy as np
import pytest
from helpers.videos import shake_video

from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.frontends.tracking import TrackingFeatureFrontend
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.tracking.sequence import SequenceLocalizer, SequenceSettings
from rs_localizer.tracking.tracker import CarriedPrediction

pytestmark = pytest.mark.slow  # (renders a map and a 40-frame video)

FROZEN = range(15, 23)  # frames carrying frame 14's image, with their own stamps


@pytest.fixture(scope="module")
def video():
    return shake_video(40 / 30, 40, seed=0)


def _run(video, settings=None, frozen=FROZEN, **fe_args):
    fmap, frames, camera, _, _ = video
    fe = TrackingFeatureFrontend(fmap, **fe_args)
    seq = SequenceLocalizer(settings or SequenceSettings(), frontend=fe, frontend_name="features")
    out = []
    for k, f in enumerate(frames):
        image = frames[frozen[0] - 1].image if k in frozen else f.image
        res = seq.process_image(int(round(f.t_first * 1e9)), image, camera, "rgb8")
        fe.wait_refresh(60.0)  # (the refresh joins at a fixed frame: every run the same)
        est = res.estimate
        if est is not None and est.success:
            err = (
                rotation_angle_deg(est.pose.orientation, f.orientation),
                100 * np.linalg.norm(est.pose.position - f.position),
                int(np.count_nonzero(est.inliers)),
            )
        else:
            err = None
        out.append((res.failure or (est.failure if est is not None else "error"), err))
    return out


def test_a_frozen_image_gives_no_wrong_pose(video):
    got = _run(video)
    wrong = [(k, e) for k, (_, e) in enumerate(got) if e and (e[0] > 1.0 or e[1] > 5.0)]
    assert wrong == [], wrong
    assert [got[k][0] for k in FROZEN] == ["frozen_image"] * len(FROZEN)
    solved = [k for k, (_, e) in enumerate(got) if e is not None]
    assert set(range(FROZEN[0])) <= set(solved)  # (before the freeze: every frame)
    after = [k for k in solved if k > FROZEN[-1]]
    assert len(after) >= len(got) - FROZEN[-1] - 3, got[FROZEN[-1] :]  # (it relocalizes)


@pytest.mark.parametrize("start, length", [(10, 13), (18, 13)])
def test_the_track_restarts_after_a_frozen_image(video, start, length):
    """Longer freezes (13 frames, 0.43 s: still within the tracker's ``max_gap``) at two places
    of the video: no wrong pose, and the optical flow's tracks hold after the freeze. A
    prediction from the track before the freeze (the relocalized frame fused into a window of
    frames from before it) misplaced them: two frames after the freeze the tracks collapsed to
    a quarter of the video's inliers (266 of ~950, 249 inliers), the weak consensus a pose
    7 cm off came from in some runs of the background refresh."""
    frozen = range(start, start + length)
    got = _run(video, frozen=frozen)
    wrong = [(k, e) for k, (_, e) in enumerate(got) if e and (e[0] > 1.0 or e[1] > 5.0)]
    assert wrong == [], wrong
    assert [got[k][0] for k in frozen] == ["frozen_image"] * length
    before = np.median([got[k][1][2] for k in range(start)])
    after = [got[k][1][2] if got[k][1] else 0 for k in range(frozen[-1] + 1, frozen[-1] + 6)]
    assert min(after) > 0.6 * before, (before, after)


def test_collapsed_tracks_are_matched_whole(video):
    """The front end's own guard: an image that jumped (frame 23's image at frame 16's stamp,
    after a frozen frame the front end was not told about) leaves few tracks; fewer than a
    quarter of the video's recent inliers, so the frame is matched whole (``few_tracks``)
    and its pose is right, where without the guard a pose rests on the survivors."""
    fmap, frames, camera, _, _ = video
    got = {}
    for ratio in (0.25, 0.0):
        fe = TrackingFeatureFrontend(fmap, collapse_ratio=ratio)
        carry = CarriedPrediction()  # (the last solved frame carried: the search's prediction)
        for k in [*range(16), 23]:
            image = frames[14].image if k == 15 else frames[k].image
            stamp = int(round(frames[16 if k == 23 else k].t_first * 1e9))
            pred = carry.predict(stamp, camera)
            uv, X, _ = fe.process(image, camera, "rgb8", prediction=pred)
            est = estimate_rs_pose(uv, X, camera) if len(uv) >= 6 else None
            fe.observe(stamp, None, est)
            carry.update(stamp, est)
            fe.wait_refresh(60.0)
        got[ratio] = (fe.report.kind, fe.report.reason, len(uv), est)
    kind, reason, n, est = got[0.25]
    assert (kind, reason) == ("global", "few_tracks") and est.success
    assert rotation_angle_deg(est.pose.orientation, frames[23].orientation) < 1.0
    assert np.linalg.norm(est.pose.position - frames[23].position) < 0.05
    kind, _, n_tracked, _ = got[0.0]
    assert kind == "tracked" and n_tracked < 0.25 * n  # (what the guard caught)
