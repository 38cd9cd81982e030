"""``rs-localizer map-markers`` with two videos and a frame fixed by surveyed markers, on rendered
rolling-shutter images of the built-in aruco_room (the map against the scene's true corners),
the summary's frame line, and refusals before any mapping."""

import cv2
import numpy as np
import pytest
import yaml

from rs_localizer.cli import main
from rs_localizer.maps import load_marker_map, write_marker_map
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import Renderer, camera_preset, frame_times
from rs_localizer.sim.render.scene import load_scene

#: the bundle adjustments of these tests take 10-70 s each
pytestmark = pytest.mark.slow

FRAMES = 16


@pytest.fixture(scope="module")
def two_videos(tmp_path_factory):
    """One rendered pan cut in two folders (two videos of one place), the camera YAML."""
    root = tmp_path_factory.mktemp("map_markers_frame")
    scene = load_scene("aruco_room")
    camera = camera_preset("vga", readout_time=0.03)
    motion = make_motion("pan", scene, duration=FRAMES / 30)
    renderer = Renderer(scene, camera)
    folders = [root / "first", root / "second"]
    for f in folders:
        f.mkdir()
    for i in range(FRAMES):
        fr = renderer.render(motion, float(frame_times(i)), index=i)
        out = folders[i * 2 // FRAMES] / f"{i:04d}.png"
        cv2.imwrite(str(out), cv2.cvtColor(fr.image, cv2.COLOR_RGB2BGR))
    cam = root / "camera.yaml"
    cam.write_text(
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
    return root, folders, cam


def command(root, folders, cam, out, *extra):
    return [
        "map-markers",
        *map(str, folders),
        "-o",
        str(out),
        "--camera",
        str(cam),
        "--marker-size",
        "0.3",
        "--dictionary",
        "DICT_4X4_250",
        *extra,
    ]


def test_two_videos_in_the_frame_of_surveyed_markers(two_videos, capsys):
    root, folders, cam = two_videos
    dictionary, true = load_marker_map("aruco_room")
    survey = write_marker_map(root / "survey.yaml", dictionary, {m: true[m] for m in (0, 1, 2)})
    out = root / "map.yaml"
    assert main(command(root, folders, cam, out, "--survey", str(survey))) == 0
    printed = capsys.readouterr().out
    assert "frame: surveyed (0, 1, 2" in printed and "alone:" in printed
    _, corners = load_marker_map(out)
    e = np.concatenate([np.linalg.norm(corners[m] - true[m], axis=1) for m in corners])
    assert len(corners) >= 20 and np.median(e) < 0.04, np.median(e)
    doc = yaml.safe_load(out.read_text())
    assert doc["frame"]["kind"] == "surveyed" and doc["frame"]["anchors"] == [0, 1, 2]
    assert doc["frame"]["rotation_std_deg"] >= 0


def test_refusals_before_mapping(two_videos, capsys):
    root, folders, cam = two_videos
    out = root / "refused.yaml"
    survey = root / "survey.yaml"
    if not survey.exists():
        dictionary, true = load_marker_map("aruco_room")
        write_marker_map(survey, dictionary, {0: true[0]})
    assert main(command(root, folders, cam, out, "--survey", str(survey), "--anchor", "0")) == 2
    assert "--survey fixes the frame" in capsys.readouterr().err
    missing = root / "nosuch"
    assert main(command(root, [folders[0], missing], cam, out)) == 2
    assert "nosuch" in capsys.readouterr().err
    assert not out.exists()
