"""Rolling-shutter renderer: rendered points sit where the exact RS model projects them."""

import numpy as np
import pytest

from rs_localizer.camera import CameraModel
from rs_localizer.geometry import matrix_to_rotvec
from rs_localizer.maps.markers import load_marker_map, write_marker_map
from rs_localizer.sim.render import (
    Renderer,
    camera_preset,
    camera_rays,
    load_scene,
    make_motion,
    motion_names,
    scene_names,
)
from rs_localizer.sim.trajectory import project_rs

T_FRAME = 0.35  # a frame with ~1 rad/s rotation in the shake motion


@pytest.fixture(scope="module")
def room():
    scene = load_scene("aruco_room")
    camera = camera_preset("vga")  # 640x480, 30 ms readout, plumb_bob distortion
    motion = make_motion("shake", scene, duration=2.0)
    return scene, camera, motion, Renderer(scene, camera)


def _locate(hit, X, uv0):
    """Sub-pixel position where the per-pixel hit map equals the world point X: an affine fit
    of the hit points over the 3x3 pixels around ``uv0``, inverted."""
    pu, pv = int(round(uv0[0])), int(round(uv0[1]))
    P, Y = [], []
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            P.append([1.0, du, dv])
            Y.append(hit[pv + dv, pu + du])
    A = np.linalg.lstsq(np.array(P), np.array(Y), rcond=None)[0]
    d = np.linalg.lstsq(A[1:].T, X - A[0], rcond=None)[0]
    return np.array([pu, pv]) + d


def test_marker_corners_appear_at_exact_rs_projection(room):
    """Every visible marker corner appears in the rendered frame (rendered line by line from
    the continuous trajectory, through lens distortion) at the pixel predicted by the exact RS
    projection with the row solved iteratively (rs_localizer.sim.trajectory.project_rs)."""
    scene, camera, motion, r = room
    hit, _quad, _ = r.hit_map(motion, T_FRAME)
    _, X = scene.marker_corner_points()
    uv, ok = project_rs(camera, motion, T_FRAME, X)
    inner = ok & camera.in_image(uv, margin=-3)
    assert inner.sum() > 150
    err = np.array(
        [np.linalg.norm(_locate(hit, X[i], uv[i]) - uv[i]) for i in np.flatnonzero(inner)]
    )
    assert err.max() < 0.1 and np.median(err) < 0.01
    # and the RS effect is real: the global-shutter projection is far off
    R, p = motion.pose(T_FRAME + camera.line_time(camera.reference_line))
    Xg = (X[inner] - p) @ R
    gs = camera.distort(Xg[:, :2] / Xg[:, 2:])
    assert np.max(np.linalg.norm(gs - uv[inner], axis=1)) > 3.0


def test_texture_blob_centroids_match_projection():
    """Image content: Gaussian blobs painted on a wall are rendered (bilinear/trilinear texture
    sampling, anti-aliasing) with their intensity centroids at the exact RS projection."""
    tpm, W, H, sig, pitch = 200, 3.0, 2.0, 0.02, 0.15
    ys, xs = np.mgrid[0 : int(H * tpm), 0 : int(W * tpm)]
    da = ((xs + 0.5) / tpm + pitch / 2) % pitch - pitch / 2
    db = ((ys + 0.5) / tpm + pitch / 2) % pitch - pitch / 2
    tex = (30 + 200 * np.exp(-(da**2 + db**2) / (2 * sig**2))).astype(np.uint8)
    scene = load_scene(
        {
            "name": "blobs",
            "viewpoint": {"position": [0, 0, 1.5], "look_at": [3, 0, 1.5]},
            "quads": [
                {
                    "name": "wall",
                    "origin": [3, 1.5, 2.5],
                    "u": [0, -1, 0],
                    "v": [0, 0, -1],
                    "size": [W, H],
                    "texture": {"array": tex},
                }
            ],
        }
    )
    camera = camera_preset("vga")
    motion = make_motion("shake", scene, duration=2.0)
    img = Renderer(scene, camera).render_image(motion, T_FRAME).mean(axis=2) - 30.0
    A, B = np.meshgrid(np.arange(1, 20) * pitch, np.arange(1, 13) * pitch)
    X = scene.quads[0].point(A.ravel(), B.ravel())
    uv, ok = project_rs(camera, motion, T_FRAME, X)
    ok &= camera.in_image(uv, margin=-14)
    assert ok.sum() > 100
    R = 11
    vv, uu = np.mgrid[-R : R + 1, -R : R + 1]
    err = []
    for p in uv[ok]:
        u0, v0 = int(round(p[0])), int(round(p[1]))
        patch = img[v0 - R : v0 + R + 1, u0 - R : u0 + R + 1]
        c = np.array([(patch * uu).sum(), (patch * vv).sum()]) / patch.sum() + [u0, v0]
        err.append(np.linalg.norm(c - p))
    assert np.max(err) < 0.1 and np.median(err) < 0.03


def test_zero_line_delay_reproduces_global_shutter(room):
    scene, camera, motion, _ = room
    gs_cam = CameraModel(
        K=camera.K, D=camera.D, width=camera.width, height=camera.height, line_delay=0.0
    )
    r0 = Renderer(scene, gs_cam)
    rolling = r0.render_image(motion, T_FRAME, "rolling")
    glob = r0.render_image(motion, T_FRAME, "global")
    np.testing.assert_array_equal(rolling, glob)
    # the global render is the render from the one pose at the reference line
    r = Renderer(scene, camera)
    f = r.render(motion, T_FRAME, shutter="global")
    np.testing.assert_array_equal(f.image, r.render_pose(f.orientation, f.position))
    # while the rolling-shutter render of the same frame differs visibly
    rs = r.render(motion, T_FRAME).image.astype(float)
    assert np.abs(rs - f.image).mean() > 5.0


def test_ground_truth_per_frame(room):
    _, camera, motion, r = room
    f = r.render(motion, T_FRAME, index=3)
    assert f.image.shape == (480, 640, 3) and f.image.dtype == np.uint8
    np.testing.assert_allclose(f.line_times, T_FRAME + np.arange(480) * camera.line_delay)
    assert f.t_ref == pytest.approx(T_FRAME + 239.5 * camera.line_delay)
    R, p = motion.pose(f.t_ref)
    np.testing.assert_allclose(f.orientation, R, atol=1e-12)
    np.testing.assert_allclose(f.position, p, atol=1e-12)
    # camera-frame velocities predict the pose 1 ms later
    dt = 1e-3
    R2, p2 = motion.pose(f.t_ref + dt)
    np.testing.assert_allclose(matrix_to_rotvec(R.T @ R2) / dt, f.angular_velocity, atol=0.02)
    np.testing.assert_allclose(R.T @ (p2 - p) / dt, f.linear_velocity, atol=0.02)
    assert np.linalg.norm(f.angular_velocity) > 0.3
    assert f.stamp_ns(1_000_000_000) == 1_000_000_000 + round(T_FRAME * 1e9)


def test_rays_follow_lens_distortion():
    cam = camera_preset("vga")
    rays = camera_rays(cam, 1)
    vv, uu = np.mgrid[0:480:37, 0:640:41]
    px = cam.distort(rays[vv.ravel(), uu.ravel(), :2])
    np.testing.assert_allclose(px, np.stack([uu.ravel(), vv.ravel()], axis=1), atol=1e-6)
    assert cam.readout_time == pytest.approx(0.030)
    assert 0.020 <= camera_preset("hd").readout_time <= 0.033


def test_scenes_and_motions(tmp_path):
    assert {"aruco_room", "textured_room"} <= set(scene_names())
    sc = load_scene("aruco_room")
    ids, _X = sc.marker_corner_points()
    assert len(sc.markers) >= 100 and len(np.unique(ids)) == len(ids)
    assert set(ids % 4) == {0, 1, 2, 3}
    # marker corners lie on their quad's plane; ArUco order TL, TR, BR, BL along u, v
    for m in sc.markers[::17]:
        q = sc.quads[m.quad]
        c = sc.marker_corners()[m.id]
        np.testing.assert_allclose((c - q.origin) @ q.normal, 0, atol=1e-12)
        np.testing.assert_allclose(c[1] - c[0], m.size * q.u, atol=1e-12)
        np.testing.assert_allclose(c[3] - c[0], m.size * q.v, atol=1e-12)
    # three perpendicular walls and a floor
    normals = np.array([q.normal for q in sc.quads])
    assert np.abs(normals @ normals.T - np.eye(4))[[0, 0, 1, 2], [1, 3, 3, 3]].max() < 1e-12
    write_marker_map(tmp_path / "m.yaml", sc.dictionary, sc.marker_corners(), scene=sc.name)
    d, corners = load_marker_map(tmp_path / "m.yaml")
    assert d == sc.dictionary and np.allclose(corners[5], sc.marker_corners()[5], atol=1e-6)
    with pytest.raises(ValueError):
        load_scene(
            {"quads": [{"origin": [0, 0, 0], "u": [1, 0, 0], "v": [1, 1, 0], "size": [1, 1]}]}
        )
    with pytest.raises(ValueError):
        load_scene(
            {
                "quads": [
                    {
                        "name": "a",
                        "origin": [0, 0, 0],
                        "u": [1, 0, 0],
                        "v": [0, 0, -1],
                        "size": [2, 2],
                    }
                ],
                "markers": {
                    "placements": [
                        {"id": 1, "quad": "a", "at": [0.5, 0.5], "size": 0.2},
                        {"id": 1, "quad": "a", "at": [1.2, 0.5], "size": 0.2},
                    ]
                },
            }
        )
    for name in motion_names():
        m = make_motion(name, sc, duration=1.0)
        w, v = m.velocity_body(np.linspace(0, 1, 7))
        assert np.isfinite(w).all() and np.isfinite(v).all()
        if name == "car":
            assert np.abs(w).max() < 1e-9 and np.linalg.norm(v, axis=1).min() > 2.5
    with pytest.raises(ValueError):
        make_motion("teleport")


def test_render_bag_roundtrip(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from rs_localizer.cli.render_bag import render_bag
    from rs_localizer.ros.image_codec import decode_image
    from rs_localizer.ros.pointcloud import read_correspondences

    bag = render_bag(tmp_path / "bag", "aruco_room", "shake", 3, mono=True, supersample=1)
    ts = get_typestore(Stores.ROS2_JAZZY)
    msgs = {}
    with Reader(bag) as r:
        for conn, _t, raw in r.messages():
            msgs.setdefault(conn.topic, []).append(ts.deserialize_cdr(raw, conn.msgtype))
    assert {k: len(v) for k, v in msgs.items()} == {
        "/camera/image_raw": 3,
        "/camera/camera_info": 3,
        "/camera/correspondences": 3,
        "/ground_truth/pose": 3,
        "/ground_truth/twist": 3,
    }
    img, enc = decode_image(msgs["/camera/image_raw"][1])
    assert img.shape == (480, 640) and enc == "mono8"
    c = read_correspondences(msgs["/camera/correspondences"][1])
    assert len(c) > 100 and set(c.ids.astype(int) % 4) == {0, 1, 2, 3}
    assert {f.name for f in msgs["/camera/correspondences"][1].fields} == set("uvxyz") | {"id"}
    im_stamp = msgs["/camera/image_raw"][1].header.stamp
    gt_stamp = msgs["/ground_truth/pose"][1].header.stamp
    dt = (gt_stamp.sec - im_stamp.sec) + (gt_stamp.nanosec - im_stamp.nanosec) * 1e-9
    assert dt == pytest.approx(239.5 * 0.030 / 480, abs=1e-8)  # reference line vs first line
    assert (bag / "sequence.json").exists() and (bag / "markers.yaml").exists()
    with pytest.raises(FileExistsError):
        render_bag(bag, frames=1)


@pytest.mark.parametrize("readout", ["bottom_to_top", "left_to_right"])
def test_other_readout_directions(room, readout):
    """Lines may be columns or read bottom-up: the corner still appears where project_rs puts
    it (hit map), and line times follow the readout."""
    scene, _, motion, _ = room
    camera = camera_preset("vga", readout=readout)
    r = Renderer(scene, camera, supersample=1)
    hit, _, _ = r.hit_map(motion, T_FRAME)
    _, X = scene.marker_corner_points()
    uv, ok = project_rs(camera, motion, T_FRAME, X)
    inner = np.flatnonzero(ok & camera.in_image(uv, margin=-3))
    assert len(inner) > 100
    err = [np.linalg.norm(_locate(hit, X[i], uv[i]) - uv[i]) for i in inner]
    assert np.max(err) < 0.1
    lt = r.line_times(0.0)
    assert len(lt) == camera.lines and (lt[-1] > lt[0]) == (readout == "left_to_right")


def test_exposure_blur(room):
    scene, camera, motion, _ = room
    sharp = Renderer(scene, camera, supersample=1).render_image(motion, T_FRAME)
    blur = Renderer(scene, camera, supersample=1, exposure=0.01).render_image(motion, T_FRAME)
    assert abs(sharp.mean() - blur.mean()) < 2.0

    # motion blur removes high-frequency energy
    def energy(img):
        return (np.diff(img, axis=0) ** 2).mean() + (np.diff(img, axis=1) ** 2).mean()

    assert energy(blur) < 0.8 * energy(sharp)
