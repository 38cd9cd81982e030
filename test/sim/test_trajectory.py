"""Synthetic RS sequences: exact per-row projection and ground-truth velocities."""

import numpy as np
import pytest

from rs_localizer.geometry import matrix_to_rotvec
from rs_localizer.maps import load_landmarks_csv, save_landmarks_csv
from rs_localizer.sim.trajectory import (
    SequenceConfig,
    Trajectory,
    default_camera,
    generate_sequence,
    make_scene,
    project_rs,
)


@pytest.fixture(scope="module")
def seq():
    return generate_sequence(SequenceConfig(num_frames=6, num_points=300, seed=3))


def test_camera_is_realistic():
    cam = default_camera()
    assert (cam.width, cam.height) == (1280, 720)
    assert 900 < cam.K[0, 0] < 1100 and cam.has_distortion
    assert cam.readout_time == pytest.approx(0.0216)


def test_frames_shape_and_outliers(seq):
    frames, scene, cam, _ = seq
    for f in frames:
        assert f.uv.shape == (300, 2) and f.xyz.shape == (300, 3) and len(f.ids) == 300
        assert np.isfinite(f.uv).all() and cam.in_image(f.uv).all()
        assert np.count_nonzero(~f.inlier) == 60
        np.testing.assert_allclose(scene.lookup(f.ids), f.xyz)
        assert f.t_ref_ns - f.stamp_ns == pytest.approx(359.5 * 30e-6 * 1e9, abs=2)
        # noise level of the inliers
        e = np.linalg.norm(f.uv[f.inlier] - f.uv_clean[f.inlier], axis=1)
        assert 0.3 < np.sqrt(np.mean(e**2) / 2) < 0.7
    assert len(set(frames[0].ids)) == 300  # distinct landmarks


def test_exact_row_constraint(seq):
    """Each clean pixel is the projection with the pose at the capture time of its own row."""
    frames, _, cam, traj = seq
    f = frames[2]
    t_first = 2 / 30.0
    t = t_first + cam.line_time(f.uv_clean[:, 1])
    R, p = traj.pose(t)
    Xc = np.einsum("nji,nj->ni", R, f.xyz - p)
    uv = cam.distort(Xc[:, :2] / Xc[:, 2:])
    np.testing.assert_allclose(uv, f.uv_clean, atol=1e-6)
    # and differs clearly from the global-shutter projection at the reference row
    Xg = (f.xyz - f.position) @ f.orientation
    gs = cam.distort(Xg[:, :2] / Xg[:, 2:])
    assert np.median(np.linalg.norm(gs - f.uv_clean, axis=1)) > 1.0


def test_ground_truth_velocity_matches_finite_motion(seq):
    """Angular/linear velocity (camera frame) predict the pose a few ms later."""
    _, _, _cam, traj = seq
    t, dt = 0.1234, 1e-3
    R, _ = traj.pose(t)
    w, v = traj.velocity_body(t)
    R0, p0 = traj.pose(t - dt)
    R1, p1 = traj.pose(t + dt)
    np.testing.assert_allclose(matrix_to_rotvec(R0.T @ R1) / (2 * dt), w, atol=1e-3)
    np.testing.assert_allclose(R.T @ (p1 - p0) / (2 * dt), v, atol=1e-3)
    assert 0.2 < np.linalg.norm(w) < 4.0 and 0.5 < np.linalg.norm(v) < 3.0


def test_global_shutter_projection_is_pinhole():
    cam = default_camera(line_delay=0.0)
    traj = Trajectory()
    scene = make_scene(np.random.default_rng(0), 500)
    uv, ok = project_rs(cam, traj, 0.5, scene.points)
    R, p = traj.pose(0.5)
    Xc = (scene.points[ok] - p) @ R
    np.testing.assert_allclose(uv[ok], cam.distort(Xc[:, :2] / Xc[:, 2:]), atol=1e-9)
    assert ok.sum() > 50 and np.isnan(uv[~ok]).all()


def test_landmarks_csv_roundtrip(tmp_path):
    scene = make_scene(np.random.default_rng(1), 50)
    path = tmp_path / "lm.csv"
    save_landmarks_csv(path, scene.ids, scene.points)
    ids, pts = load_landmarks_csv(path)
    np.testing.assert_array_equal(ids, scene.ids)
    np.testing.assert_allclose(pts, scene.points, atol=1e-9)
    (tmp_path / "bad.csv").write_text("id,x,y,z\n1,2,3\n")
    with pytest.raises(ValueError, match=r"bad\.csv:2"):
        load_landmarks_csv(tmp_path / "bad.csv")
    (tmp_path / "dup.csv").write_text("1,0,0,0\n1,1,1,1\n")
    with pytest.raises(ValueError, match="duplicate"):
        load_landmarks_csv(tmp_path / "dup.csv")


def test_landmark_files_must_be_regular(tmp_path):
    """A FIFO as landmarks_file blocked the reader (and the node) until
    someone wrote to it. Only regular files are opened; the check never blocks."""
    import os
    import threading

    from rs_localizer.maps import check_regular_file

    fifo = tmp_path / "lm.fifo"
    os.mkfifo(fifo)
    out = {}

    def load():
        try:
            load_landmarks_csv(fifo)
        except ValueError as e:
            out["error"] = str(e)

    th = threading.Thread(target=load, daemon=True)
    th.start()
    th.join(5.0)
    if th.is_alive():  # (release the blocked reader before failing)
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
    assert not th.is_alive() and "not a regular file" in out.get("error", ""), out
    for bad in (fifo, tmp_path):
        with pytest.raises(ValueError, match="not a regular file"):
            check_regular_file(bad)
    with pytest.raises(FileNotFoundError):
        check_regular_file(tmp_path / "missing.csv")
    ok = tmp_path / "lm.csv"
    save_landmarks_csv(ok, [3, 5], np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]))
    check_regular_file(ok)
    ids, pts = load_landmarks_csv(ok)
    assert ids.tolist() == [3, 5] and pts[1].tolist() == [3.0, 4.0, 5.0]
