"""Localizer.process_image: every camera's 640x480 images of the marker room (rendered at the
rig's motion composed with each camera's mounting, rs_localizer.sim.render.render_rig_frames)
through its own ArUco front end, the rig posed against the true trajectory; the rig's prediction
handed to each camera's front end (and none after a reset); dropped images counted; and which camera
is named when mountings disagree (two cameras: both; three: the wrong one)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rig import T0, Log, assert_balanced, mounts_of

from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.render import render_rig_frames, vga_rig
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_truth
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.video import SKIP_REASONS, Localizer, LocalizerSettings


@pytest.fixture(scope="module")
def rendered():
    cams = vga_rig(3)
    frames, motion = render_rig_frames(cams, 6, seed=3)
    return cams, frames, motion


def aruco_rig(cams, **kw):
    from rs_localizer.frontends import make_frontend

    rig = Localizer(LocalizerSettings(mounts_of(cams)), **kw)
    for c in cams:
        # (windows however much of the frame they cover: aruco_room is dense with markers)
        fe = make_frontend("aruco", "aruco_room", windowed=True, window_max_share=1.0)
        rig.set_frontend(c.name, fe, "aruco")
    return rig


def test_images_of_three_cameras_pose_the_rig_and_the_prediction_guides_each_front_end(rendered):
    """6 rig frames of 3 cameras: every rig frame posed from all three cameras within 0.1 deg
    and 3 mm of the truth; from the third rig frame on, each camera's prediction (the rig's
    prediction through its mounting) is within 1.5 deg and 4 cm of that camera's true pose
    (median 0.3 deg, 1.5 cm; a side camera is 35 deg from the rig's axes, the pose of the rig
    itself would be that far off) and its front end searched in windows around the predicted
    markers."""
    cams, frames, motion = rendered
    by = {c.name: c for c in cams}
    rig = aruco_rig(cams)
    outs, pred_err = [], []
    for f in frames:
        c = by[f.name]
        pred = rig.predict_camera(f.name, f.stamp_ns, c.camera)
        if pred is not None:
            t = (f.t_ref_ns - T0) * 1e-9
            R_rig, p_rig, _, _ = rig_truth(motion, t)
            R_true = (R_rig @ c.R_rig_cam).T  # world -> camera
            C_true = -R_true @ (p_rig + R_rig @ c.p_rig_cam)
            pred_err.append((rotation_angle_deg(pred.R, R_true), np.linalg.norm(pred.C - C_true)))
        outs += rig.process_image(f.name, f.stamp_ns, f.image, c.camera, "rgb8")
    outs += rig.close()
    assert len(outs) == 6 and all(o.success and len(o.cameras) == 3 for o in outs)
    for o in outs:
        R, p, _, _ = rig_truth(motion, (o.stamp_ns - T0) * 1e-9)
        assert rotation_angle_deg(o.estimate.pose.orientation, R) < 0.1
        assert np.linalg.norm(o.estimate.pose.position - p) < 0.003
        assert all(s.inliers > 60 for s in o.shares.values()), o.shares
    assert len(pred_err) >= 3 * 4, len(pred_err)  # (nothing predicts the first rig frame)
    e = np.array(pred_err)
    # (the first predictions carry one rig frame's twist through a shaking motion: ~1 deg)
    assert e[:, 0].max() < 1.5 and e[:, 1].max() < 0.04, e
    assert np.median(e[:, 0]) < 0.3 and np.median(e[:, 1]) < 0.015, e
    for c in cams:
        assert rig.frontend(c.name).counts["windowed"] >= 3, c.name
    assert_balanced(rig)


def test_dropped_images_are_counted_and_the_rig_runs_on(rendered):
    """A front end that raises on the right camera's images, the left camera's image sent
    twice and an image before its camera model: each counted under its reason
    (``frontend_error``, ``frozen_image``, ``no_camera_info``), the rig posed from the others,
    received = solved + failed + skipped + pending per camera and per rig frame."""
    cams, frames, _ = rendered
    by = {c.name: c for c in cams}

    class Broken:
        def process(self, image, camera=None, encoding="bgr8"):
            raise RuntimeError("no detector")

    log = Log()
    rig = aruco_rig(cams, log=log)
    rig.set_frontend("right", Broken())
    outs = []
    for f in frames:
        cam = None if (f.name == "front" and f.index == 0) else by[f.name].camera
        outs += rig.process_image(f.name, f.stamp_ns, f.image, cam, "rgb8")
        if f.name == "left" and f.index == 2:  # (the driver sends it again)
            outs += rig.process_image(f.name, f.stamp_ns + 33_000_000, f.image, cam, "rgb8")
    outs += rig.close()
    c = rig.counts
    assert c["right.skipped.frontend_error"] == 6 and c["right.solved"] == 0
    assert c["left.skipped.frozen_image"] == 1 and c["left.received"] == 7
    assert c["front.skipped.no_camera_info"] == 1
    assert {"frontend_error", "frozen_image", "no_camera_info"} <= set(SKIP_REASONS)
    assert sum(o.success for o in outs) >= 5
    assert any("no detector" in t for _, t in log.warnings)
    assert_balanced(rig)
    with pytest.raises(ValueError, match="not in the rig"):
        rig.drop("back", T0, None, "bad_image")
    with pytest.raises(ValueError, match="unknown skip reason"):
        rig.drop("left", T0, None, "cosmic_ray")
    with pytest.raises(ValueError, match="no front end"):
        Localizer(LocalizerSettings(mounts_of(cams))).process_image(
            "left", T0, frames[0].image, None
        )


def _run(frames, cams, mounts, log):
    by = {c.name: c.camera for c in cams}
    rig = Localizer(LocalizerSettings(mounts), log=log)
    outs = []
    for f in frames:
        outs += rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    return rig, outs + rig.close()


@pytest.mark.parametrize("wrong", ["front", "left"])
def test_two_cameras_that_disagree_are_both_named(wrong):
    """Two cameras, one mounting 3 deg off (the camera with more points, or the one with
    fewer): their disagreement alone cannot tell which mounting is wrong, so both cameras are
    named (state ``disagrees``, :meth:`camera_partner`), in one warning that says so; the
    right mountings: nobody is named."""
    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.4, num_points=150, seed=6)
    few = {"front": 150, "left": 60}  # (left sees fewer points)
    keep = []
    for f in frames:
        n = few[f.name]
        keep.append(
            type(f)(**{**f.__dict__, "uv": f.uv[:n], "xyz": f.xyz[:n], "inlier": f.inlier[:n]})
        )
    mounts = mounts_of(cams)
    bad = rotvec_to_matrix(np.radians([0.0, 3.0, 0.0]))
    mounts[wrong] = Mounting(bad @ mounts[wrong].R, mounts[wrong].c)
    log = Log()
    rig, outs = _run(keep, cams, mounts, log)
    assert outs[-1].disagreeing == ("front", "left")
    assert rig.camera_state("front") == rig.camera_state("left") == "disagrees"
    assert {rig.camera_partner("front"), rig.camera_partner("left")} == {"front", "left"}
    texts = [t for k, t in log.warnings if k.startswith("rig.disagrees.")]
    assert len(texts) == 1, texts
    assert "'left' and 'front' disagree" in texts[0] or "'front' and 'left' disagree" in texts[0]
    assert "cannot tell which" in texts[0], texts[0]
    _, good = _run(keep, cams, mounts_of(cams), Log())
    assert all(o.disagreeing == () for o in good)


def test_a_third_camera_names_the_wrong_mounting():
    """Three cameras, the left one 3 deg off: the two others agree, only left is named (no
    partner), its warning naming it alone."""
    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.4, num_points=150, seed=6)
    mounts = mounts_of(cams)
    bad = rotvec_to_matrix(np.radians([0.0, 3.0, 0.0]))
    mounts["left"] = Mounting(bad @ mounts["left"].R, mounts["left"].c)
    log = Log()
    rig, outs = _run(frames, cams, mounts, log)
    assert outs[-1].disagreeing == ("left",) and rig.camera_partner("left") is None
    assert rig.camera_state("front") == "running"
    texts = [t for k, t in log.warnings if k.startswith("rig.disagrees.")]
    assert len(texts) == 1 and "rig camera 'left' disagrees with the others" in texts[0]


def test_an_images_stamp_is_checked_once_and_its_reference_time_made_once(monkeypatch):
    """``process_image`` with a raw stamp: the stamp validated once and the frame's reference
    time computed once (its prediction, its rig frame and the front end's feedback share
    them); every rig frame at the earliest reference time of its frames, the simulation's
    (``t_ref_ns``, from the trajectory)."""
    import rs_localizer.camera as camera_mod
    import rs_localizer.tracking.sequence as sequence_mod
    import rs_localizer.tracking.video as rig_mod
    from rs_localizer.correspondences import Correspondences

    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=150, seed=6)
    checks, refs = [], []
    original = camera_mod.checked_stamp

    def counted(stamp_ns, what="frame"):
        if type(stamp_ns) is not camera_mod.Stamp:  # (one already checked is taken as is)
            checks.append(stamp_ns)
        return original(stamp_ns, what)

    for mod in (camera_mod, rig_mod, sequence_mod):
        monkeypatch.setattr(mod, "checked_stamp", counted)
    time_offset = camera_mod.CameraModel.time_offset

    def counted_offset(self, a, b):
        refs.append((a, b))
        return time_offset(self, a, b)

    monkeypatch.setattr(camera_mod.CameraModel, "time_offset", counted_offset)
    current = {}

    class Frontend:  # (the frame's own correspondences, whatever the image)
        def process(self, image, camera, encoding="bgr8", prediction=None):
            f = current["frame"]
            return Correspondences(f.uv, f.xyz)

    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    for c in cams:
        rig.set_frontend(c.name, Frontend(), "stub")
    by = {c.name: c.camera for c in cams}
    rng = np.random.default_rng(1)
    outs = []
    for f in frames:
        checks.clear()
        refs.clear()
        current["frame"] = f
        img = rng.integers(0, 255, (48, 64), np.uint8)
        outs += rig.process_image(f.name, f.stamp_ns, img, by[f.name], "mono8")
        assert checks == [f.stamp_ns] and len(refs) == 1, (f.name, checks, refs)
    outs += rig.close()
    assert outs and all(o.success for o in outs)
    t_ref = {(f.name, f.stamp_ns): f.t_ref_ns for f in frames}
    for o in outs:
        refs_in = [t_ref[(n, o.frames[n].stamp_ns)] for n in o.cameras]
        assert o.stamp_ns == min(refs_in)
    assert_balanced(rig)


def test_a_reset_forgets_the_last_rig_frame_posed():
    """Without tracking a camera's front end is handed the last rig frame posed carried to its
    frame; after ``reset()`` (a new video) the next frame, 11 ms on (well within ``max_gap``),
    is handed no prediction (``prediction=None``), and ``predict_camera`` has none either,
    as a camera's ``reset`` forgets its carried pose."""
    from rs_localizer.correspondences import Correspondences

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=150, seed=6)
    seen, current = [], {}

    class Frontend:  # (a video front end: the frame's own correspondences; notes predictions)
        def process(self, image, camera, encoding="bgr8", prediction=None):
            f = current["frame"]
            seen.append((f.name, prediction))
            return Correspondences(f.uv, f.xyz)

        def observe(self, stamp_ns, points2d, feedback):
            pass

        def pop_warning(self):
            return None

    rig = Localizer(LocalizerSettings(mounts_of(cams), tracking=None))
    for c in cams:
        rig.set_frontend(c.name, Frontend(), "stub")
    by = {c.name: c.camera for c in cams}
    rng = np.random.default_rng(1)

    def send(f):
        current["frame"] = f
        img = rng.integers(0, 255, (48, 64), np.uint8)
        return rig.process_image(f.name, f.stamp_ns, img, by[f.name], "mono8")

    half = len(frames) // 2
    outs = [o for f in frames[:half] for o in send(f)]
    assert sum(o.success for o in outs) >= 1
    assert seen[-1][1] is not None  # (before the reset: the last rig frame posed, carried)
    rig.reset()
    nxt = frames[half]
    assert (nxt.stamp_ns - frames[half - 1].stamp_ns) * 1e-9 < rig.settings.max_gap
    send(nxt)
    assert seen[-1] == (nxt.name, None)
    assert rig.predict_camera(nxt.name, nxt.stamp_ns, by[nxt.name]) is None


def test_a_cameras_rows_are_capped_to_max_points_and_counted_as_one_cameras():
    """``LocalizerSettings.max_points`` 40, the front camera's front end returning its 102-120 rows
    with 5 NaN rows added and a score per row: the NaN rows dropped first (counted
    ``front.points_dropped``), then the 40 highest-scored rows kept, as a single camera keeps
    them (:func:`usable_rows`): counted ``front.capped_clouds`` (every frame) and
    ``front.capped_points``, a warning naming the camera; the left camera's 30 rows are left
    as they are; the rig posed from at most 40 front rows a rig frame; the diagnostics show
    the counts under the camera's keys. Each front row's group (its row index given, here)
    stays with its row: the rig frame's rows are the given rows their groups name."""
    from dataclasses import replace

    from helpers.ros import rig_status

    from rs_localizer.correspondences import Correspondences
    from rs_localizer.tracking.localizer import usable_rows

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.3, num_points=120, seed=6)
    frames = [f if f.name == "front" else replace(f, uv=f.uv[:30], xyz=f.xyz[:30]) for f in frames]
    front = [f for f in frames if f.name == "front"]
    assert min(len(f.uv) for f in front) > 40
    rng = np.random.default_rng(2)
    current, observed, given = {}, {}, {}

    class Frontend:  # (the frame's own rows; the front camera's with NaN rows and scores)
        def process(self, image, camera, encoding="bgr8", prediction=None):
            f = current["frame"]
            if f.name != "front":
                return Correspondences(f.uv, f.xyz)
            uv = np.vstack([f.uv, np.full((5, 2), np.nan)])
            xyz = np.vstack([f.xyz, f.xyz[:5]])
            scores = rng.permutation(len(uv)).astype(float)
            current["given"] = (uv, xyz, scores)
            given[f.stamp_ns] = uv
            return Correspondences(uv, xyz, scores=scores, groups=np.arange(len(uv)))

        def observe(self, stamp_ns, points2d, feedback):
            observed[stamp_ns] = points2d

        def pop_warning(self):
            return None

    log = Log()
    rig = Localizer(LocalizerSettings(mounts_of(cams), max_points=40), log=log)
    for c in cams:
        rig.set_frontend(c.name, Frontend(), "stub")
    by = {c.name: c.camera for c in cams}
    expected, outs = {}, []
    for f in frames:
        current["frame"] = f
        img = rng.integers(0, 255, (48, 64), np.uint8)
        outs += rig.process_image(f.name, f.stamp_ns, img, by[f.name], "mono8")
        if f.name == "front":  # (what a single camera keeps of the same rows)
            uv, _, _ = usable_rows(*current["given"], 40, lambda *a: None, lambda *a: None)
            expected[f.stamp_ns] = uv
    outs += rig.close()
    c = rig.counts
    assert c["front.points_dropped"] == 5 * len(front)
    assert c["front.capped_clouds"] == len(front) == c["front.received"]
    assert c["front.capped_points"] == sum(len(f.uv) - 40 for f in front)
    assert c["left.capped_clouds"] == c["left.points_dropped"] == 0
    assert outs and all(o.success for o in outs)
    assert all(o.shares["front"].points <= 40 for o in outs if "front" in o.shares)
    posed = [o.frames["front"] for o in outs if "front" in o.frames]
    assert len(posed) == len(front)
    for fr in posed:  # (the kept rows' groups name the rows given: none of the NaN rows)
        uv = given[fr.stamp_ns]
        assert len(fr.groups) == 40 and fr.groups.max() < len(uv) - 5
        assert np.array_equal(uv[fr.groups], fr.points2d)
    assert all(o.frames["left"].groups is None for o in outs if "left" in o.frames)
    assert set(observed) >= set(expected)
    for stamp, uv in expected.items():
        assert np.array_equal(observed[stamp], uv) and len(uv) == 40
    capped = [t for k, t in log.warnings if k == "rig.capped.front"]
    assert capped and capped[0].startswith("rig camera 'front': cloud of ")
    assert capped[0].endswith("points capped to max_points 40")
    assert not any(k == "rig.capped.left" for k, _ in log.warnings)
    v = rig_status(rig)[2]
    assert v["front.capped_clouds"] == len(front) and v["left.capped_clouds"] == 0
    assert v["front.points_dropped"] == 5 * len(front)
    assert_balanced(rig)


def test_each_images_frame_and_only_it_is_observed_once_its_rig_frame_is_solved():
    """Two cameras with front ends, the left camera's frames alternately images
    (``process_image``) and clouds beside its front end (``add``): each image's frame is
    observed exactly once, when its rig frame is solved, whether an image, a cloud or the
    video's end (``close``) completed it, with its stamp, its rows and the rig's feedback for
    that camera (success and the camera's inliers); a cloud's frame is not observed (it is
    not the front end's), nor is an image skipped as ``out_of_order`` (one of the same stamp,
    its own rows: not those of the frame its rig frame holds)."""
    from rs_localizer.correspondences import Correspondences

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.3, num_points=80, seed=4)
    current, observed = {}, []

    class Frontend:  # (the frame's own correspondences; notes what it is told)
        def process(self, image, camera, encoding="bgr8", prediction=None):
            f, n = current["frame"], current.get("rows")
            return Correspondences(f.uv[:n], f.xyz[:n])

        def observe(self, stamp_ns, points2d, feedback):
            observed.append((current["names"][stamp_ns], stamp_ns, points2d, feedback))

        def pop_warning(self):
            return None

    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    for c in cams:
        rig.set_frontend(c.name, Frontend(), "stub")
    by = {c.name: c.camera for c in cams}
    rng = np.random.default_rng(5)
    current["names"], images, clouds, outs, by_image = {}, {}, set(), [], []
    for i, f in enumerate(frames):
        current["frame"], current["names"][f.stamp_ns] = f, f.name
        if f.name == "left" and i % 4 == 1:
            clouds.add(f.stamp_ns)
            outs += rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
            continue
        img = rng.integers(0, 255, (48, 64), np.uint8)
        by_image += rig.process_image(f.name, f.stamp_ns, img, by[f.name], "mono8")
        images[(f.name, f.stamp_ns)] = f.uv
        if i == 6:  # (another image of that stamp, 20 rows: skipped, never observed)
            current["rows"] = 20
            by_image += rig.process_image(f.name, f.stamp_ns, img + 1, by[f.name], "mono8")
            current["rows"] = None
    by_others = outs + rig.close()  # (rig frames a cloud or the video's end completed)
    outs = by_others + by_image
    assert rig.counts[f"{frames[6].name}.skipped.out_of_order"] == 1
    assert clouds and outs and all(o.success for o in outs)
    solved = {(n, o.frames[n].stamp_ns): (o, k) for o in outs for k, n in enumerate(o.cameras)}
    seen = [(n, t) for n, t, _, _ in observed]
    assert len(seen) == len(set(seen)) and set(seen) == set(images) & set(solved)
    assert {(n, o.frames[n].stamp_ns) for o in by_others for n in o.cameras} & set(seen)
    assert not {t for _, t in seen} & clouds
    for n, t, uv, feedback in observed:
        o, k = solved[(n, t)]
        assert uv is o.frames[n].points2d and np.array_equal(uv, images[(n, t)])
        assert feedback.success and feedback.num_inliers == o.estimate.num_inliers_per_view[k]
    assert_balanced(rig)


def test_an_images_frame_solved_by_a_jump_ahead_is_observed_once():
    """A rig frame still open when a camera's stamp jumps ahead (a time reset,
    ``stamp_jump``) is solved as it is and handed out with the frame that made the jump: its
    image's frame is observed by its front end exactly once, as every solved image's frame."""
    from rs_localizer.correspondences import Correspondences

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=80, seed=6)
    current, observed = {}, []

    class Frontend:  # (the frame's own correspondences; notes what it is told)
        def __init__(self, name):
            self.name = name

        def process(self, image, camera, encoding="bgr8", prediction=None):
            return Correspondences(current["frame"].uv, current["frame"].xyz)

        def observe(self, stamp_ns, points2d, feedback):
            observed.append((self.name, stamp_ns))

        def pop_warning(self):
            return None

    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    for c in cams:
        rig.set_frontend(c.name, Frontend(c.name), "stub")
    by = {c.name: c.camera for c in cams}
    img = np.zeros((48, 64), np.uint8)
    first = frames[0]
    other = next(g for g in frames if g.name != first.name)
    outs = []
    for k, (f, jump) in enumerate(((first, 0), (other, 5 * 10**9))):  # (the second jumps ahead)
        current["frame"] = f
        outs += rig.process_image(f.name, f.stamp_ns + jump, img + k, by[f.name], "mono8")
    assert rig.counts["rig.time_resets"] == 1
    assert [o.cameras for o in outs] == [(first.name,)] and outs[0].success
    assert observed == [(first.name, first.stamp_ns)]
