"""A marker video through the Localizer: the front end's groups (each corner's marker id,
Correspondences.groups) reach the estimator, a camera's and a rig's, tracked or not. Rendered
640x480 images of the marker room (rs_localizer.sim.render.render_rig_frames) through the ArUco
front end; the covariance of each frame checked against the estimator run on the same frame's
rows with groups made from the front end's correspondence ids (``4 * marker_id + corner``) and
without them: the groups change the covariance only, never the estimate."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rig import mounts_of

from rs_localizer.correspondences import Correspondences
from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.estimation.implementation import COMPILED, NUMPY
from rs_localizer.estimation.rig import estimate_rig_pose
from rs_localizer.estimation.view import View
from rs_localizer.frames import Mounting
from rs_localizer.frontends import make_frontend
from rs_localizer.sim.render import render_rig_frames, vga_rig
from rs_localizer.tracking.tracker import TrackerOptions
from rs_localizer.tracking.video import Localizer, LocalizerSettings

IDENTITY = Mounting(np.eye(3), np.zeros(3))


class Stripped:
    """The ArUco front end with its correspondences' groups left out."""

    def __init__(self):
        self.fe = make_frontend("aruco", "aruco_room")

    def process(self, image, camera=None, encoding="bgr8", prediction=None):
        c = self.fe.process(image, camera, encoding, prediction)
        return Correspondences(c.points2d, c.points, c.ids, c.scores)

    def observe(self, stamp_ns, points2d, feedback):
        self.fe.observe(stamp_ns, points2d, feedback)

    def pop_warning(self):
        return self.fe.pop_warning()


@pytest.fixture(scope="module")
def one_camera():
    (c,) = vga_rig(1)
    frames, _ = render_rig_frames([c], 6, seed=3)
    return c, frames


def _run(c, frames, frontend, tracking):
    """``(localizer, outputs, the front end's correspondences of each frame)`` of a camera
    alone (a rig of one) on ``frames``."""
    rig = Localizer(LocalizerSettings({c.name: IDENTITY}, tracking=tracking))
    rig.set_frontend(c.name, frontend, "aruco")
    outs, found = [], []
    for f in frames:
        (out,) = rig.process_image(c.name, f.stamp_ns, f.image, c.camera, "rgb8")
        outs.append(out)
        found.append(rig.last_correspondences(c.name))
        # (the front end's rows all given: none capped or dropped)
        assert len(found[-1]) == len(out.frames[c.name].points2d)
    return rig, outs, found


def _impl(out) -> str:
    return COMPILED if out.compiled else NUMPY


def test_a_camera_s_covariance_is_the_estimators_with_the_markers_groups(one_camera):
    """Without tracking every frame is solved cold: its covariance (the camera's estimate and
    the rig of one's, what the node publishes) is that of ``estimate_rs_pose`` on the frame's
    rows with ``groups = ids // 4`` (its markers), which differs from the white-noise one on
    frames whose residuals tell a shared shift (3 of these 6); with the groups stripped from
    the front end's rows it is the white-noise one. Poses the same either way."""
    c, frames = one_camera
    rig, outs, found = _run(c, frames, make_frontend("aruco", "aruco_room"), None)
    _, plain, _ = _run(c, frames, Stripped(), None)
    s = rig.settings
    differ = 0
    for out, bare, f in zip(outs, plain, found, strict=True):
        assert out.success and out.compiled  # (the NumPy path ignores groups)
        fr = out.frames[c.name]
        groups = np.asarray(f.ids) // 4
        np.testing.assert_array_equal(fr.groups, groups)
        args = (fr.points2d, fr.points3d, fr.camera, s.solver, s.options)
        kw = dict(scores=fr.scores, implementation=_impl(out))
        grouped = estimate_rs_pose(*args, groups=groups, **kw)
        white = estimate_rs_pose(*args, **kw)
        for est in (out.camera_estimate, out.estimate):
            np.testing.assert_array_equal(est.covariance, grouped.covariance)
        np.testing.assert_array_equal(bare.camera_estimate.covariance, white.covariance)
        assert bare.frames[c.name].groups is None
        np.testing.assert_array_equal(
            out.camera_estimate.pose.position, bare.camera_estimate.pose.position
        )
        np.testing.assert_array_equal(out.camera_estimate.model.R, bare.camera_estimate.model.R)
        differ += not np.allclose(grouped.covariance, white.covariance, rtol=1e-3, atol=0)
    assert differ >= 2, differ  # (else the check above could not tell grouped from white)


def test_a_tracked_camera_s_frames_take_their_groups(one_camera, monkeypatch):
    """With tracking (the tracker path's solves, ``FrameViews``): every solve of every frame,
    cold and tracked, is given the frame's markers as its groups (``ids // 4``), none with the
    groups stripped; the first frame (cold) posed the same either way. Later frames may move
    by a few micrometres: their motion prior comes from the track's fused twist, whose filter
    weighs each frame by its covariance."""
    from rs_localizer.tracking import tracker

    calls = []

    def recorded(*args, **kw):
        calls.append(kw.get("groups"))
        return estimate_rs_pose(*args, **kw)

    monkeypatch.setattr(tracker, "estimate_rs_pose", recorded)
    c, frames = one_camera
    runs = {}
    for name, fe in (("grouped", make_frontend("aruco", "aruco_room")), ("bare", Stripped())):
        calls.clear()
        rig = Localizer(LocalizerSettings({c.name: IDENTITY}, tracking=TrackerOptions()))
        rig.set_frontend(c.name, fe, "aruco")
        runs[name] = []
        for f in frames:
            n = len(calls)
            (out,) = rig.process_image(c.name, f.stamp_ns, f.image, c.camera, "rgb8")
            ids = rig.last_correspondences(c.name).ids
            runs[name].append((out, calls[n:], np.asarray(ids) // 4))
    paths = [out.path for out, _, _ in runs["grouped"]]
    assert paths[0] == "cold" and paths.count("tracked") >= 4, paths
    for out, given, groups in runs["grouped"]:
        assert out.success and out.compiled and given
        assert all(g is not None and np.array_equal(g, groups) for g in given)
    assert all(g is None for _, given, _ in runs["bare"] for g in given)
    (a, _, _), (b, _, _) = runs["grouped"][0], runs["bare"][0]
    np.testing.assert_array_equal(a.camera_estimate.pose.position, b.camera_estimate.pose.position)
    for (a, _, _), (b, _, _) in zip(runs["grouped"], runs["bare"], strict=True):
        assert a.path == b.path
        np.testing.assert_allclose(a.camera_estimate.pose.position,
                                   b.camera_estimate.pose.position, rtol=0, atol=1e-4)  # fmt: skip


def test_a_rig_s_covariance_is_the_rig_estimators_with_each_camera_s_markers():
    """Three cameras, no tracking: each rig frame's covariance is that of
    ``estimate_rig_pose`` on the rig frame's views with each view's ``groups = ids // 4``
    (the rig frame's cold solve: every camera also posed alone), which differs from the one
    without groups on rig frames whose residuals tell a shared shift (4 of these 6)."""
    cams = vga_rig(3)
    frames, _ = render_rig_frames(cams, 6, seed=3)
    mounts = mounts_of(cams)
    rig = Localizer(LocalizerSettings(mounts, tracking=None))
    for cam in cams:
        rig.set_frontend(cam.name, make_frontend("aruco", "aruco_room"), "aruco")
    by = {cam.name: cam.camera for cam in cams}
    ids, outs = {}, []
    for f in frames:
        outs += rig.process_image(f.name, f.stamp_ns, f.image, by[f.name], "rgb8")
        ids[(f.name, f.stamp_ns)] = rig.last_correspondences(f.name).ids
    outs += rig.close()
    assert len(outs) == 6 and all(o.success and len(o.cameras) == 3 for o in outs)
    differ = 0
    for out in outs:
        views, bare = [], []
        for n in out.cameras:
            fr = out.frames[n]
            g = np.asarray(ids[(n, fr.stamp_ns)]) // 4
            np.testing.assert_array_equal(fr.groups, g)
            v = (fr.points2d, fr.points3d, fr.camera, mounts[n], out.stamp_offsets[n])
            views.append(View(*v, groups=g))
            bare.append(View(*v))
        kw = dict(verify_cameras=True, implementation=_impl(out))
        grouped = estimate_rig_pose(views, rig.settings.options, **kw)
        white = estimate_rig_pose(bare, rig.settings.options, **kw)
        np.testing.assert_array_equal(out.estimate.covariance, grouped.covariance)
        np.testing.assert_array_equal(out.estimate.pose.position, white.pose.position)
        differ += not np.allclose(grouped.covariance, white.covariance, rtol=1e-3, atol=0)
    assert differ >= 2, differ  # (else the check above could not tell grouped from white)
