"""A map that cannot fit the place (mirrored: z -> -z) gives no pose, and the user is told
the map is the likely cause: ``frames_failed_with_matches``, ``map_fit_doubtful`` (the node's
diagnostics keys) and the warning ``rs-localizer replay`` prints; the right map raises no
doubt."""

from __future__ import annotations

import yaml

from rs_localizer.ros.bags.replay import replay


def _mirrored(src, dst):
    m = yaml.safe_load(src.read_text())
    for marker in m["markers"]:
        marker["corners"] = [[x, y, -z] for x, y, z in marker["corners"]]
    dst.write_text(yaml.safe_dump(m))
    return dst


def test_a_mirrored_marker_map_is_named(sample_images_bag, tmp_path):
    mirrored = _mirrored(sample_images_bag / "markers.yaml", tmp_path / "mirrored.yaml")
    params = {"frontend": "aruco", "frontend_map": str(mirrored)}
    res = replay(sample_images_bag, params=params, progress=None)
    assert res.solved == 0 and len(res.rows) >= 10
    assert res.counts["frames_failed_with_matches"] >= 10
    assert res.counts["map_fit_doubtful"] == 1
    text = [n for n in res.notes if "does the map fit this place?" in n]
    assert len(text) == 1 and "mirrored" in text[0] and "another room" in text[0], res.notes
    right = {"frontend": "aruco", "frontend_map": str(sample_images_bag / "markers.yaml")}
    res = replay(sample_images_bag, params=right, progress=None)
    assert res.solved == len(res.rows) and not res.counts.get("map_fit_doubtful")
    assert not any("does the map fit" in n for n in res.notes)


def _mirrored_rig_bag(tmp_path, mirror: bool):
    from dataclasses import replace as dc_replace

    import numpy as np

    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.5, num_points=80, seed=2)
    if mirror:
        frames = [dc_replace(f, xyz=f.xyz * np.array([1.0, 1.0, -1.0])) for f in frames]
    name = "mirrored" if mirror else "right"
    return write_rig_bag(tmp_path / name, frames, cams, traj), cams, frames


def test_a_rig_with_a_mirrored_map_is_told_as_a_camera_is(tmp_path, capsys):
    """A rig whose correspondences' map is mirrored (z -> -z): no rig frame posed, and
    ``replay`` warns that the map likely does not fit, as for one camera (the rig frames'
    rows together); the true map raises no doubt. The rig node's diagnostics count the same
    (``rig_frames_failed_with_matches``, ``map_fit_doubtful``) and the status message says
    it (the rig's map-fit check run on the rig frames, as the node's worker runs it)."""
    from collections import Counter

    from helpers.ros import rig_status

    from rs_localizer.cli import main
    from rs_localizer.ros.diagnostics import OK, RigInputs
    from rs_localizer.ros.pipeline import MapFitCheck

    bag, _, _ = _mirrored_rig_bag(tmp_path, True)
    res = replay(bag, progress=None)
    assert res.solved == 0 and len(res.outputs) >= 10
    assert len(res.notes) == 1 and "does the map fit this place?" in res.notes[0], res.notes
    assert "rig frames with 20 or more correspondences" in res.notes[0], res.notes
    assert main(["replay", str(bag), "--quiet"]) == 1
    assert "warning: " + res.notes[0] in capsys.readouterr().err
    # the node's diagnostics: its worker's check over the rig frames the rig hands out
    from rs_localizer.ros.bags.bag_frames import read_rig_frames, rig_bag_config
    from rs_localizer.ros.camera_input import to_rig
    from rs_localizer.tracking.video import Localizer

    rig = Localizer(rig_bag_config(bag)[2].settings)
    outs = [o for item in read_rig_frames(bag).items for o in to_rig(rig, item)]
    outs += rig.close()
    fit, counts = MapFitCheck("rig frames"), Counter()
    for o in outs:
        refused, _ = fit.update(sum(len(f.points2d) for f in o.frames.values()), o.estimate)
        counts["rig_frames_failed_with_matches"] += bool(refused)
    counts["map_fit_doubtful"] = int(fit.doubtful)
    level, message, v = rig_status(rig, (), RigInputs(counts=counts))
    assert v["rig_frames_failed_with_matches"] == len(outs) == len(res.outputs)
    assert v["map_fit_doubtful"] == "true" and level != OK
    assert "does the map fit this place? mirrored or another room?" in message, message
    right, _, _ = _mirrored_rig_bag(tmp_path, False)
    res = replay(right, progress=None)
    assert res.solved == len(res.outputs) and res.notes == []


def test_a_rig_frame_is_checked_against_the_map_in_its_frame_step():
    """The rig node's map-fit check runs in the frame step that completes the rig frame (under
    the worker's lock, with the frame's count), as the camera alone's does: a diagnostics
    snapshot taken between the frame step and its publication sees the rig frame refused
    for its geometry counted (``rig_frames_failed_with_matches``, ``map_fit_doubtful``)."""
    from types import SimpleNamespace

    from rs_localizer.ros.camera_input import CameraCounts, FrameStep
    from rs_localizer.ros.mode import CameraFrameResult, LocalizerMode
    from rs_localizer.ros.pipeline import MAP_FIT_MIN_POINTS, MAP_FIT_WINDOW, MapFitCheck

    mode = LocalizerMode.__new__(LocalizerMode)  # (a rig's, its node a stand-in)
    mode.alone, mode._counts, mode._map_fit = False, CameraCounts(), MapFitCheck("rig frames")
    warned = []
    mode.node = SimpleNamespace(inputs={"a": SimpleNamespace(newest=object())}, camera_viz={},
                                republish=False, warn=lambda k, t: warned.append(k))  # fmt: skip
    refused = SimpleNamespace(success=False, failure="cheirality")
    out = SimpleNamespace(estimate=refused, num_points=MAP_FIT_MIN_POINTS, gyro_seconds=0.0,
                          success=False)  # fmt: skip
    n = MAP_FIT_WINDOW // 2
    for _ in range(n):
        res = CameraFrameResult("a")
        mode._entered("a", "cloud", FrameStep(object(), [out], 0.0), 0.0, res)
    assert mode._counts.get("rig_frames_failed_with_matches") == n
    assert mode._counts.get("map_fit_doubtful") == 1 and warned == ["map_fit"]
