"""``render-bag --rig`` at 1280x720 and with mixed resolutions (``--rig-cameras hd vga``): every
camera's camera_info and images have its preset's size, its marker front end finds
correspondences, and the rig replays; a preset count that does not fit is a one-line error."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("rosbags")


@pytest.mark.slow
def test_a_rig_of_an_hd_and_a_vga_camera(tmp_path, capsys):
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore
    from rs_localizer.sim.render.renderer import CAMERA_PRESETS

    bag = tmp_path / "rig"
    argv = ["render-bag", str(bag), "--rig", "2", "--rig-cameras", "hd", "vga", "--frames", "3",
            "--supersample", "1", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    ts = typestore()
    want = {"front": CAMERA_PRESETS["hd"][:2], "back": CAMERA_PRESETS["vga"][:2]}
    assert want["front"] == (1280, 720) and want["back"] == (640, 480)
    sizes: dict = {}
    for topic, mt, _, raw in iter_messages(bag):
        if mt.endswith(("CameraInfo", "Image")):
            m = ts.deserialize_cdr(raw, mt)
            sizes.setdefault(topic, set()).add((int(m.width), int(m.height)))
    for cam, wh in want.items():
        assert sizes[f"/rig/{cam}/camera_info"] == {wh}
        assert sizes[f"/rig/{cam}/image_raw"] == {wh}
    meta = json.loads((bag / "sequence.json").read_text())
    assert all(v > 0 for v in meta["settings"]["correspondences_per_frame"].values())
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["solved"] == s["frames_total"] == 3


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--rig", "3", "--rig-cameras", "hd", "vga"], "2 presets for --rig 3"),
        (["--rig-cameras", "hd"], "it needs --rig N"),
        (["--rig", "2", "--camera", "hd", "--rig-cameras", "hd", "vga"], "not both"),
    ],
)
def test_camera_presets_that_do_not_fit(tmp_path, capsys, extra, message):
    from rs_localizer.cli import main

    capsys.readouterr()
    assert main(["render-bag", str(tmp_path / "b"), "--frames", "1", "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
