"""``python -m benchmarks.bench_markers`` on one frame: a row per detector (36h11 and the
ArUco dictionary), every frame posed, no false marker, the targets printed; the OpenCV
settings sweep."""

import pytest

from benchmarks.bench_markers import main
from rs_localizer.frontends.marker_detection import apriltag_binding


@pytest.mark.slow
def test_bench_markers_runs(capsys):
    args = ["--frames", "1", "--presets", "vga", "--decimate", "2", "--false-frames", "1"]
    assert main([*args, "--false-dictionaries", "DICT_APRILTAG_36h11"]) == 0
    out = capsys.readouterr().out
    assert "vga 640x480, 1 frames of apriltag_room" in out
    rows = [
        line
        for line in out.splitlines()
        if line.strip().startswith(("opencv", "apriltag")) and "|" in line
    ]
    # 36h11: opencv, opencv default (+ apriltag d2); DICT_4X4_250: opencv, opencv default
    assert len(rows) == (5 if apriltag_binding() else 4)
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
