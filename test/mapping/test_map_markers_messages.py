"""map-markers' messages: the tags never detected named, the lever arm of a frame whose origin
lies far from its anchor explained, the readout line's verdict."""

from types import SimpleNamespace

import numpy as np

from rs_localizer.cli.map_markers import _lever_arm
from rs_localizer.mapping.marker_map import _never_detected
from rs_localizer.mapping.outputs import readout_dict, readout_line


def test_tags_never_detected_are_named():
    obs = {0: {0: 1, 1: 1, 3: 1}, 1: {4: 1, 6: 1, 7: 1}}
    out = _never_detected(obs, {}, {})
    assert sorted(out) == [2, 5] and "never detected" in out[2]
    # (already left out for another reason: not named twice)
    assert sorted(_never_detected(obs, {5: "seen in 1 frame(s)"}, {})) == [2]
    # ids far apart (several sets of tags): not guessed
    assert _never_detected({0: {0: 1, 100: 1}}, {}, {}) == {}


def test_lever_arm_is_explained():
    # the anchor 6 m from the origin, the frame turned by 0.4 deg: 42 mm at the origin
    f = SimpleNamespace(kind="anchor", rotation_std_deg=0.4, position_std_mm=45.0)
    res = SimpleNamespace(anchor=3, marker_poses={3: (np.eye(3), np.array([6.0, 0.0, 0.0]))})
    msg = _lever_arm(res, f)
    expected = np.radians(0.4) * 6.0 * 1e3
    assert f"about {expected:.0f} mm" in msg and "6.0 m from the anchor" in msg
    assert "lever arm" in msg
    # the origin at the anchor: nothing to explain
    res.marker_poses[3] = (np.eye(3), np.zeros(3))
    assert _lever_arm(res, f) == ""


def test_readout_line_and_entry():
    r = SimpleNamespace(line_delay=62.5e-6, line_delay_std=1.5e-6, readout_verdict="")
    assert "62.500 +- 1.500 us/line" in readout_line(r, 480) and ": observable" in readout_line(r)
    d = readout_dict(r, 480)
    assert d["observable"] and np.isclose(d["readout_time_s"], 0.03) and d["calibrated"]
    r.readout_verdict = "too little rotation: relative std 0.2 > 0.05"
    assert "NOT observable: too little rotation" in readout_line(r)
    r.readout_verdict = None
    assert "not calibrated" in readout_line(r) and not readout_dict(r)["calibrated"]


def test_coverage_is_one_line_per_reason():
    """56 markers above --coverage-std make 1 + one line per reason, every marker named once
    under each of its reasons (the per-marker reasons stay in the report)."""
    from rs_localizer.cli.map_markers import coverage_lines

    cov = {}
    for m in range(56):
        why = [f"seen in {3 + m % 5} frames"] if m % 2 else []
        if m % 3 == 0:
            why.append("only from far (closest 4.1 m, 16 cm side)")
        if m % 7 == 0:
            why.append("only head-on (within 12 deg of its face normal)")
        text = ", ".join(why) if why else "far from the markers that fix the frame"
        cov[m] = f"std {11 + m} mm: {text}; views from closer and at an angle would fix it"
    lines = coverage_lines(cov, 0.01)
    assert len(lines) == 1 + 4 and lines[0].startswith("  56 markers above --coverage-std 10 mm")
    by = {ln.split(":")[0].strip(): ln for ln in lines[1:]}
    assert set(by) == {
        "seen in fewer than 10 frames",
        "only from far",
        "only head-on",
        "far from the markers that fix the frame",
    }
    far = [int(x) for x in by["only from far"].split(": ")[-1].split(", ")]
    assert far == [m for m in range(56) if m % 3 == 0]
    assert "19 markers, std 11-65 mm" in by["only from far"]
