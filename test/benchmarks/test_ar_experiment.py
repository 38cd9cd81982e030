"""The paper's AR experiment (quick variant): RS solvers vs P3P on rendered ArUco sequences."""

import numpy as np
import pytest

from benchmarks.ar_experiment import SOLVERS_AR, cube_edges, project_estimate, run
from rs_localizer.sim.render import camera_preset


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("ar")
    return out, run(out, quick=True, verbose=False)


def test_rs_solvers_beat_p3p_on_shake(quick):
    _, res = quick
    s = res["rolling"]["summary"]
    assert res["rolling"]["info"]["angular_speed_rad_s"][1] > 0.8  # hand-held, fast
    for k in SOLVERS_AR:
        assert s[k]["success"] == 1.0
    for k in SOLVERS_AR[1:]:
        # clearly below P3P's median rotation and position errors
        assert s[k]["factor_rot"] > 5, (k, s[k])
        assert s[k]["factor_pos"] > 5, (k, s[k])
        assert s[k]["reproj_px_median"] < 0.5 * s["p3p"]["reproj_px_median"]
        assert s[k]["angvel_median"] < 0.3  # rad/s, camera-frame angular velocity


def test_rs_solvers_match_p3p_on_global_shutter(quick):
    _, res = quick
    s = res["global"]["summary"]
    for k in SOLVERS_AR[1:]:
        assert s[k]["rot_deg_median"] <= 2.0 * s["p3p"]["rot_deg_median"] + 0.005, (k, s)
        assert s[k]["pos_m_median"] <= 2.0 * s["p3p"]["pos_m_median"] + 0.002, (k, s)
        assert s[k]["reproj_px_median"] <= 1.2 * s["p3p"]["reproj_px_median"]


def test_outputs_written(quick):
    out, res = quick
    for name in (
        "reprojection_hist.png",
        "ar_overlay.png",
        "errors.png",
        "report.md",
        "results.json",
    ):
        assert (out / name).stat().st_size > 1000, name
    report = (out / "report.md").read_text()
    assert "holds" in report and "p3p" in report
    assert "**Quick run**" in report and "noisy" in report  # quick verdicts say so
    cube = res["rolling"]["cube_px"]
    assert np.median(cube["r6p_1lin"]) < 0.3 * np.median(cube["p3p"])


def test_project_estimate_global_and_cube():
    cam = camera_preset("vga")
    X = cube_edges().reshape(-1, 3) - [2.0, 0.0, 1.2] + [0.0, 0.0, 2.0]  # in front, camera frame
    R, C = np.eye(3), np.zeros(3)
    uv = project_estimate(R, C, np.zeros(3), np.zeros(3), cam, X)
    np.testing.assert_allclose(uv, cam.distort(X[:, :2] / X[:, 2:]), atol=1e-9)
    # with motion: each point satisfies the RS constraint at its own (distorted) row
    w, t = np.array([0.0, 0.02, 0.0]), np.array([0.01, 0.0, 0.0])
    uv = project_estimate(R, C, w, t, cam, X)
    tau = cam.rs_coordinate(uv) - cam.r0
    from rs_localizer.geometry import rotvec_to_matrix

    p = np.einsum("nij,nj->ni", rotvec_to_matrix(tau[:, None] * w), X) + tau[:, None] * t
    np.testing.assert_allclose(cam.distort(p[:, :2] / p[:, 2:]), uv, atol=1e-6)
