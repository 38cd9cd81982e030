"""A frozen image (a driver re-sending its last frame, a USB stall) in a rendered
rolling-shutter video of ``textured_room`` tracked with the feature front end: the repeated
images are refused as ``frozen_image`` and no pose published after them is wrong (within
1 deg and 5 cm of the renderer's truth). The background refresh is joined after every frame,
so every run is the same."""

import numpy as np
import pytest
from helpers.videos import shake_video

from rs_localizer.frontends.tracking import TrackingFeatureFrontend
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.tracking.sequence import SequenceLocalizer, SequenceSettings

pytestmark = pytest.mark.slow  # (renders a map and a 40-frame video)

FROZEN = range(15, 23)  # frames carrying frame 14's image, with their own stamps


@pytest.fixture(scope="module")
def video():
    return shake_video(40 / 30, 40, seed=0)


def _run(video, settings=None, **fe_args):
    fmap, frames, camera, _, _ = video
    fe = TrackingFeatureFrontend(fmap, **fe_args)
    seq = SequenceLocalizer(settings or SequenceSettings(), frontend=fe, frontend_name="features")
    out = []
    for k, f in enumerate(frames):
        image = frames[FROZEN[0] - 1].image if k in FROZEN else f.image
        res = seq.process_image(int(round(f.t_first * 1e9)), image, camera, "rgb8")
        fe.wait_refresh(60.0)  # (the refresh joins at a fixed frame: every run the same)
        est = res.estimate
        if est is not None and est.success:
            err = (
                rotation_angle_deg(est.orientation, f.orientation),
                100 * np.linalg.norm(est.position - f.position),
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


def test_collapsed_tracks_are_matched_whole(video):
    """With the frozen-image check off, the front end's own guard still keeps the first new
    image after the freeze from a pose on the few tracks that survived: the tracks collapsed
    below a quarter of the video's recent inliers, so the frame is matched whole."""
    got = _run(video, SequenceSettings(frozen_image_level=-1.0))
    after = [(k, e) for k, (_, e) in enumerate(got) if k > FROZEN[-1] and e is not None]
    wrong = [(k, e) for k, e in after if e[0] > 1.0 or e[1] > 5.0]
    assert wrong == [], wrong
    assert len(after) >= len(got) - FROZEN[-1] - 3, got[FROZEN[-1] :]
