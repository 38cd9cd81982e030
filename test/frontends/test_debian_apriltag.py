"""Debian's AprilTag binding (``python3-apriltag``) raises ``RuntimeError("Unable to create N
threads for detector")`` on a frame without tags whenever the calling thread's ``errno`` is
``EAGAIN`` (left behind by any earlier non-blocking call, such as a lock Python tried): the
detector reads that as no detection, not as an error. With the Debian module installed (the
distro profile) the real binding is driven into that state; a stand-in raising the same
error covers the other installs."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from rs_localizer.frontends import marker_detection as md


def _debian_module():
    try:
        import apriltag
    except (ImportError, OSError):
        return None
    return apriltag if callable(getattr(apriltag, "apriltag", None)) else None


DEBIAN = _debian_module()


def _leave_eagain() -> None:
    """A lock tried while held: ``sem_trywait`` fails with ``EAGAIN`` in this thread."""
    lock = threading.Lock()
    lock.acquire()
    assert not lock.acquire(False)


@pytest.mark.skipif(DEBIAN is None, reason="Debian's python3-apriltag is not installed")
def test_debian_binding_frame_without_tags_is_no_detection():
    det = md.AprilTagDetector("tag36h11", binding=("apriltag", DEBIAN))
    gray = np.full((64, 80), 128, np.uint8)
    raw = DEBIAN.apriltag("tag36h11", threads=1)
    _leave_eagain()
    with pytest.raises(RuntimeError, match="Unable to create"):
        raw.detect(gray)  # (the binding's own behaviour this guards against)
    for _ in range(3):
        _leave_eagain()
        corners, ids, hamming, margins = det.raw(gray)
        assert corners.shape == (0, 4, 2) and len(ids) == len(hamming) == len(margins) == 0


class _Raising:
    def __init__(self, message: str):
        self.message = message

    def detect(self, gray):
        raise RuntimeError(self.message)


def test_only_the_debian_eagain_error_is_taken_as_no_detection():
    gray = np.zeros((32, 32), np.uint8)
    eagain = _Raising("Unable to create 1 threads for detector")
    assert tuple(md._library_detect(eagain, gray, "apriltag")) == ()
    with pytest.raises(RuntimeError, match="Unable to create"):  # (pupil_apriltags: raised)
        md._library_detect(eagain, gray, "pupil_apriltags")
    with pytest.raises(RuntimeError, match="out of memory"):
        md._library_detect(_Raising("out of memory"), gray, "apriltag")
