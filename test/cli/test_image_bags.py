"""Image bags through the CLI: export-image --all with stamps, calibrate-readout without a map."""

import csv

import cv2
import numpy as np

from rs_localizer.cli import main as cli


def test_export_all_keeps_each_image_and_its_stamp(sample_images_bag, tmp_path):
    """Every image in bag order, the same pixels, and stamps.csv naming each file with its
    header stamp: the camera_info of the same frame carries the same stamp."""
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore
    from rs_localizer.ros.image_codec import decode_image

    out = tmp_path / "frames"
    assert cli(["export-image", str(sample_images_bag), str(out), "--all", "--quiet"]) == 0
    ts = typestore()
    images, info_stamps = [], []
    for topic, mt, _, raw in iter_messages(sample_images_bag, None):
        if topic == "/camera/image_raw":
            images.append(decode_image(ts.deserialize_cdr(raw, mt))[0])
        elif topic == "/camera/camera_info":
            st = ts.deserialize_cdr(raw, mt).header.stamp
            info_stamps.append(st.sec * 1_000_000_000 + st.nanosec)
    with open(out / "stamps.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["file"] for r in rows] == [f"{k:06d}.png" for k in range(len(images))]
    assert len(images) == 20 and sorted(set(info_stamps)) == [int(r["stamp_ns"]) for r in rows]
    for r, img in zip(rows, images, strict=True):
        back = cv2.imread(str(out / r["file"]), cv2.IMREAD_UNCHANGED)
        back = back if back.ndim == 2 else back[:, :, 0]
        np.testing.assert_array_equal(back, img if img.ndim == 2 else img[:, :, 0])


def test_calibrate_readout_on_images_without_a_map_says_how_to_get_one(
    sample_images_bag, tmp_path, capsys
):
    """An image bag whose sequence.json names no front end, calibrated with --frontend aruco
    but no map: the error names the missing map and the command that builds one together
    with the readout time (not 'no front end given': one was given)."""
    import json
    import shutil

    bag = tmp_path / "bag"
    shutil.copytree(sample_images_bag, bag)
    info = json.loads((bag / "sequence.json").read_text())
    del info["frontend"]
    (bag / "sequence.json").write_text(json.dumps(info))
    rc = cli(["calibrate-readout", str(bag), "--source", "image", "--frontend", "aruco"])
    err = capsys.readouterr().err
    assert rc == 2 and "needs its map" in err and "--frontend-map" in err, err
    assert "map-markers" in err and "--calibrate-readout" in err and "no front end" not in err


def test_replay_of_images_warns_when_the_line_delay_is_the_default(
    sample_images_bag, tmp_path, capsys
):
    """The line delay comes from the parameters or the bag's sequence.json; a bag without
    either replays with the default and says so (as the node does), once."""
    import json
    import shutil

    assert cli(["replay", str(sample_images_bag), "--quiet"]) == 0
    assert "rs.line_delay is the default" not in capsys.readouterr().err
    bag = tmp_path / "bag"
    shutil.copytree(sample_images_bag, bag)
    info = json.loads((bag / "sequence.json").read_text())
    del info["rs"]
    (bag / "sequence.json").write_text(json.dumps(info))
    assert cli(["replay", str(bag), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.count("warning: rs.line_delay is the default 30 us/line") == 1, err
    assert cli(["replay", str(bag), "--quiet", "-p", "rs.line_delay:=6.25e-05"]) == 0
    assert "rs.line_delay is the default" not in capsys.readouterr().err
    # the default value itself, set by the parameters or recorded in sequence.json: no warning
    assert cli(["replay", str(bag), "--quiet", "-p", "rs.line_delay:=3.0e-05"]) == 0
    assert "rs.line_delay is the default" not in capsys.readouterr().err
    info["rs"] = {"line_delay": 3e-05}
    (bag / "sequence.json").write_text(json.dumps(info))
    assert cli(["replay", str(bag), "--quiet"]) == 0
    assert "rs.line_delay is the default" not in capsys.readouterr().err
