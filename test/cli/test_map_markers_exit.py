"""map-markers says in its exit code when a video was refused as another place (3) and the map
written from the other videos. The detection step is replaced by simulated detections (the
room of rs_localizer.sim.marker_room); the mapping and the writing run as the command runs
them."""

from pathlib import Path

import pytest
import yaml

import rs_localizer.cli.map_markers as mm
from rs_localizer.cli import main
from rs_localizer.mapping import FrameDetections
from rs_localizer.maps import load_marker_map
from rs_localizer.sim.marker_room import (
    RoomWalk,
    make_marker_room,
    room_camera,
    simulate_detections,
)


@pytest.mark.slow  # (two maps: about 6 s of CPU, 40 s on a loaded machine)
def test_a_refused_video_sets_exit_code_3(tmp_path, monkeypatch, capsys):
    camera = room_camera()
    room = make_marker_room(12, seed=0, size=(4.5, 4.0, 2.6))
    walk, _ = simulate_detections(room, camera, RoomWalk(centre=(2.25, 2.0)), 40, seed=1)
    other, _ = simulate_detections(
        make_marker_room(12, seed=9), camera, RoomWalk(centre=(3.0, 2.5)), 20, seed=2
    )
    videos = {
        "hall": [FrameDetections(s, d) for s, d in walk],
        "lab": [FrameDetections(s, {m + 100: c for m, c in d.items()}) for s, d in other],
    }

    def detect(src: Path, args):
        frames = videos[src.name]
        counts = {"images": len(frames), "without_markers": 0, "duplicate_ids": 0}
        return camera, frames, counts

    monkeypatch.setattr(mm, "_detect", detect)
    K = camera.K
    cam = tmp_path / "camera.yaml"
    cam.write_text(
        yaml.safe_dump(
            {
                "image_width": 640,
                "image_height": 480,
                "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
                "distortion_model": "plumb_bob",
                "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5},
            }
        )
    )
    for name in videos:
        (tmp_path / name).mkdir()
    out = tmp_path / "map.yaml"
    argv = ["map-markers", str(tmp_path / "hall"), str(tmp_path / "lab"), "-o", str(out)]
    argv += ["--camera", str(cam), "--marker-size", "0.2", "--quiet"]
    sizes = ",".join(f"{int(i)}:{s}" for i, s in zip(room.ids, room.sides, strict=True))
    code = main([*argv, "--marker-sizes", sizes])
    err = capsys.readouterr().err
    assert code == mm.EXIT_REFUSED_VIDEO == 3, err
    assert "lab: refused" in err and "written from 1 of the 2 videos, 1 refused" in err
    _, corners = load_marker_map(out)  # (the hall's markers only)
    assert corners and all(m < 100 for m in corners)
    # the same run without the other place: exit code 0
    code = main([*argv[:2], *argv[3:], "--marker-sizes", sizes, "--overwrite"])
    assert code == 0 and "refused" not in capsys.readouterr().err
