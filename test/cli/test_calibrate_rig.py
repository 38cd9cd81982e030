"""``rs-localizer calibrate-rig``: every camera's mounting from a rig bag of a known map, against
the bag's true mountings, written as the node's rig parameters."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("rosbags")


def _mount(m):
    from rs_localizer.frames import Mounting
    from rs_localizer.ros import conversions as cv

    return Mounting.from_pose(cv.matrix_from_quaternion(m[3:]), m[:3])


@pytest.fixture(scope="module")
def rig_bag(tmp_path_factory):
    from rs_localizer.cli import main

    bag = tmp_path_factory.mktemp("calib") / "rig"
    assert main(["make-bag", str(bag), "--rig", "3", "--frames", "40", "--points", "300",
                 "--quiet"]) == 0  # fmt: skip
    return bag


def test_mountings_match_the_truth_within_their_stated_std(rig_bag, tmp_path, capsys):
    """3 unsynchronized cameras (stamps 4 and 8 ms apart), 40 rig frames of 300 points, 20 %
    outliers: each mounting within 0.05 deg and 2 mm of the truth and within 3 of its stated
    standard deviations; the parameter file written is the node's (read back, every camera
    with a mounting and its timing)."""
    from rs_localizer.cli import main
    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros.param_files import read_params_file

    out = tmp_path / "rig.yaml"
    capsys.readouterr()
    assert main(["calibrate-rig", str(rig_bag), "-o", str(out), "--json"]) == 0
    printed = capsys.readouterr()
    report = json.loads(printed.out)
    assert "WARNING" not in printed.err  # (40 rig frames: the std stands)
    assert report["reference"] == "front" and report["rig_frame"] == "base_link"
    truth = {
        c["name"]: c for c in json.loads((rig_bag / "sequence.json").read_text())["rig"]["cameras"]
    }
    params = read_params_file(out)
    assert params["rig.cameras"] == ["front", "left", "right"]
    for name, c in truth.items():
        got = report["cameras"][name]
        assert params[f"rig.{name}.mounting"] == pytest.approx(got["mounting"])
        assert params[f"rig.{name}.line_delay"] == pytest.approx(c["line_delay"])
        assert params[f"rig.{name}.direction"] == c["direction"]
        t, e = _mount(c["mounting"]), _mount(got["mounting"])
        deg = rotation_angle_deg(t.R, e.R)
        mm = 1e3 * np.linalg.norm(t.position - e.position)
        if name == "front":  # (the reference keeps its mounting: the rig frame is base_link)
            assert deg < 1e-6 and mm < 1e-6
            continue
        assert got["frames"] >= 30
        assert deg < 0.05 and mm < 2.0, (name, deg, mm)
        assert deg < 3 * got["std_deg"] and mm < 3 * got["std_mm"], (name, deg, mm, got)
        # the covariance written (x, y, z, rot x, rot y, rot z) is the printed std's
        C = np.array(params[f"rig.{name}.mounting_covariance"]).reshape(6, 6)
        assert np.allclose(C, np.array(got["mounting_covariance"]).reshape(6, 6))
        assert 1e3 * np.sqrt(np.trace(C[:3, :3])) == pytest.approx(got["std_mm"], rel=1e-4)
        assert np.degrees(np.sqrt(np.trace(C[3:, 3:]))) == pytest.approx(got["std_deg"], rel=1e-4)
    # the node's configuration reads it back as each mounting's covariance
    from rs_localizer.ros.bags.bag_frames import rig_parameter_values
    from rs_localizer.ros.config import build_config

    cfg = build_config(*rig_parameter_values(None, [out]))
    covs = {c.name: c.mount.covariance for c in cfg.cameras}
    assert covs["front"] is None and covs["left"].shape == covs["right"].shape == (6, 6)


def test_the_reference_cameras_optical_frame_and_bad_input(rig_bag, tmp_path, capsys):
    """--optical-frame: the reference camera at the identity and the others relative to it (as
    the true mountings relative to it), the file's base_frame that camera's optical frame and
    how to move it to the robot's base printed; an unknown reference camera is a user
    error."""
    from rs_localizer.cli import main
    from rs_localizer.geometry import rotation_angle_deg

    capsys.readouterr()
    out = tmp_path / "rig.yaml"
    args = ["calibrate-rig", str(rig_bag), "--json", "--optical-frame", "--reference", "left",
            "-o", str(out)]  # fmt: skip
    assert main(args) == 0
    cap = capsys.readouterr()
    report = json.loads(cap.out)
    truth = {c["name"]: _mount(c["mounting"]) for c in
             json.loads((rig_bag / "sequence.json").read_text())["rig"]["cameras"]}  # fmt: skip
    # the rig frame is named: the left camera's optical frame (its camera_info's frame_id),
    # and how to move it to the robot's base is printed
    from rs_localizer.ros.param_files import read_params_file

    assert report["rig_frame"] == "left_optical_frame"
    assert read_params_file(out)["base_frame"] == "left_optical_frame"
    assert "tf2_echo base_link left_optical_frame" in cap.err
    assert "rig.left.mounting" in cap.err
    ref = _mount(report["cameras"]["left"]["mounting"])
    assert np.allclose(ref.R, np.eye(3)) and np.allclose(ref.c, 0.0)
    for name in ("front", "right"):
        e = _mount(report["cameras"][name]["mounting"])
        # the truth relative to the left camera: x_cam = R_c R_left^T (x_left - c_left) + c_c
        R_rel = truth[name].R @ truth["left"].R.T
        c_rel = truth[name].c - R_rel @ truth["left"].c
        assert rotation_angle_deg(e.R, R_rel) < 0.05
        assert np.linalg.norm(e.c - c_rel) < 0.002
    assert main(["calibrate-rig", str(rig_bag), "--reference", "nope"]) == 2
    assert "nope" in capsys.readouterr().err


def test_the_parameters_mountings_are_checked_against_the_calibrated_ones(
    rig_bag, tmp_path, capsys
):
    """Each camera's mounting in the parameters (the bag's true ones) is compared with the
    calibrated one: within 3 std, no warning; a parameter file that turns the left camera by
    5 deg and moves it 10 mm: 5 deg / 10 mm off reported and warned (printed and in the file), in
    base_frame and in the reference camera's optical frame alike."""
    from rs_localizer.cli import main
    from rs_localizer.geometry import rotvec_to_matrix
    from rs_localizer.ros import conversions as cv

    truth = {c["name"]: c["mounting"] for c in
             json.loads((rig_bag / "sequence.json").read_text())["rig"]["cameras"]}  # fmt: skip
    capsys.readouterr()
    assert main(["calibrate-rig", str(rig_bag), "--json", "-o", str(tmp_path / "a.yaml")]) == 0
    cap = capsys.readouterr()
    report = json.loads(cap.out)["cameras"]
    assert "parameters_off_deg" not in report["front"]  # (the reference)
    for name in ("left", "right"):
        got = report[name]
        assert got["parameters_off_deg"] < 3 * got["std_deg"], got
        assert got["parameters_off_mm"] < 3 * got["std_mm"], got
        assert f"{name}: the parameters' mounting is" in cap.err
    assert "WARNING" not in cap.err

    m = truth["left"]
    R = rotvec_to_matrix(np.radians([0.0, 0.0, 5.0])) @ cv.matrix_from_quaternion(m[3:])
    wrong = [m[0], m[1] + 0.010, m[2], *cv.quaternion_from_matrix(R)]
    params = tmp_path / "wrong.yaml"
    params.write_text(
        "/**/rs_localizer:\n  ros__parameters:\n    rig:\n      left:\n"
        f"        mounting: {[float(x) for x in wrong]}\n"
    )
    for extra in ([], ["--optical-frame"]):
        out = tmp_path / "b.yaml"
        args = ["calibrate-rig", str(rig_bag), "--json", "--params-file", str(params), "-o",
                str(out), *extra]  # fmt: skip
        assert main(args) == 0
        cap = capsys.readouterr()
        got = json.loads(cap.out)["cameras"]
        assert got["left"]["parameters_off_deg"] == pytest.approx(5.0, abs=0.05), extra
        assert got["left"]["parameters_off_mm"] == pytest.approx(10.0, abs=2.0), extra
        assert got["right"]["parameters_off_deg"] < 3 * got["right"]["std_deg"], extra
        warning = "WARNING: left: the mounting in the parameters is off by "
        assert warning in cap.err and f"# {warning}" in out.read_text(), extra
        assert "WARNING: right" not in cap.err
    # the reference camera not placed by the parameters: its optical frame and theirs are
    # unrelated, nothing is compared
    from rs_localizer.cli.calibrate_rig import relative_to
    from rs_localizer.ros.config import rig_mounting

    assert relative_to({"left": rig_mounting("left", truth["left"])}, "front") == {}
    # a mounting the node would refuse is refused here too, by the node's own reading
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**/rs_localizer:\n  ros__parameters:\n    rig:\n      left:\n"
                   "        mounting: [0.0, 0.1, 0.2]\n")  # fmt: skip
    capsys.readouterr()
    assert main(["calibrate-rig", str(rig_bag), "--params-file", str(bad)]) == 2
    assert "rig.left.mounting must be 7 finite numbers" in capsys.readouterr().err


def test_a_ring_of_cameras_and_a_camera_not_connected(tmp_path, capsys):
    """A rig bag of a ring of four cameras (front, left, back, right) where only neighbours
    see the map at the same time (front and back never): every mounting within 0.3 deg and
    5 mm of the truth and 3 of its std. With the front camera's frames only where no other
    camera sees the map, it is refused by name (one line, exit 2)."""
    from rs_localizer.cli import main
    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    ring = ("front", "left", "back", "right")
    cams = default_rig(4)
    frames, _, traj = generate_rig_video(cams, duration=1.6, num_points=150, seed=1)
    t0 = 1_700_000_000_000_000_000

    def quarter(f):
        return min(int(4 * (f.stamp_ns - t0) * 1e-9 / 1.6), 3)

    seen = [f for f in frames if f.name in (ring[quarter(f)], ring[(quarter(f) + 1) % 4])]
    bag = write_rig_bag(tmp_path / "ring", seen, cams, traj)
    capsys.readouterr()
    assert main(["calibrate-rig", str(bag), "--json", "-o", str(tmp_path / "r.yaml")]) == 0
    report = json.loads(capsys.readouterr().out)["cameras"]
    for c in cams[1:]:
        t, e = _mount([*c.p_rig_cam, *_quat(c.R_rig_cam)]), _mount(report[c.name]["mounting"])
        deg = rotation_angle_deg(t.R, e.R)
        mm = 1e3 * np.linalg.norm(t.position - e.position)
        got = report[c.name]
        assert deg < 0.3 and mm < 5.0, (c.name, deg, mm)
        assert deg < 3 * got["std_deg"] and mm < 3 * got["std_mm"], (c.name, deg, mm, got)
    # front alone in the first quarter (left's frames there left out), then nowhere
    alone = [f for f in seen if quarter(f) in (1, 2) or (quarter(f) == 0 and f.name == "front")]
    bag = write_rig_bag(tmp_path / "apart", alone, cams, traj)
    assert main(["calibrate-rig", str(bag), "--reference", "left"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "['front']" in err[0] and "'left'" in err[0], err
    n_front = sum(f.name == "front" for f in alone)
    assert f"front: {n_front} frames read, {n_front} with 20 correspondences" in err[0], err
    # a camera whose frames hold no correspondence (it never sees the map): said so
    blind = [replace(f, uv=f.uv[:0], xyz=f.xyz[:0]) if f.name == "back" else f for f in seen]
    bag = write_rig_bag(tmp_path / "blind", blind, cams, traj)
    assert main(["calibrate-rig", str(bag), "--reference", "left"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    n_back = sum(f.name == "back" for f in blind)
    assert len(err) == 1 and "['back']" in err[0], err
    assert f"back: {n_back} frames read, none with 20 correspondences or more" in err[0], err
    # a camera of the parameters with no frame in the bag at all: said so, by name
    bag = write_rig_bag(tmp_path / "no_back", [f for f in seen if f.name != "back"], cams, traj)
    assert main(["calibrate-rig", str(bag), "--reference", "left"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "['back']" in err[0] and "back: no frame in the bag" in err[0], err


def _quat(R):
    from rs_localizer.ros import conversions as cv

    return cv.quaternion_from_matrix(np.asarray(R))


def test_a_short_video_is_warned_about(tmp_path, capsys):
    """3 rig frames: the std is the scatter of 3 frames (on the simulated rig, 2-5 frames
    gave errors up to 2.8x the stated std, 10-20 frames up to 1.5x: docs/rig_node.md): each
    camera's mounting is written with a warning naming the frames and the factor."""
    from rs_localizer.cli import main
    from rs_localizer.cli.calibrate_rig import MIN_RIG_FRAMES

    bag = tmp_path / "short"
    assert main(["make-bag", str(bag), "--rig", "3", "--frames", "3", "--points", "300",
                 "--quiet"]) == 0  # fmt: skip
    capsys.readouterr()
    out = tmp_path / "rig.yaml"
    assert main(["calibrate-rig", str(bag), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    for name in ("left", "right"):
        assert f"WARNING: {name}: only 3 rig frames" in err, err
    assert "up to 4.4x the std" in err and f"record {MIN_RIG_FRAMES} or more" in err
    assert "# WARNING: left: only 3 rig frames" in out.read_text()


def test_cameras_that_do_not_expose_together_are_noted():
    """A camera whose mounting was kept from the corners' refinement for the time offset the
    video shows: a note with that offset naming --time-offsets; none without one (a refined
    mounting's note says how its std was scaled; one left out of the others' refinement says
    so)."""
    from rs_localizer.calibration.mountings import MountingEstimate
    from rs_localizer.cli.calibrate_rig import _camera_notes
    from rs_localizer.frames import Mounting

    e = MountingEstimate("left", Mounting(np.eye(3), np.zeros(3)), 50, 0, 0.1, 1.0, 0.2, 2.0)
    notes, _ = _camera_notes("left", replace(e, exposure_offset=-0.0088), None)
    assert any(
        "do not seem to expose together" in n and "-8.8 ms" in n and "--time-offsets" in n
        for n in notes
    ), notes
    notes, _ = _camera_notes("left", replace(e, corners_refined=True, corner_misfit=4.0), None)
    assert not any("expose together" in n for n in notes), notes
    # a refined mounting's std: the corners' solve's plus what the two estimates disagree by
    assert any("refined on the corners" in n and "misfit 4.0" in n for n in notes), notes
    notes, _ = _camera_notes("left", e, None)
    assert not any("refined on the corners" in n for n in notes), notes
    # the others refined on the corners, this camera not (no corner of it in their solve)
    notes, _ = _camera_notes("left", replace(e, exposure_offset=-0.0088), None, True)
    assert any("not refined on the corners" in n and "pose-level" in n for n in notes), notes
    assert not any("--time-offsets" in n for n in notes), notes
    # a poorly fixed offset: refined on the corners (the rig moved), the offset changes over
    # the video; estimated at the pose level alone, the rig did not move enough to show it
    timed = replace(e, time_offset=-0.006, time_offset_std=0.012, exposure_offset=-0.009)
    notes, _ = _camera_notes("left", replace(timed, corners_refined=True), None)
    assert any("changes over the video" in n and "12 ms" in n for n in notes), notes
    assert not any("hardly moves" in n for n in notes), notes
    notes, _ = _camera_notes("left", timed, None)
    assert any("hardly moves" in n for n in notes), notes
    assert not any("changes over the video" in n for n in notes), notes


def test_clouds_are_read_as_the_rig_node_reads_them(tmp_path, capsys):
    """The left camera's clouds each hold a row with a NaN and more rows than ``max_points``
    (the front camera's fewer): calibrate-rig's frames of the left camera hold at most
    ``max_points`` rows, all finite and all rows of the cloud; the front camera's every row.
    The rows dropped and capped are counted per camera, printed for the left camera alone
    and given for each in the JSON; the mountings are still calibrated."""
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_frames import read_rig_frames
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.5, num_points=200, seed=5)
    cap = 60
    rows = {}  # (camera, stamp ns) -> the cloud's finite rows as (u, v, x, y, z)
    for f in frames:
        if f.name == "left":
            f.uv = f.uv.copy()
            f.uv[3, 0] = np.nan
        else:  # (front: fewer rows than the cap)
            f.uv, f.xyz = f.uv[: cap - 10], f.xyz[: cap - 10]
        ok = np.isfinite(f.uv).all(axis=1)
        rows[(f.name, f.stamp_ns)] = np.hstack([f.uv[ok], f.xyz[ok]])
    n_left = sum(f.name == "left" for f in frames)
    assert min(len(r) for (c, _), r in rows.items() if c == "left") > cap
    bag = write_rig_bag(tmp_path / "rig", frames, cams, traj)
    params = tmp_path / "cap.yaml"
    params.write_text(f"/**/rs_localizer:\n  ros__parameters:\n    max_points: {cap}\n")

    read = read_rig_frames(bag, [params])
    assert len(read.frames) == len(frames)
    for f in read.frames:
        want = rows[(f.camera_name, f.stamp_ns)]
        got = np.hstack([f.points2d, f.points3d])
        assert np.isfinite(got).all()
        if f.camera_name == "left":
            assert len(got) == cap
            assert all(np.isclose(want, g, atol=1e-4).all(axis=1).any() for g in got)
        else:
            assert np.allclose(got, want, atol=1e-4)
    capped_points = sum(len(r) - cap for (c, _), r in rows.items() if c == "left")
    assert read.counts == {
        "front": {"points_dropped": 0, "capped_clouds": 0, "capped_points": 0, "bad_input": 0},
        "left": {"points_dropped": n_left, "capped_clouds": n_left, "capped_points": capped_points,
                 "bad_input": 0},
    }  # fmt: skip

    capsys.readouterr()
    args = ["calibrate-rig", str(bag), "--params-file", str(params), "--json", "-o",
            str(tmp_path / "out.yaml")]  # fmt: skip
    assert main(args) == 0
    cap_out = capsys.readouterr()
    report = json.loads(cap_out.out)["cameras"]
    line = (
        f"left: points_dropped {n_left}, capped_clouds {n_left}, capped_points "
        f"{capped_points}, bad_input 0 (rows with a NaN or inf dropped; clouds of more than "
        f"max_points {cap} rows capped to it; clouds not read: no u, v, x, y, z fields "
        "(bad_input), a header stamp out of range (bad_stamp))"
    )
    assert line in cap_out.err and "front: points_dropped" not in cap_out.err
    assert f"# {line}" in (tmp_path / "out.yaml").read_text()
    for c in ("front", "left"):
        assert {k: report[c][k] for k in read.counts[c]} == read.counts[c]
    assert report["left"]["frames"] >= 5 and np.isfinite(report["left"]["std_deg"])


def test_a_cameras_time_offset_is_used_and_kept_or_estimated(rig_bag, tmp_path, capsys):
    """A camera's ``rig.<camera>.time_offset`` given in a parameter file puts its frames on the
    rig's clock for the calibration and is written into the calibrated parameter file; with
    ``--time-offsets`` every camera's is estimated instead: the bag's stamps are the true
    capture times, so a wrongly given 4 ms is found to be 0 (within 0.5 ms and 4 std)."""
    from rs_localizer.cli import main
    from rs_localizer.ros.param_files import read_params_file

    extra = tmp_path / "offset.yaml"
    extra.write_text(
        "/**/rs_localizer:\n  ros__parameters:\n    rig:\n      left:\n        time_offset: 0.004\n"
    )
    out = tmp_path / "rig.yaml"
    capsys.readouterr()
    assert main(["calibrate-rig", str(rig_bag), "--params-file", str(extra), "-o", str(out)]) == 0
    params = read_params_file(out)
    assert params["rig.left.time_offset"] == 0.004
    assert "rig.right.time_offset" not in params
    capsys.readouterr()
    assert main(["calibrate-rig", str(rig_bag), "--params-file", str(extra), "-o", str(out),
                 "--time-offsets", "--json"]) == 0  # fmt: skip
    report = json.loads(capsys.readouterr().out)["cameras"]
    params = read_params_file(out)
    assert "time_offset_std" not in report["front"] and report["front"]["time_offset"] == 0.0
    for name in ("left", "right"):
        dt, std = report[name]["time_offset"], report[name]["time_offset_std"]
        assert abs(dt) < 5e-4 and abs(dt) < 4 * std + 1e-5, (name, dt, std)
        assert params.get(f"rig.{name}.time_offset", 0.0) == pytest.approx(dt, abs=1e-7)


def test_an_estimated_time_offset_std_is_written_with_an_offset_of_zero_too(tmp_path):
    """The node adds a camera's ``rig.<camera>.time_offset_std`` to each rig frame's covariance
    whatever its ``time_offset``: the parameter file written for an offset estimated as 0 holds
    the std, which the node's configuration reads into the camera's mounting; a camera whose
    offset was not estimated (no std in the report, the reference's) gets neither."""
    from rs_localizer.cli.calibrate_rig import params_yaml
    from rs_localizer.ros.bags.bag_frames import rig_parameter_values
    from rs_localizer.ros.config import build_config
    from rs_localizer.ros.param_files import read_params_file

    entry = {"mounting": [0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "mounting_covariance": None}
    report = {
        "a": {**entry, "mounting": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "time_offset": 0.0},
        "b": {**entry, "time_offset": 0.0, "time_offset_std": 2.5e-4},
        "c": {**entry, "time_offset": -0.003, "time_offset_std": 1.25e-4},
    }
    out = tmp_path / "rig.yaml"
    out.write_text(params_yaml(0.0, {n: {} for n in report}, report, [], "base_link"))
    params = read_params_file(out)
    assert params["rig.b.time_offset_std"] == 2.5e-4 and "rig.b.time_offset" not in params
    assert params["rig.c.time_offset_std"] == 1.25e-4 and params["rig.c.time_offset"] == -0.003
    assert not [k for k in params if k.startswith("rig.a.time_offset")]
    a, b, c = build_config(*rig_parameter_values(None, [out])).cameras
    assert (a.mount.time_offset_std, b.mount.time_offset_std) == (0.0, 2.5e-4)
    assert (b.time_offset, c.time_offset, c.mount.time_offset_std) == (0.0, -0.003, 1.25e-4)


def test_a_rendered_rig_bags_images_are_read_through_each_cameras_front_end(
    rig_bag, tmp_path, capsys
):
    """With a front end (-p frontend, frontend_map) each camera's images are read instead of
    its clouds: on a rendered rig bag, whose clouds that front end made from the same images,
    every frame has the cloud's rows (to the cloud's float32 rounding) and the mountings are
    calibrated within their stated std of the truth; an image another size than its
    camera_info's is left out and counted; a bag without images is refused with why."""
    from helpers.rig_bags import cut_image, rewrite_bag

    from rs_localizer.cli import main
    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros.bags.bag_frames import read_rig_frames
    from rs_localizer.ros.param_files import read_params_file

    bag = tmp_path / "rendered"
    assert main(["render-bag", str(bag), "--rig", "2", "--frames", "6", "--supersample", "1",
                 "--quiet"]) == 0  # fmt: skip
    params = {"frontend": "aruco", "frontend_map": str(bag / "markers.yaml")}
    clouds, images = read_rig_frames(bag).frames, read_rig_frames(bag, params=params).frames
    assert len(images) == len(clouds) == 12
    for a, b in zip(images, clouds, strict=True):
        assert (a.camera_name, a.stamp_ns, a.tag) == (b.camera_name, b.stamp_ns, b.tag)
        assert np.abs(a.points2d - b.points2d).max() < 1e-6
        assert np.abs(a.points3d - b.points3d).max() < 1e-6
    capsys.readouterr()
    args = ["calibrate-rig", str(bag), "--json", "-o", str(tmp_path / "r.yaml"),
            "--min-inliers", "8", "-p", "frontend:=aruco",
            "-p", f"frontend_map:={bag / 'markers.yaml'}"]  # fmt: skip
    assert main(args) == 0
    back = json.loads(capsys.readouterr().out)["cameras"]["back"]
    truth = _mount(read_params_file(bag / "rig_params.yaml")["rig.back.mounting"])
    got = _mount(back["mounting"])
    assert rotation_angle_deg(got.R, truth.R) < 3 * back["std_deg"]
    assert 1e3 * np.linalg.norm(got.position - truth.position) < 3 * back["std_mm"]
    assert back["frames"] == 6 and "image_size_mismatch" not in back
    # the back camera's third image cut to 320 px wide: left out, counted

    read = read_rig_frames(rewrite_bag(bag, tmp_path / "cut", cut_image("back", 2)), params=params)
    assert read.counts["back"]["image_size_mismatch"] == 1 and len(read.frames) == 11
    # the make-bag rig bag has clouds only
    args = ["calibrate-rig", str(rig_bag), "-p", "frontend:=aruco"]
    assert main(args) == 2
    assert "the rig bag has no camera images" in capsys.readouterr().err


def test_a_markers_corners_reach_the_estimator_as_one_group(tmp_path, monkeypatch, capsys):
    """Read through each camera's ArUco front end, calibrate-rig's camera frames carry each
    corner's marker id as its group: every corner's map point is a corner of the marker of its
    group in the bag's marker map, at most 4 corners a group; and each camera frame is posed
    alone with those groups (the covariance of a marker's shared shift weighs its pose)."""
    from rs_localizer.calibration import mountings as mountings_module
    from rs_localizer.cli import main
    from rs_localizer.maps.markers import load_marker_map
    from rs_localizer.ros.bags.bag_frames import read_rig_frames

    bag = tmp_path / "rendered"
    assert main(["render-bag", str(bag), "--rig", "2", "--frames", "6", "--supersample", "1",
                 "--quiet"]) == 0  # fmt: skip
    _, markers = load_marker_map(bag / "markers.yaml")
    params = {"frontend": "aruco", "frontend_map": str(bag / "markers.yaml")}
    frames = read_rig_frames(bag, params=params).frames
    assert len(frames) == 12
    for f in frames:
        assert f.groups is not None and f.groups.shape == (len(f.points2d),)
        assert len(set(f.groups.tolist())) >= 2
        assert np.bincount(f.groups).max() <= 4
        for g, X in zip(f.groups, f.points3d, strict=True):
            assert np.abs(markers[int(g)] - X).max(axis=1).min() < 1e-5, (g, X)

    seen = []
    estimate = mountings_module.estimate_rs_pose

    def spy(uv, X, camera, **kw):
        seen.append((len(uv), kw.get("groups")))
        return estimate(uv, X, camera, **kw)

    monkeypatch.setattr(mountings_module, "estimate_rs_pose", spy)
    capsys.readouterr()
    args = ["calibrate-rig", str(bag), "--json", "-o", str(tmp_path / "r.yaml"),
            "--min-inliers", "8", "-p", "frontend:=aruco",
            "-p", f"frontend_map:={bag / 'markers.yaml'}"]  # fmt: skip
    assert main(args) == 0
    want = sorted((len(f.points2d), f.groups.tolist()) for f in frames)
    assert sorted((n, None if g is None else g.tolist()) for n, g in seen) == want
