"""``python -m benchmarks.bench_markers`` on one frame: a row per detector, every frame
posed, no false marker."""

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
    assert len(rows) == (2 if apriltag_binding() else 1)
    assert all(line.rstrip().endswith("1/1") for line in rows), rows  # every frame posed
    assert "markers reported 0" in out
