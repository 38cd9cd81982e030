"""Readout calibration (line delay from a video with rotation) and the new synthetic sequences:
against the line delay the sequences were generated with."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rs_localizer.calibration.readout import calibrate_line_delay, fit_line_delay
from rs_localizer.cli import main as cli_main
from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.trajectory import (
    R_IMU_CAMERA,
    TRAJECTORIES,
    SequenceConfig,
    default_camera,
    generate_sequence,
    imu_samples,
    make_trajectory,
)

LINE_DELAY = 30e-6


def test_trajectory_presets():
    """The presets do what their names say (rates from the trajectories' finite differences)."""
    t = np.linspace(0, 4, 801)
    rates = {}
    for name in TRAJECTORIES:
        w, v = make_trajectory(name).velocity_body(t)
        alpha = np.gradient(w, t, axis=0)
        rates[name] = (
            np.linalg.norm(w, axis=1),
            np.linalg.norm(v, axis=1),
            np.linalg.norm(alpha, axis=1),
        )
    assert rates["car"][0].max() < 0.1 and rates["car"][1].min() > 4.5  # near-pure translation
    assert rates["shake"][2].max() > 25.0 > rates["walk"][2].max()  # strong angular accel.
    assert np.median(rates["pan"][0]) > 0.5  # rotation for the calibration
    with pytest.raises(ValueError):
        make_trajectory("boat")


def test_fit_on_exact_rates_and_gyro():
    """Exact per-frame rates (w = -omega s) of a trajectory give s back; so does a gyro with
    bias and noise in a rotated IMU frame (the rotation is estimated)."""
    cam = default_camera(line_delay=LINE_DELAY)
    traj = make_trajectory("pan")
    s = cam.seconds_per_unit_r
    t = np.arange(60) / 30.0
    Ori = traj.orientation(t)
    w = -traj.velocity_body(t)[0] * s
    stamps = (t * 1e9).astype(np.int64)
    res = fit_line_delay(stamps, Ori, w, cam)
    assert res.observable and res.line_delay == pytest.approx(LINE_DELAY, rel=1e-3)
    assert res.frames_used == 60 and res.samples == 58
    # gyro: stamps are of row 0, the rates at the reference row (360 lines later)
    t_ref = t + float(cam.line_time(cam.reference_line))
    w_ref = -traj.velocity_body(t_ref)[0] * s
    ti, om, _ = imu_samples(traj, -0.1, 2.1, 200.0, seed=1)
    g = fit_line_delay(
        stamps,
        traj.orientation(t_ref),
        w_ref,
        cam,
        gyro=((ti * 1e9).astype(np.int64), om),
        stamp_row=0.0,
    )
    assert g.observable and g.line_delay == pytest.approx(LINE_DELAY, rel=5e-3)
    assert np.abs(g.camera_imu_rotation - R_IMU_CAMERA.T).max() < 0.02
    # too few frames / no rotation
    assert not fit_line_delay(stamps[:5], Ori[:5], w[:5], cam).observable
    still = fit_line_delay(
        stamps,
        np.repeat(np.eye(3)[None], 60, 0),
        np.random.default_rng(0).normal(0, 1e-3, (60, 3)),
        cam,
    )
    assert not still.observable and still.line_delay is None and still.reason


def _frames(name, seed, n=60, **cfg):
    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=n, seed=seed, **cfg),
        camera=default_camera(line_delay=LINE_DELAY),
        trajectory=make_trajectory(name),
    )
    return [(f.stamp_ns, f.uv, f.xyz) for f in frames], cam


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_line_delay_from_a_panning_video(seed):
    frames, cam = _frames("pan", seed)
    # the bag's stated RS timing is ignored: tell it something wrong
    from dataclasses import replace

    res = calibrate_line_delay(frames, replace(cam, line_delay=1e-3))
    assert res.observable and res.frames_used == 60
    err = res.line_delay - LINE_DELAY
    assert abs(err) < 0.03 * LINE_DELAY  # the target: within 3 %
    assert abs(err) < 3 * res.line_delay_std  # an honest std ...
    assert res.line_delay_std < 0.01 * LINE_DELAY  # ... that is not vacuous
    assert res.readout_time == pytest.approx(res.line_delay * 720)
    assert json.loads(json.dumps(res.as_dict())) == res.as_dict()


def test_no_rotation_is_not_observable():
    frames, cam = _frames("car", 0, n=40)
    res = calibrate_line_delay(frames, cam)
    assert not res.observable and res.line_delay is None and res.line_delay_std is None
    assert "rotation" in res.reason


@pytest.mark.slow
def test_cli_json_and_bag_without_ground_truth_twist(tmp_path, capsys):
    bag = tmp_path / "pan"
    assert (
        cli_main(
            [
                "make-bag",
                str(bag),
                "--motion",
                "pan",
                "--frames",
                "40",
                "--seed",
                "2",
                "--imu-rate",
                "200",
                "--no-gt-twist",
                "--drop-frames",
                "20",
                "--no-keypoints",
            ]
        )
        == 0
    )
    meta = json.loads((bag / "sequence.json").read_text())
    assert "gt_twist" not in meta["topics"] and meta["topics"]["imu"] == "/imu/data"
    assert meta["settings"]["motion"] == "pan" and meta["settings"]["drop_frames"] == [20]
    capsys.readouterr()
    for extra in ([], ["--imu-topic", "/imu/data"]):
        assert cli_main(["calibrate-readout", str(bag), "--json"] + extra) == 0
        out, err = capsys.readouterr()
        res = json.loads(out)  # exactly one JSON object on stdout
        assert out.strip().count("\n") == 0
        assert set(res) == {"line_delay", "line_delay_std", "frames_used", "observable"}
        assert res["observable"] and abs(res["line_delay"] - LINE_DELAY) < 0.03 * LINE_DELAY
        assert res["frames_used"] >= 36 and "line delay" in err
    # replay still works on a bag without ground-truth twist (pose errors only)
    assert cli_main(["replay", str(bag), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "rotation median" in out and "lin.vel" not in out


def test_cli_not_observable_exit_code(tmp_path, capsys):
    bag = tmp_path / "car"
    cli_main(["make-bag", str(bag), "--motion", "car", "--frames", "30", "--no-keypoints"])
    capsys.readouterr()
    assert cli_main(["calibrate-readout", str(bag), "--json"]) == 3
    res = json.loads(capsys.readouterr().out)
    assert res == {
        "line_delay": None,
        "line_delay_std": None,
        "frames_used": 30,
        "observable": False,
    }


def test_teleport_and_dropped_frames_in_sequences():
    from rs_localizer.sim.trajectory import Teleport

    base = make_trajectory("walk")
    tp = Teleport(base, time=0.3, offset=(8.0, 0.0, 0.0), yaw=0.7)
    np.testing.assert_allclose(tp.position(0.29), base.position(0.29))
    np.testing.assert_allclose(tp.position(0.31), base.position(0.31) + [8, 0, 0])
    np.testing.assert_allclose(
        tp.orientation(0.31), rotvec_to_matrix([0, 0, 0.7]) @ base.orientation(0.31)
    )
    full, _, _, _ = generate_sequence(SequenceConfig(num_frames=6, num_points=100, seed=7))
    some, _, _, _ = generate_sequence(
        SequenceConfig(num_frames=6, num_points=100, seed=7, drop_frames=(2, 3))
    )
    assert [f.index for f in some] == [0, 1, 4, 5]
    for f in some:  # the frames left are those of the full sequence
        np.testing.assert_array_equal(f.uv, full[f.index].uv)


def test_image_source_on_the_rendered_bag(capsys):
    """data/sample_images: real ArUco detections in rendered RS images (62.5 us/line, a
    hand-held shake at ~0.6 rad/s rms, 20 frames)."""
    from helpers.paths import SAMPLE_IMAGES_BAG

    if not (SAMPLE_IMAGES_BAG / "metadata.yaml").exists():
        pytest.skip("data/sample_images missing")
    assert (
        cli_main(["calibrate-readout", str(SAMPLE_IMAGES_BAG), "--source", "image", "--json"]) == 0
    )
    res = json.loads(capsys.readouterr().out)
    assert res["observable"] and res["frames_used"] == 20
    err = res["line_delay"] - 62.5e-6
    assert abs(err) < 0.05 * 62.5e-6 and abs(err) < 3 * res["line_delay_std"], res


def _shifted_gyro(traj, seconds, offset, seed=1, t0_ns=0):
    """A 200 Hz gyro (bias, noise, IMU axes of R_IMU_CAMERA) stamped on a clock ``offset`` s
    behind the camera's (t_cam = t_imu + offset)."""
    ti, om, _ = imu_samples(traj, -0.2, seconds + 0.2, 200.0, seed=seed)
    return t0_ns + np.round((ti - offset) * 1e9).astype(np.int64), om


def test_time_offset_on_exact_rates_and_not_on_a_constant_rate():
    """Exact per-frame rates of a hand-held shake and a gyro 10 ms late: the offset comes back
    to 0.2 ms with a std that covers it; the rotation and the line delay as without an offset.
    A constant rotation rate fits any shift: not observable, with the reason."""
    cam = default_camera(line_delay=LINE_DELAY)
    s = cam.seconds_per_unit_r
    t = np.arange(60) / 30.0
    stamps = (t * 1e9).astype(np.int64)
    t_ref = t + float(cam.line_time(cam.reference_line))
    traj = make_trajectory("shake")
    w = -traj.velocity_body(t_ref)[0] * s
    g = fit_line_delay(stamps, traj.orientation(t_ref), w, cam, gyro=_shifted_gyro(traj, 2, 0.01))
    assert g.observable and g.line_delay == pytest.approx(LINE_DELAY, rel=5e-3)
    assert abs(g.time_offset - 0.01) < 2e-4 and abs(g.time_offset - 0.01) < 3 * g.time_offset_std
    assert np.abs(g.camera_imu_rotation - R_IMU_CAMERA.T).max() < 0.02
    # constant rate about a fixed axis (0.8 rad/s): the fit of s and R still works (bias
    # aside), the offset does not
    rng = np.random.default_rng(3)
    omega = np.array([0.1, 0.8, 0.05])
    ti = np.arange(-0.2, 2.2, 0.005)
    gyro = ((ti * 1e9).astype(np.int64), omega @ R_IMU_CAMERA.T + rng.normal(0, 3e-3, (len(ti), 3)))
    w_const = -np.tile(omega, (60, 1)) * s + rng.normal(0, 1e-3 * s, (60, 3))
    c = fit_line_delay(stamps, np.repeat(np.eye(3)[None], 60, 0), w_const, cam, gyro=gyro)
    assert c.observable and c.time_offset is None
    assert "barely changes" in c.time_offset_reason, c.time_offset_reason


@pytest.mark.parametrize("readout", ["bottom_to_top", "right_to_left"])
def test_time_offset_when_the_readout_runs_backwards(readout):
    """A camera read bottom to top (or right to left), its stamp the capture time of pixel
    line 0, which it reads last: the frames' reference-line times come before their stamps,
    and a gyro 10 ms late is found 10 ms late (not off by twice the half readout, 21.6 ms
    here), with the line delay."""
    from dataclasses import replace

    cam = replace(default_camera(line_delay=LINE_DELAY), readout=readout)
    s = cam.seconds_per_unit_r
    t = np.arange(60) / 30.0
    stamps = (t * 1e9).astype(np.int64)
    lead = float(cam.line_time(cam.reference_line) - cam.line_time(0.0))
    assert lead < 0  # (the reference line is read before line 0)
    t_ref = t + lead
    traj = make_trajectory("shake")
    w = -traj.velocity_body(t_ref)[0] * s
    g = fit_line_delay(stamps, traj.orientation(t_ref), w, cam, gyro=_shifted_gyro(traj, 2, 0.01))
    assert g.observable and g.line_delay == pytest.approx(LINE_DELAY, rel=5e-3)
    assert abs(g.time_offset - 0.01) < 2e-4, g.time_offset
    assert np.abs(g.camera_imu_rotation - R_IMU_CAMERA.T).max() < 0.02


@pytest.mark.slow
def test_time_offset_from_a_shaky_video():
    """2 s of simulated hand-held shake (60 frames, 500 correspondences with 0.5 px noise and
    20 % outliers) with a gyro 10 ms late: the offset to within 1 ms (0.39 ms the largest error
    over seeds 0-5, std 0.36-0.44 ms), an honest std, and the parameter line printed."""
    frames, cam = _frames("shake", 0)
    traj = make_trajectory("shake")
    t0 = SequenceConfig().t0_ns
    res = calibrate_line_delay(frames, cam, gyro=_shifted_gyro(traj, 2, 0.01, 0, t0))
    assert res.observable and abs(res.line_delay - LINE_DELAY) < 0.03 * LINE_DELAY
    err = res.time_offset - 0.01
    assert abs(err) < 1e-3 and abs(err) < 3 * res.time_offset_std < 3e-3, res
    # the shake turns about every axis: mount and bias determined, within 3 std of the truth
    # (the simulated IMU: R_IMU_CAMERA, bias (0.01, -0.02, 0.005) rad/s)
    assert res.camera_imu_rotation_observable and res.gyro_bias_observable, res.mount_reason
    rot_err = matrix_to_rotvec(res.camera_imu_rotation @ R_IMU_CAMERA)  # camera axes
    assert np.all(np.abs(rot_err) < 3 * res.camera_imu_rotation_std), (rot_err, res)
    assert np.all(res.camera_imu_rotation_std < np.radians(0.3))
    bias_err = res.gyro_bias - np.array([0.01, -0.02, 0.005])
    assert np.all(np.abs(bias_err) < 3 * res.gyro_bias_std) and np.abs(bias_err).max() < 2e-3
    assert np.all(res.gyro_bias_std < 2e-3) and res.mount_reason == ""


@pytest.mark.slow
def test_one_axis_pan_leaves_the_mount_about_its_axis_undetermined():
    """A pan turns about one axis (the camera's y): the rotation about it is reported as not
    observable, with the axis and the advice to rotate about all three axes; the figures
    printed are still within 3 std of the truth (an honest std, not only a large one)."""
    frames, cam = _frames("pan", 0)
    t0 = SequenceConfig().t0_ns
    res = calibrate_line_delay(frames, cam, gyro=_shifted_gyro(make_trajectory("pan"), 2, 0, 1, t0))
    assert res.observable and res.camera_imu_rotation_observable is False
    std = res.camera_imu_rotation_std
    assert std[1] > np.radians(0.5) and std[1] > 5 * max(std[0], std[2]), std
    assert "all three axes" in res.mount_reason and "camera axis [" in res.mount_reason
    rot_err = matrix_to_rotvec(res.camera_imu_rotation @ R_IMU_CAMERA)
    assert np.all(np.abs(rot_err) < 3 * std), (rot_err, std)
    bias_err = res.gyro_bias - np.array([0.01, -0.02, 0.005])
    assert np.all(np.abs(bias_err) < 3 * res.gyro_bias_std), (bias_err, res.gyro_bias_std)


@pytest.mark.slow
def test_cli_prints_the_time_offset_as_a_parameter(tmp_path, capsys):
    """make-bag --imu-time-offset 0.01, then calibrate-readout --imu-topic: the offset is
    printed as the node's parameter and within 1 ms of the simulated one."""
    bag = tmp_path / "late"
    args = ["--frames", "60", "--motion", "shake", "--imu-rate", "200"]
    assert cli_main(["make-bag", str(bag), *args, "--imu-time-offset", "0.01"]) == 0
    meta = json.loads((bag / "sequence.json").read_text())
    assert meta["imu"]["time_offset"] == 0.01
    capsys.readouterr()
    assert cli_main(["calibrate-readout", str(bag), "--imu-topic", "/imu/data"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("imu.time_offset:"))
    assert abs(float(line.split(":")[1]) - 0.01) < 1e-3, out
    assert "imu.rotation:" in out and "imu.gyro_bias:" in out
    assert "camera-IMU rotation: std about camera x/y/z" in out and ": observable" in out, out


def test_gyro_lines_say_what_is_not_determined():
    """The printed lines carry each std and verdict; an undetermined rotation gets the
    warning; no gyro, no lines."""
    from rs_localizer.calibration.readout import ReadoutCalibration

    assert ReadoutCalibration(3e-5, 1e-7, 60, True).gyro_lines() == []
    res = ReadoutCalibration(
        3e-5,
        1e-7,
        60,
        True,
        camera_imu_rotation=np.eye(3),
        camera_imu_rotation_std=np.radians([0.1, 2.0, 0.1]),
        camera_imu_rotation_observable=False,
        gyro_bias=np.array([0.01, -0.02, 0.005]),
        gyro_bias_std=np.array([0.001, 0.002, 0.001]),
        gyro_bias_observable=True,
        mount_reason="the camera-IMU rotation about camera axis [0.00, 1.00, 0.00] is not ...",
    )
    rot, bias, warn = res.gyro_lines()
    assert rot == "camera-IMU rotation: std about camera x/y/z 0.1/2/0.1 deg: NOT observable"
    assert bias.startswith("gyro bias [0.0100, -0.0200, 0.0050]") and "0.0020" in bias
    assert bias.endswith(": observable") and warn.startswith("WARNING: the camera-IMU rotation")
