"""Images and windows smaller than the detector libraries take: the AprilTag 3 library ends
the process (SIGFPE, SIGSEGV) on images of a few pixels, OpenCV raises on empty ones. Each
tiny or degenerate shape goes through the detectors, the corner refinements and the node's
pipeline in a child process, which must survive and report a clear refusal (a ValueError
from the detectors, ``bad_image`` from the pipeline) or no detections (windows off the image
or empty)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rs_localizer.frontends import marker_detection as md
from rs_localizer.frontends.image import MIN_IMAGE_SIDE, check_image_size

#: (H, W) below the front ends' minimum: empty, a few pixels, one row or column
TINY = [(0, 0), (1, 1), (2, 2), (3, 3), (1, 7), (7, 1), (640, 1), (1, 640), (4, 640), (640, 4)]
#: (H, W) the front ends take
TAKEN = [(MIN_IMAGE_SIDE, MIN_IMAGE_SIDE), (16, 640), (640, 16), (48, 64)]
#: windows (x0, y0, x1, y1) of a 64x48 frame: off it, empty, reversed, not finite, on it
WINDOWS = {
    "left of the image": (-40, 0, -10, 48),
    "below the image": (0, 60, 64, 90),
    "right of the image": (64, 0, 80, 48),
    "empty": (10, 10, 10, 30),
    "reversed": (30, 30, 10, 10),
    "not finite": (float("nan"), 0, 20, 20),
    "one pixel": (20, 20, 21, 21),
    "across the border": (-5, -5, 8, 8),
    "the whole frame": (0, 0, 64, 48),
}
OFF_IMAGE = {"left of the image", "below the image", "right of the image", "empty", "reversed"}


def _child(code: str, timeout: float = 120.0) -> dict:
    """Run ``code`` in a child Python (it prints one JSON line last); a crash fails the test
    with the child's exit status (e.g. -8: SIGFPE, -11: SIGSEGV) and its output."""
    r = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    tail = f"{r.stdout[-2000:]}{r.stderr[-3000:]}"
    assert r.returncode == 0, f"child exited with {r.returncode}\n{tail}"
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_min_image_side_covers_the_decimation():
    """The AprilTag library needs MIN_DECIMATED_SIDE px after its decimation."""
    assert md.min_image_side() == MIN_IMAGE_SIDE == 16
    assert md.min_image_side(1.5) == 16 and md.min_image_side(2.0) == 16
    assert md.min_image_side(4.0) == 32 and md.min_image_side(3.0) == 24
    for shape in TINY:
        with pytest.raises(ValueError, match=f"smaller than the {MIN_IMAGE_SIDE}x"):
            check_image_size(shape)
    for shape in TAKEN:
        check_image_size(shape)


def test_clip_window():
    """Windows clipped to the frame, grown to the minimum, None when nothing is left."""
    shape = (48, 64)
    for name, win in WINDOWS.items():
        got = md.clip_window(win, shape, 16)
        if name in OFF_IMAGE or name == "not finite":
            assert got is None, name
            continue
        x0, y0, x1, y1 = got
        assert 0 <= x0 < x1 <= 64 and 0 <= y0 < y1 <= 48, (name, got)
        assert x1 - x0 >= 16 and y1 - y0 >= 16, (name, got)
    assert md.clip_window((0, 0, 64, 48), shape, 16) == (0, 0, 64, 48)
    assert md.clip_window((2, 3, 10, 40), shape, 16) == (0, 3, 16, 40)  # (grown about 6)
    assert md.clip_window((60, 0, 64, 48), shape, 16) == (48, 0, 64, 48)  # (within the frame)
    with pytest.raises(ValueError, match="a window is"):
        md.clip_window((1, 2, 3), shape, 16)


_DETECTORS = """
import json, warnings
import numpy as np
from rs_localizer.frontends import marker_detection as md
TINY, TAKEN, WINDOWS = json.loads({params!r})
dets = {{"opencv": md.make_marker_detector("DICT_4X4_50")}}
if md.apriltag_binding() is not None:
    dets["apriltag"] = md.make_marker_detector("tag36h11")
    dets["apriltag_q4"] = md.make_marker_detector("tag36h11", md.DetectorOptions(quad_decimate=4))
out = {{}}
rng = np.random.default_rng(0)
for name, det in dets.items():
    for h, w in TINY + TAKEN:
        g = rng.integers(0, 256, (h, w), dtype=np.uint8)
        key = f"{{name}} {{h}}x{{w}}"
        print(key, flush=True)  # (the last shape printed before a crash)
        try:
            c, ids, _ = det.detect(g)
            out[key] = ["ok", len(ids)]
        except ValueError as e:
            out[key] = ["ValueError", str(e)]
    frame = rng.integers(0, 256, (48, 64), dtype=np.uint8)
    for wname, win in WINDOWS.items():
        key = f"{{name}} window {{wname}}"
        print(key, flush=True)
        try:
            c, ids, _ = det.detect_window(frame, tuple(float(v) for v in win))
            out[key] = ["ok", len(ids)]
        except ValueError as e:
            out[key] = ["ValueError", str(e)]
# the corner refinements: tiny images, corners off the image and not finite, cells 0
for h, w in TINY + TAKEN:
    g = np.zeros((h, w), np.uint8)
    corners = np.array([[[-3.0, -3.0], [w + 2.0, 0.5], [w + 2.0, h + 2.0], [0.5, h + 2.0]],
                        [[np.nan, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]]])
    for fn in ("refine_corners", "refine_tag_edges"):
        key = f"{{fn}} {{h}}x{{w}}"
        print(key, flush=True)
        try:
            got = getattr(md, fn)(g, corners, 6)
            same = bool(np.array_equal(got, corners, equal_nan=True))
            out[key] = ["ok", same]
        except ValueError as e:
            out[key] = ["ValueError", str(e)]
for fn in ("refine_corners", "refine_tag_edges"):
    for cells in (0, -1, 2.5):
        key = f"{{fn}} cells {{cells}}"
        try:
            getattr(md, fn)(np.zeros((40, 40), np.uint8), np.full((1, 4, 2), 10.0), cells)
            out[key] = ["ok"]
        except ValueError as e:
            out[key] = ["ValueError", str(e)]
print(json.dumps(out))
"""


def test_detectors_refuse_tiny_images_and_survive():
    """Every detector (OpenCV, the AprilTag library at its default and at quad_decimate 4),
    its window search and the corner refinements, on each tiny shape, in a child process:
    images below the minimum refused with a ValueError naming it, the ones at or above it
    searched (a 16x16 image at quad_decimate 4 is refused: 32 px needed), windows off the image
    or empty give no detections, the others are clipped and searched; corners off the image
    or not finite keep their position; cells 0 refused."""
    out = _child(_DETECTORS.format(params=json.dumps([TINY, TAKEN, WINDOWS])))
    names = {k.split()[0] for k in out}
    assert "opencv" in names
    for key, res in out.items():
        name, rest = key.split(" ", 1)
        if name.startswith("refine_"):
            if rest.startswith("cells"):
                assert res[0] == "ValueError" and "cells must be an integer >= 1" in res[1], key
            else:
                assert res == ["ok", True], (key, res)  # (nothing to refine: kept as given)
            continue
        if rest.startswith("window"):
            assert res == ["ok", 0], (key, res)  # (a random frame: no markers)
            continue
        h, w = (int(v) for v in rest.split("x"))
        need = 32 if name == "apriltag_q4" else MIN_IMAGE_SIDE
        if min(h, w) < need:
            assert res[0] == "ValueError" and f"smaller than the {need}x{need}" in res[1], (
                key,
                res,
            )
        else:
            assert res == ["ok", 0], (key, res)
    if md.apriltag_binding() is not None:
        assert {"apriltag", "apriltag_q4"} <= names


_PIPELINE = """
import json, sys, time
sys.path.insert(0, {test_dir!r})  # (the tests' helpers)
import numpy as np
from rs_localizer.camera import CameraModel
from rs_localizer.ros import config as C, params as P
from rs_localizer.ros.bags.bag_io import RosbagsMessages
from rs_localizer.ros.frame_queue import FrameQueue, frame_accounting
from helpers.camera_node import CameraNode
SHAPES = {shapes!r}
msgs = RosbagsMessages()
cfg = C.build_config({{**P.default_values(), "camera_info_wait": 0.0, "frontend": "aruco",
                      "frontend_map": "apriltag_board", "tracking.enabled": False}})
maps = C.load_maps(cfg.camera, owner=object())
out = {{}}
rng = np.random.default_rng(1)
for k, (h, w) in enumerate(SHAPES):
    key = f"{{h}}x{{w}}"
    print(key, flush=True)
    pipe = CameraNode(cfg, maps=maps)
    stamp = (k + 1) * 10**8
    ch, cw = max(h, 1), max(w, 1)  # (a camera_info of the image's size; 1x1 for 0x0)
    cam = CameraModel(K=np.array([[400.0, 0, cw / 2], [0, 400.0, ch / 2], [0, 0, 1]]),
                      width=cw, height=ch, line_delay=1e-5)
    assert pipe.add_camera_info(msgs.camera_info(cam, 0, "cam")) is not None
    img = msgs.image(rng.integers(0, 256, (h, w), dtype=np.uint8), stamp, "cam")
    results = []
    def process(m):
        r = pipe.process(m, "image")
        pipe.stats.frame_done(0.0, "solved" if r.failure is None else "failed." + r.failure)
        return r

    q = FrameQueue(process, lambda m, r: results.append(r), counts_of=lambda m: pipe.stats)
    q.start()
    q.put(img, 10)
    end = time.monotonic() + 60
    while q.pending and time.monotonic() < end:
        time.sleep(0.01)
    q.stop()
    c = frame_accounting(pipe.stats.counts())
    (res,) = results
    out[key] = [res.failure, res.detail, c.received, c.solved + c.failed + c.skipped + c.pending,
                c.failures]
print(json.dumps(out))
"""


def test_node_pipeline_counts_tiny_images_as_bad_image():
    """The single-camera node's pipeline (no DDS) with the AprilTag front end on a tag map:
    each tiny image, with a camera_info of the same size, dropped as ``bad_image`` naming the
    minimum, the frame accounted for (through the node's frame queue: received = failed, under
    that reason); the process survives; images of the minimum size and
    larger reach the front end (which finds no tags in noise)."""
    shapes = TINY + TAKEN
    out = _child(
        _PIPELINE.format(shapes=shapes, test_dir=str(Path(__file__).parents[1])), timeout=240.0
    )
    for (h, w), key in zip(shapes, out, strict=True):
        failure, detail, received, accounted, failures = out[key]
        assert received == accounted == 1 and failures == {failure: 1}, (key, out[key])
        if min(h, w) < MIN_IMAGE_SIDE:
            assert failure == "bad_image", (key, out[key])
            assert "empty image" in detail or f"smaller than the {MIN_IMAGE_SIDE}x" in detail
        else:
            assert failure == "frontend_too_few_points", (key, out[key])


_RIG = """
import json
import numpy as np
from rs_localizer.camera import CameraModel
from rs_localizer.frames import Mounting
from rs_localizer.frontends import make_frontend
from rs_localizer.sim.render import vga_rig
from rs_localizer.tracking.video import Localizer, LocalizerSettings
SHAPES = {shapes!r}
cams = vga_rig(2)
mounts = {{c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}}
rig = Localizer(LocalizerSettings(mounts))
for c in cams:
    rig.set_frontend(c.name, make_frontend("aruco", "apriltag_board"), "aruco")
name = cams[0].name
rng = np.random.default_rng(2)
for k, (h, w) in enumerate(SHAPES):
    print(f"{{h}}x{{w}}", flush=True)
    ch, cw = max(h, 1), max(w, 1)
    cam = CameraModel(K=np.array([[400.0, 0, cw / 2], [0, 400.0, ch / 2], [0, 0, 1]]),
                      width=cw, height=ch, line_delay=1e-5)
    img = rng.integers(0, 256, (h, w), dtype=np.uint8)
    rig.process_image(name, (k + 1) * 10**8, img, cam, "mono8")
rig.close()
counts = {{k: v for k, v in rig.counts.items() if k.startswith(name)}}
print(json.dumps([rig.camera_counts(name), counts]))
"""


def test_rig_images_of_tiny_size_are_skipped_and_the_process_survives():
    """The rig's library path (``Localizer.process_image``, what the rig node calls) with
    an AprilTag front end on each tiny image: the detector refuses it (a ValueError instead of
    the library's SIGFPE / SIGSEGV), the image is skipped as ``frontend_error`` and counted;
    the process survives."""
    out = _child(_RIG.format(shapes=TINY), timeout=240.0)
    per_camera, counts = out
    assert per_camera["received"] == len(TINY), out
    assert per_camera["received"] == sum(
        per_camera[k] for k in ("solved", "failed", "skipped", "pending")
    ), out
    assert per_camera["skipped"] == len(TINY), out
    assert any("frontend_error" in k and v == len(TINY) for k, v in counts.items()), counts
