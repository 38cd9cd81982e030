"""benchmarks.bench_real_markers on the real photos of ``shared/data/real_markers`` (skipped
when absent): its tables, the default corners as the library's, the small-tag rows."""

import re

import pytest

from benchmarks.bench_real_markers import DATA, main
from rs_localizer.frontends.marker_detection import DetectorOptions, apriltag_binding


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="no real marker photos (shared/data)")
@pytest.mark.skipif(apriltag_binding() is None, reason="no AprilTag library binding installed")
def test_bench_real_markers_runs(capsys):
    assert main(["--small", "--repeats", "1", "--render-frames", "0"]) == 0
    out = capsys.readouterr().out
    tags, board = out.split("opencv_aruco_tutorial")[:2]
    rows = {line.split("  ")[0].strip(): line for line in tags.splitlines() if "/" in line}
    for name in ("library", "edge profile", "cornerSubPix", "default"):
        assert name in rows, name
    assert all(n in board for n in ("library", "edge profile", "cornerSubPix"))
    # the default corners are the library's unless the edge profiles are on by default
    same = rows["default"].split()[1:] == rows["library"].split()[1:]
    assert same != DetectorOptions().edge_refinement
    small = [line for line in out.splitlines() if line.startswith("default + small_tags")]
    dflt = [line for line in out.splitlines() if line.startswith("default (by image size)")]
    assert len(small) == 1 and len(dflt) == 1
    found = [int(re.search(r" (\d+)/\d+ ", line[0]).group(1)) for line in (small, dflt)]
    assert found[0] > found[1], found
