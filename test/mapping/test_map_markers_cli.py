"""``rs-localizer map-markers`` on rendered rolling-shutter images of the built-in aruco_room
(sim/render: every line rendered at its own capture time), the written map against the scene's
true marker corners, and the command's refusals (no bent or partial map file)."""

import os
import stat

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from rs_localizer.cli import main
from rs_localizer.frontends.aruco import ArucoFrontend
from rs_localizer.maps import load_marker_map
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import Renderer, camera_preset, frame_times
from rs_localizer.sim.render.scene import load_scene

FRAMES = 16


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("map_markers")
    scene = load_scene("aruco_room")
    camera = camera_preset("vga", readout_time=0.03)
    motion = make_motion("pan", scene, duration=FRAMES / 30)
    renderer = Renderer(scene, camera)
    images = root / "images"
    images.mkdir()
    for i in range(FRAMES):
        fr = renderer.render(motion, float(frame_times(i)), index=i)
        cv2.imwrite(str(images / f"{i:04d}.png"), cv2.cvtColor(fr.image, cv2.COLOR_RGB2BGR))
    cam_yaml = root / "camera.yaml"
    cam_yaml.write_text(
        yaml.safe_dump(
            {
                "image_width": camera.width,
                "image_height": camera.height,
                "camera_matrix": {"rows": 3, "cols": 3, "data": camera.K.ravel().tolist()},
                "distortion_model": "plumb_bob",
                "distortion_coefficients": {"rows": 1, "cols": 5, "data": camera.D.tolist()},
            }
        )
    )
    _, true = load_marker_map("aruco_room")
    c = true[0]  # anchor pose from its true corners (x right, y up, z out of the face)
    x = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
    y = (c[0] - c[3]) / np.linalg.norm(c[0] - c[3])
    q = Rotation.from_matrix(np.stack([x, y, np.cross(x, y)], axis=1)).as_quat()
    pose = [str(v) for v in [*c.mean(axis=0), *q]]
    return root, images, cam_yaml, true, pose


def args(rendered, out, *extra):
    _, images, cam_yaml, _, pose = rendered
    return [
        "map-markers",
        str(images),
        "-o",
        str(out),
        "--camera",
        str(cam_yaml),
        "--marker-size",
        "0.3",
        "--dictionary",
        "DICT_4X4_250",
        "--anchor",
        "0",
        "--anchor-pose",
        *pose,
        "--quiet",
        *extra,
    ]


@pytest.mark.slow
def test_map_from_rendered_images_matches_the_scene(rendered, tmp_path):
    _, images, _, true, _ = rendered
    out = tmp_path / "map.yaml"
    report = tmp_path / "report"
    old = os.umask(0o022)  # (every file the tool writes follows the user's umask)
    try:
        assert main(args(rendered, out, "--report", str(report))) == 0
    finally:
        os.umask(old)
    written = sorted(tmp_path.rglob("*"))
    assert {out, report / "report.yaml", report / "map.png"} <= set(written)
    for f in written:
        assert stat.S_IMODE(f.stat().st_mode) == (0o755 if f.is_dir() else 0o644), f
    dictionary, corners = load_marker_map(out)
    assert dictionary == "DICT_4X4_250"
    assert len(corners) >= 20
    e = np.concatenate([np.linalg.norm(corners[m] - true[m], axis=1) for m in corners])
    assert np.median(e) < 0.04 and e.max() < 0.12, (np.median(e), e.max())
    # the ArUco front end localizes against the written map
    front = ArucoFrontend.from_file(out)
    img = cv2.imread(str(images / "0000.png"))
    uv, _, ids = front.process(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    assert len(ids) >= 16 and len(uv) == len(ids)
    rep = yaml.safe_load((report / "report.yaml").read_text())
    assert set(rep["markers"]) == set(corners)
    assert (report / "map.png").stat().st_size > 10_000
    # an existing map is not overwritten without --overwrite
    before = out.read_bytes()
    assert main(args(rendered, out)) == 2
    assert out.read_bytes() == before


@pytest.mark.slow
def test_refusals_write_no_file(rendered, tmp_path, capsys):
    cam_yaml = rendered[2]
    out = tmp_path / "map.yaml"
    # wrong dictionary: no detections
    a = args(rendered, out)
    a[a.index("DICT_4X4_250")] = "DICT_APRILTAG_36h11"
    assert main(a) == 2
    assert "no marker detections" in capsys.readouterr().err
    # anchor never in view
    a = args(rendered, out)
    a[a.index("--anchor") + 1] = "999"
    assert main(a) == 2
    assert "anchor marker 999" in capsys.readouterr().err
    # images of another size than the camera
    cam = yaml.safe_load(cam_yaml.read_text())
    cam["image_width"] = 800
    other = tmp_path / "camera800.yaml"
    other.write_text(yaml.safe_dump(cam))
    a = args(rendered, out)
    a[a.index("--camera") + 1] = str(other)
    assert main(a) == 2
    assert "the camera 800x480" in capsys.readouterr().err
    assert not out.exists()
    assert not list(tmp_path.glob(".map.yaml.*"))


@pytest.mark.slow
def test_map_from_a_rendered_bag(rendered, tmp_path, capsys):
    """The same scene rendered to a bag by ``render-bag`` (images, camera_info, header stamps
    at the first line's capture time)."""
    true, pose = rendered[3], rendered[4]
    bag = tmp_path / "bag"
    assert main(["render-bag", str(bag), "--frames", "12", "--motion", "pan"]) == 0
    capsys.readouterr()
    out = tmp_path / "map.yaml"
    common = ["--marker-size", "0.3", "--dictionary", "DICT_4X4_250", "--anchor", "0"]
    a = ["map-markers", str(bag), "-o", str(out), *common, "--anchor-pose", *pose, "--quiet"]
    assert main([*a, "--image-topic", "/no/such/image"]) == 2
    assert "no image topic '/no/such/image'" in capsys.readouterr().err
    assert not out.exists()
    assert main(a) == 0
    _, corners = load_marker_map(out)
    assert len(corners) >= 20
    e = np.concatenate([np.linalg.norm(corners[m] - true[m], axis=1) for m in corners])
    # (12 frames of a pan: markers at the edge of the view are seen in few frames; their
    # error depends on the OpenCV build's corner refinement: max 0.14 m with Debian 12's
    # OpenCV 4.6, below 0.12 m with the PyPI wheel)
    assert np.median(e) < 0.04 and e.max() < 0.2, (np.median(e), e.max())


def test_an_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    import os

    import rs_localizer.mapping.outputs as outputs

    def interrupted(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        outputs.write_atomic(tmp_path / "map.yaml", "markers: []\n")
    assert list(tmp_path.iterdir()) == []


def test_detector_choice_is_checked_before_any_work(tmp_path, capsys):
    """An unknown dictionary, or the AprilTag detector asked for an ArUco dictionary: exit 2
    naming what is supported, before any image is read (the folder is empty)."""
    images = tmp_path / "images"
    images.mkdir()
    cam = tmp_path / "camera.yaml"
    cam.write_text("image_width: 64\nimage_height: 48\n")
    base = ["map-markers", str(images), "-o", str(tmp_path / "m.yaml"), "--camera", str(cam)]
    base += ["--marker-size", "0.1", "--quiet"]
    assert main([*base, "--dictionary", "DICT_9X9_1"]) == 2
    err = capsys.readouterr().err
    assert "unknown marker dictionary 'DICT_9X9_1'" in err and "tag36h11" in err
    assert main([*base, "--dictionary", "DICT_4X4_250", "--detector", "apriltag"]) == 2
    assert "AprilTag families only" in capsys.readouterr().err
    assert not (tmp_path / "m.yaml").exists()


def test_detect_folder_with_the_apriltag_library(tmp_path):
    """AprilTag images detected through the marker detector with the command's options: the
    corners of every tag, a repeated tag dropped and counted."""
    from rs_localizer.frontends.marker_detection import DetectorOptions, apriltag_binding
    from rs_localizer.mapping.outputs import detect_folder

    if apriltag_binding() is None:
        pytest.skip("no AprilTag library binding installed")
    scene = load_scene("apriltag_board")
    camera = camera_preset("vga", line_delay=0.0)
    renderer = Renderer(scene, camera)
    motion = make_motion("shake", scene, duration=0.2)
    images = tmp_path / "images"
    images.mkdir()
    gray = cv2.cvtColor(renderer.render(motion, 0.0).image, cv2.COLOR_RGB2GRAY)
    cv2.imwrite(str(images / "0000.png"), gray)
    twice = gray.copy()
    twice[:, 320:] = gray[:, :320]  # the left tags twice
    cv2.imwrite(str(images / "0001.png"), twice)
    frames, counts = detect_folder(
        images,
        camera,
        scene.dictionary,
        30.0,
        progress=False,
        detector_options=DetectorOptions(detector="apriltag", quad_decimate=1.0),
    )
    assert sorted(frames[0].corners) == list(range(12))
    truth, ok = renderer.project(
        np.concatenate([scene.marker_corners()[m] for m in range(12)]),
        motion,
        0.0,
        shutter="global",
        occlusion=False,
    )
    got = np.concatenate([frames[0].corners[m] for m in range(12)])
    assert ok.all() and np.median(np.linalg.norm(got - truth, axis=1)) < 0.15
    assert counts["duplicate_ids"] >= 2 and counts["images"] == 2
    assert len(frames[1].corners) + counts["duplicate_ids"] <= 12


def _z_error_deg(corners: dict, true: dict) -> float:
    """Angle between the map's z axis and the scene's up (z), after the rigid best fit of the
    map's corners onto the scene's (SciPy)."""
    ids = sorted(set(corners) & set(true))
    a = np.concatenate([corners[m] for m in ids])
    b = np.concatenate([true[m] for m in ids])
    rot, _ = Rotation.align_vectors(b - b.mean(0), a - a.mean(0))
    return float(np.degrees(np.arccos(np.clip(rot.as_matrix()[2, 2], -1.0, 1.0))))


@pytest.mark.slow
def test_gravity_frame_and_readout_from_a_bag_with_an_imu(rendered, tmp_path, capsys):
    """A bag with an accelerometer (render-bag --imu-rate): the default frame is z up from it,
    or from the aruco_room's three walls (--frame walls) or its floor markers (--frame
    floor); --calibrate-readout prints the line delay with its std and verdict under --quiet,
    writes it into the map, and gives the same value with the anchor's frame at
    --anchor-pose."""
    from rs_localizer.maps import load_marker_readout

    true, pose = rendered[3], rendered[4]
    bag = tmp_path / "bag"
    assert (
        main(["render-bag", str(bag), "--frames", "12", "--motion", "pan", "--imu-rate", "200"])
        == 0
    )
    capsys.readouterr()
    common = ["--marker-size", "0.3", "--dictionary", "DICT_4X4_250", "--calibrate-readout"]
    values = {}
    for name, extra in (
        ("imu", []),
        ("walls", ["--frame", "walls"]),
        ("floor", ["--frame", "floor"]),
        ("anchor", ["--anchor", "0", "--anchor-pose", *pose]),
    ):
        out = tmp_path / f"{name}.yaml"
        assert main(["map-markers", str(bag), "-o", str(out), *common, "--quiet", *extra]) == 0
        printed = capsys.readouterr().out
        assert "us/line" in printed and "+-" in printed and "observable" in printed
        r = load_marker_readout(out)
        assert r["calibrated"] and r["line_delay_std_s"] > 0 and "observable" in r
        values[name] = (r["line_delay_s"], r["line_delay_std_s"])
        frame = yaml.safe_load(out.read_text())["frame"]
        _, corners = load_marker_map(out)
        if name == "anchor":
            assert frame["kind"] == "anchor"
            continue
        assert frame["kind"] == "gravity" and frame["up_source"] == name
        # (the accelerometer: 12 frames of a pan, the map's own rotation error included)
        assert _z_error_deg(corners, true) < (1.2 if name == "imu" else 1.0)
    # the output frame does not change the calibrated line delay
    ld = np.array(list(values.values()))
    # (the same adjustment up to its gauge marker and start: within the solver's tolerance)
    assert np.abs(ld[:, 0] - ld[0, 0]).max() < 0.3 * ld[0, 1]
    assert np.allclose(ld[:, 1], ld[0, 1], rtol=0.05)
    # true: 30 ms over 480 lines
    assert abs(ld[0, 0] - 0.03 / 480) < 3 * ld[0, 1]
    assert load_marker_readout(tmp_path / "no_such.yaml") == {}


def test_summary_says_when_the_corner_offset_is_not_needed():
    """The summary names the corner offset's std, and says the term is not needed only when
    the offset is within 2 std of zero and the video fixes it to 0.025 px or better."""
    from types import SimpleNamespace

    from rs_localizer.cli.map_markers import _offset_note

    def note(co, std):
        return _offset_note(SimpleNamespace(corner_offset_px=co, corner_offset_std_px=std))

    assert "need no corner-offset term" in note(-0.004, 0.0125)
    assert "(std 0.01 px)" in note(-0.004, 0.0125)
    assert "need no" not in note(0.10, 0.012)  # (OpenCV's corners: inside the squares)
    assert "need no" not in note(0.01, 0.15)  # (too loosely fixed to tell)
    assert note(0.0, float("nan")) == ""  # (not estimated)
