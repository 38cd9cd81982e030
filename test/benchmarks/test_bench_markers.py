"""``python -m benchmarks.bench_markers`` on one frame: a row per detector (36h11 and the
ArUco dictionary), every frame posed, no false marker, the targets printed; the OpenCV
settings sweep; the corner error's causes (still and moving views, the straight-edge fit)."""

import numpy as np
import pytest

from benchmarks.bench_markers import _line_fit_corners, main, room
from rs_localizer.frontends.marker_detection import apriltag_binding
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import camera_preset
from rs_localizer.sim.trajectory import project_rs


@pytest.mark.slow
def test_bench_markers_runs(capsys):
    args = ["--frames", "1", "--presets", "vga", "--decimate", "2", "--false-frames", "1"]
    args += ["--corner-views", "0"]  # (test_bench_markers_corner_causes)
    assert main([*args, "--false-dictionaries", "DICT_APRILTAG_36h11"]) == 0
    out = capsys.readouterr().out
    assert "vga 640x480, 1 frames of apriltag_room" in out
    rows = [
        line
        for line in out.splitlines()
        if line.strip().startswith(("opencv", "apriltag")) and "|" in line
    ]
    # 36h11: opencv, opencv default (+ apriltag d2 and its edge-profile corners, d2 edge);
    # DICT_4X4_250: opencv, opencv default
    assert len(rows) == (6 if apriltag_binding() else 4)
    assert all(line.rstrip().endswith("1/1") for line in rows), rows  # every frame posed
    assert "markers reported 0" in out
    assert "with DICT_4X4_250 markers" in out and "targets" in out
    assert "false markers, DICT_APRILTAG_36h11:" in out and "(target 0) met" in out


@pytest.mark.slow
def test_bench_markers_opencv_sweep(capsys):
    args = ["--frames", "1", "--presets", "", "--false-frames", "0"]
    assert main([*args, "--opencv-sweep", "7:10,20:20"]) == 0
    out = capsys.readouterr().out
    lines = [x for x in out.splitlines() if x.strip().startswith("constant")]
    assert len(lines) == 2 and "constant    7 step  10" in lines[0], lines


def _fit_error(line_delay: float | None, distortion: bool) -> float:
    """Largest distance (px) between the straight-edge fit and the exact rolling-shutter
    corners of the room's tags in view, on one frame of its ``shake`` video."""
    scene = room()
    camera = camera_preset("vga", distortion=distortion, line_delay=line_delay)
    motion = make_motion("shake", scene, duration=1.0)
    worst = 0.0
    for X4 in scene.marker_corners().values():
        fit = _line_fit_corners(lambda P: project_rs(camera, motion, 0.1, P), X4)
        if np.isfinite(fit).all():
            exact, _ = project_rs(camera, motion, 0.1, X4)
            worst = max(worst, float(np.abs(fit - exact).max()))
    return worst


def test_line_fit_corners_exact_on_straight_edges():
    # no distortion, line delay 0: the edges are straight, the fitted corners the exact ones
    assert _fit_error(0.0, distortion=False) < 1e-6
    # the lens and the 30 ms readout bend the edges: the corners are off, by little
    assert 1e-4 < _fit_error(0.0, distortion=True) < 0.1
    assert 1e-5 < _fit_error(None, distortion=False) < 0.1


@pytest.mark.slow
def test_bench_markers_corner_causes(capsys):
    args = ["--frames", "1", "--presets", "vga", "--decimate", "0", "--false-frames", "0"]
    assert main([*args, "--aruco-dictionary", "", "--corner-views", "2"]) == 0
    out = capsys.readouterr().out
    if not apriltag_binding():
        return
    assert "each rendered still" in out
    rows = [x for x in out.splitlines() if x.startswith("  apriltag d") and x.count("|") == 2]
    assert [r.split()[1] for r in rows[-3:]] == ["d1", "d1.5", "d2"], rows
    fit = next(x for x in out.splitlines() if "perfect straight-edge quad fit" in x)
    assert float(fit.split("still ")[1].split()[0]) < 0.05, fit
    assert float(fit.split("moving ")[1].split()[0]) < 0.05, fit
    target = next(x for x in out.splitlines() if "corner error median, still views" in x)
    assert "on the moving RS video" in target, target
    # the estimator on the renderer's exact corners of the tags found: a row and the bound
    exact = next(x for x in out.splitlines() if x.startswith("  exact corners"))
    assert "0.000 0.000" in exact and exact.rstrip().endswith("1/1"), exact
    assert any(x.startswith("  exact + 0.07 px") for x in out.splitlines())
    assert "on the renderer's exact corners of the same tags: rotation" in out


@pytest.mark.slow
def test_bench_markers_refine_study(capsys):
    args = ["--frames", "1", "--presets", "", "--false-frames", "0", "--aruco-dictionary", ""]
    assert main([*args, "--corner-views", "0", "--refine-study"]) == 0
    out = capsys.readouterr().out
    rows = [x for x in out.splitlines() if x.strip().startswith("threshold")]
    assert len(rows) == 8, rows  # 2 videos x 2 thresholdings x 2 refinements
    for row in rows:
        stuck = int(row.split("left on a pixel")[1].split()[0])
        err = float(row.split("error median")[1].split()[0])
        assert err < 0.6, row
        if row.split(",")[1].split()[0] == "staged":
            assert stuck <= 1, row  # (corners refined off the contour's pixel)
