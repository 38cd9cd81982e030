"""What a frame's estimate says of the gyro: one rule for a camera and a rig
(:meth:`rs_localizer.tracking.gyro_input.GyroInput.solved`)."""

from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

from rs_localizer.tracking.gyro_input import GyroInput


class _Log:
    def __init__(self):
        self.warnings = []

    def info(self, text):
        pass

    def warning(self, key, text, count=0):
        self.warnings.append((key, text))


def _estimate(success=True, used=False, rejected="", covariance=True):
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cov = np.diag(np.arange(1.0, 13.0)) if covariance else None
    return SimpleNamespace(
        success=success,
        gyro_used=used,
        gyro_rejected=bool(rejected),
        gyro_rejection=rejected,
        covariance=cov,
        pose=SimpleNamespace(orientation=R),
    )


@pytest.mark.parametrize("rig", [False, True], ids=["camera", "rig"])
def test_one_rule_counts_the_gyro_and_feeds_the_checks_with_posed_frames_only(rig):
    """A camera's and a rig's gyro input (the rig's keys ``rig.``-prefixed by its owner, its
    frames posed with the gyro counted ``gyro_used``): posed with the gyro counts it; a
    rejection counts it with its reason and warns; a failed frame counts no use; the checks
    are fed the posed frame's orientation and rotation covariance, a failed frame, a raised
    estimator (None) or a frame without covariance as the update's arguments say."""
    counts, log = Counter(), _Log()
    kw = {"what": "rig frame", "key": "rig.gyro", "used_key": "gyro_used"} if rig else {}
    gi = GyroInput(lambda k, n: counts.__setitem__(k, counts[k] + n), log, **kw)
    calls = []
    gi.update = lambda *a: calls.append(a)  # (what the mount check and the bias are fed)
    used = "gyro_used" if rig else "frames_with_gyro"

    gi.solved(1, _estimate(used=True), False)
    assert counts == {used: 1} and not log.warnings
    _, ok, R, cov, new = calls[-1]
    assert ok and not new
    np.testing.assert_array_equal(R, _estimate().pose.orientation)
    np.testing.assert_array_equal(cov, np.diag([1.0, 2.0, 3.0]))

    gi.solved(2, _estimate(rejected="contradicted"), True)
    assert counts["gyro_rejected"] == counts["gyro_rejected.contradicted"] == 1
    assert counts[used] == 1
    assert [k for k, _ in log.warnings] == ["rig.gyro.rejected" if rig else "gyro.rejected"]
    assert ("rig frame" if rig else "frame") in log.warnings[0][1]
    assert calls[-1][1] and calls[-1][4]  # (posed without the gyro: still a posed frame)

    gi.solved(3, _estimate(success=False, used=True), False)
    assert counts[used] == 1  # (not posed: no frame posed with the gyro)
    assert calls[-1][1:4] == (False, None, None)

    gi.solved(4, None, False)  # (the estimator raised)
    assert calls[-1][1:4] == (False, None, None)

    gi.solved(5, _estimate(used=True, covariance=False), False)
    assert counts[used] == 2 and calls[-1][1] and calls[-1][3] is None
