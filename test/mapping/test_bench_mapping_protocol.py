"""The marker-map benchmark compares localization against two maps on the frames both solve:
a map that fails on the hard frames must not look better for it."""

import numpy as np

from rs_localizer.evaluation.bench_mapping import paired_ratios


def _result(per_frame: dict) -> dict:
    rot = [r for r, _ in per_frame.values()]
    pos = [p for _, p in per_frame.values()]
    return dict(
        frames=10,
        solved=len(per_frame),
        rotation_deg=float(np.median(rot)),
        position_cm=float(np.median(pos)),
        per_frame=per_frame,
    )


def test_ratios_are_taken_over_the_frames_both_maps_solve():
    rng = np.random.default_rng(0)
    ref = {k: (float(rng.uniform(0.1, 2.0)), float(rng.uniform(0.5, 5.0))) for k in range(10)}
    # the other map: twice the reference's errors, but it fails on the five hardest frames
    hard = sorted(ref, key=lambda k: -ref[k][0])[:5]
    other = {k: (2 * r, 2 * p) for k, (r, p) in ref.items() if k not in hard}
    rr, rp, both = paired_ratios(_result(other), _result(ref))
    assert both == 5
    assert np.isclose(rr, 2.0) and np.isclose(rp, 2.0)
    # the medians over each map's own frames would hide most of that
    naive = _result(other)["rotation_deg"] / _result(ref)["rotation_deg"]
    assert naive < 0.85 * rr


def test_no_frame_in_common_gives_nan():
    a, b = _result({0: (1.0, 1.0)}), _result({1: (1.0, 1.0)})
    rr, rp, both = paired_ratios(a, b)
    assert both == 0 and np.isnan(rr) and np.isnan(rp)
