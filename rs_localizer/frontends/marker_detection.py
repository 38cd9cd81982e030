"""Square fiducial markers in a grayscale image: one interface, two detectors.

:func:`make_marker_detector` picks the detector from the marker map's ``dictionary``:

* AprilTag families (OpenCV's ``DICT_APRILTAG_16h5``, ``_25h9``, ``_36h10``, ``_36h11`` or the
  AprilTag library's own names, :data:`APRILTAG_FAMILIES`: ``tag36h11``, ``tagStandard41h12``,
  ``tagCircle21h7``...) go to the AprilTag 3 C library (the detector of ``apriltag_ros`` and
  ``isaac_ros_apriltag``), through either Python binding: ``pupil_apriltags`` (PyPI wheel,
  library 3.1) or Debian's ``python3-apriltag`` (module ``apriltag``, library 3.3; no
  ``decode_sharpening`` option, the library's default 0.25 is used).
* ArUco dictionaries (``DICT_4X4_50`` ... ``DICT_ARUCO_ORIGINAL``) go to OpenCV's ArUco
  detector (:class:`~rs_localizer.cv_compat.MarkerDetector`), with an adaptive
  threshold constant of 20 grey levels and two thresholding passes (window step 20) instead of
  OpenCV's 7 and three: on textured walls OpenCV's defaults turn every dark speck into a marker
  candidate, each one warped and identified (about 300 candidates per 640x480 frame of
  ``apriltag_room``; 15 with these settings and the front end's smallest perimeter, which find
  as many markers there and on the plain ``aruco_room``: ``python -m benchmarks.bench_markers``).
  Their corners are refined in stages (:func:`refine_corners`), not by OpenCV's one window.

Both return the same thing: corners (M, 4, 2) float64 in distorted pixels, in OpenCV's ArUco
order (for ArUco dictionaries the printed marker's top-left, top-right, bottom-right,
bottom-left, clockwise in the image; for AprilTag families printed from the AprilTag library's
images its bottom-right, bottom-left, top-left, top-right: OpenCV's ``DICT_APRILTAG_*`` images
are those turned by 180 degrees; ``docs/marker_maps.md``, "Corner order"), with OpenCV's pixel
convention (integer coordinates at pixel centres). The AprilTag library
reports its corners in another order (bottom-left, bottom-right, top-right, top-left of the tag
seen with its y axis up, i.e. :data:`APRILTAG_TO_ARUCO_ORDER` away from ArUco's) and with
integer coordinates at pixel corners, half a pixel off in x and y; both are converted here
(measured on the renderer's exact corners: ``test/frontends/test_marker_detection.py``). The
detector returns the library's corners. With ``edge_refinement`` the corners of the families
whose black square is framed by the tag's white border (36h11, 36h10, 25h9, 16h5) are refined
from their edges' grey-level profiles (:func:`refine_tag_edges`): on renders (640x480 frames of
a textured room) the median corner error drops from 0.12 to 0.03 px, but on real photos with a
calibrated camera the refined corners fit their squares and the board worse than the library's
(``python -m benchmarks.bench_real_markers``), so it is off by default.

Detections are refused when weak (AprilTag: more corrected bits than ``max_hamming`` or a
decision margin below ``min_decision_margin``) and an id found more than once in one image is
dropped from that image; both are counted (``last_weak``, ``last_duplicates``). Both detectors
also search windows of a frame (``detect_window``: the front end's predicted search) with the
frame's settings.

Images smaller than the libraries take are refused before they are called (a
:class:`ValueError`: both sides at least :data:`~rs_localizer.frontends.image.MIN_IMAGE_SIDE`
px, and for the AprilTag library :data:`MIN_DECIMATED_SIDE` px after its decimation,
:func:`min_image_side`); a search window is clipped to the frame, skipped when nothing of it
is left, grown within the frame to that size when smaller. Corners whose refinement window
or profiles do not fit in the image keep their position.

Without an AprilTag binding installed an OpenCV dictionary name of an AprilTag family
(``DICT_APRILTAG_36h11``) falls back to OpenCV's detector: slower on textured images and
less exact (at 640x480 on ``apriltag_room``: 1.6x the CPU time, 2.5x the corner error, with the
settings above; 49x the time with OpenCV's defaults). The detector says so (``fallback``, a
:class:`RuntimeWarning` at construction) so that the caller can report it.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "APRILTAG_FAMILIES",
    "APRILTAG_INSTALL",
    "APRILTAG_TO_ARUCO_ORDER",
    "DETECTOR_BACKENDS",
    "OPENCV_APRILTAG_FAMILIES",
    "AprilTagDetector",
    "DetectorOptions",
    "OpenCVDetector",
    "apriltag_binding",
    "apriltag_family",
    "auto_decimate",
    "drop_duplicates",
    "make_marker_detector",
    "min_image_side",
    "refine_corners",
    "refine_tag_edges",
    "supported_dictionaries",
]

#: OpenCV's dictionary names of the AprilTag families -> the AprilTag library's family names
OPENCV_APRILTAG_FAMILIES = {
    "DICT_APRILTAG_16h5": "tag16h5",
    "DICT_APRILTAG_25h9": "tag25h9",
    "DICT_APRILTAG_36h10": "tag36h10",
    "DICT_APRILTAG_36h11": "tag36h11",
}

#: the families of the AprilTag 3 library (both bindings build all of them)
APRILTAG_FAMILIES = (
    "tag36h11",
    "tag36h10",
    "tag25h9",
    "tag16h5",
    "tagCircle21h7",
    "tagCircle49h12",
    "tagStandard41h12",
    "tagStandard52h13",
    "tagCustom48h12",
)

#: the families pupil_apriltags builds (all but tag36h10)
PUPIL_FAMILIES = tuple(f for f in APRILTAG_FAMILIES if f != "tag36h10")

#: index of the AprilTag library's corner for each ArUco corner (TL, TR, BR, BL)
APRILTAG_TO_ARUCO_ORDER = (1, 0, 3, 2)

#: the AprilTag library's corners minus OpenCV's pixel-centre convention (px, x and y)
APRILTAG_PIXEL_OFFSET = 0.5

#: how to install an AprilTag binding (messages)
APRILTAG_INSTALL = "pip install pupil-apriltags (or apt install python3-apriltag)"

#: ``DetectorOptions.detector`` values
DETECTOR_BACKENDS = ("auto", "apriltag", "opencv")

#: smallest decision margin kept per binding when ``min_decision_margin`` is None. The two
#: library versions scale the margin differently: on the same 640x480 frames of
#: ``apriltag_room`` the true 36h11 tags scored at least 28.5 (median 117) with library 3.1
#: (pupil_apriltags) and at least 97.7 (median 226) with 3.3 (Debian); the false tag16h5
#: detections of its walls without tags (hamming 1-2, but one with 0) at most 24.6 and 52.7.
DEFAULT_MIN_MARGIN = {"pupil_apriltags": 25.0, "apriltag": 60.0}


#: :class:`DetectorOptions` ``nthreads`` by default: one worker thread of the AprilTag library.
#: The library before 3.4.3 creates a detector's worker threads at its first detection and
#: queues that detection's work while they start; a thread that starts while the queue grows
#: reads it as it is reallocated (fixed upstream by waiting for the threads to start). The
#: detector script of ``test/frontends/test_tiny_images.py`` (each AprilTag detector's first
#: detection a small image) in a loop of child processes on a quiet machine, two threads: 5 of
#: 40 runs ended by SIGSEGV with Debian 12's library 3.3, 2 of 40 with ``pupil_apriltags``
#: (3.1); one thread: 0 of 60 with each. Two threads cut the 640x480 node's latency median
#: from 13.6-16.2 to 9.6-13.8 ms (docs/node.md, "Marker detection")
DEFAULT_THREADS = 1


@dataclass(frozen=True)
class DetectorOptions:
    """Options of the marker detector, with the AprilTag library's names.

    Attributes:
        detector: ``auto`` (AprilTag families with the AprilTag library when a binding is
            installed, else OpenCV, saying so; ArUco dictionaries with OpenCV), ``apriltag``
            (the AprilTag library, an error when it is missing or the dictionary is not an
            AprilTag family) or ``opencv`` (OpenCV's ArUco detector for every dictionary).
        quad_decimate: detect quads on an image decimated by this factor (1: full
            resolution, 1.5 or an integer: the library decimates by other factors wrongly);
            the corners are then refined on the full image (``refine_edges``) and the tags
            decoded at full resolution. 0: by image size (:func:`auto_decimate`: 1.5 up to
            640x480, 2 above). AprilTag only.
        nthreads: worker threads of the AprilTag library (>= 1; default 1, as
            ``apriltag_ros``). Two threads took the 640x480 node's latency median from 14.7
            to 10.7 ms, but the library before 3.4.3 (``pupil_apriltags`` 1.0.4 ships 3.1,
            Debian 12 3.3) starts a detector's threads at its first detection while handing
            them work, which now and then ends the process (SIGSEGV; :data:`DEFAULT_THREADS`).
            AprilTag only.
        quad_sigma: standard deviation (px) of the Gaussian blur before quad detection (0:
            none; noisy images: ~0.8). AprilTag only.
        refine_edges: snap the quad edges to the strong gradients nearby. AprilTag only.
        decode_sharpening: sharpening of the decoded samples (library default 0.25; the Debian
            binding always uses 0.25). AprilTag only.
        max_hamming: largest number of corrected bits of a kept detection (the library corrects
            at most 2). AprilTag only.
        min_decision_margin: smallest decision margin of a kept detection (the library's
            units, which differ between library versions); None: the binding's measured
            default (:data:`DEFAULT_MIN_MARGIN`). AprilTag only.
        adaptive_thresh_constant: OpenCV's ``adaptiveThreshConstant``: a pixel is a marker
            candidate's dark when this much (grey levels) below its neighbourhood's mean
            (OpenCV's default 7 makes every dark speck of a textured wall a candidate). OpenCV
            only.
        adaptive_thresh_win_size_step: OpenCV's ``adaptiveThreshWinSizeStep``: the
            thresholding windows run from 3 to 23 px in this step (10: three passes, 20:
            two). OpenCV only.
        error_correction_rate: OpenCV's ``errorCorrectionRate``: the share of a dictionary's
            correctable bits a kept marker may have wrong. OpenCV only.
        edge_refinement: refine the library's corners of 36h11, 36h10, 25h9 and 16h5 tags
            from their edges' grey-level profiles (:func:`refine_tag_edges`). Off by default:
            it brings rendered corners closer to the truth (0.12 -> 0.03 px median) but on
            real photos with a calibrated camera the library's corners fit their squares
            and the board better (``python -m benchmarks.bench_real_markers``). AprilTag only.
        small_tags: with ``quad_decimate`` above 1, a whole frame is detected by a coarse
            pass (:data:`SMALL_TAGS_PASS_DECIMATE`) and a full-resolution look for the tags it
            is too coarse for (:meth:`AprilTagDetector.raw_frame`); windows
            (``detect_window``) keep the frame's decimation. With
            ``python -m benchmarks.bench_real_markers --small``: 0.98x the tags of a
            full-resolution pass on the real photos for 1.25x the default's time, all of them
            on 640x480 renders for 1.03x; off by default. AprilTag only.
    """

    detector: str = "auto"
    quad_decimate: float = 0.0
    nthreads: int = DEFAULT_THREADS
    quad_sigma: float = 0.0
    refine_edges: bool = True
    decode_sharpening: float = 0.25
    max_hamming: int = 0
    min_decision_margin: float | None = None
    adaptive_thresh_constant: float = 20.0
    adaptive_thresh_win_size_step: int = 20
    error_correction_rate: float = 0.6
    edge_refinement: bool = False
    small_tags: bool = False

    def __post_init__(self):
        if self.detector not in DETECTOR_BACKENDS:
            raise ValueError(
                f"unknown marker detector {self.detector!r}; expected one of {DETECTOR_BACKENDS}"
            )
        q = float(self.quad_decimate)
        if not (q in (0.0, 1.5) or (q >= 1.0 and q == int(q))):
            raise ValueError(
                f"quad_decimate must be 0 (by image size), 1, 1.5 or an integer, got {q} (the "
                "AprilTag library decimates by the integer part but scales the corners back by "
                "the factor given)"
            )
        if int(self.nthreads) < 1:
            raise ValueError(
                f"nthreads must be >= 1 (AprilTag library threads), got {self.nthreads}"
            )
        if not self.quad_sigma >= 0.0:
            raise ValueError(f"quad_sigma must be >= 0, got {self.quad_sigma}")
        if not 0 <= int(self.max_hamming) <= 2:
            raise ValueError(f"max_hamming must be 0, 1 or 2, got {self.max_hamming}")
        if not self.decode_sharpening >= 0.0:
            raise ValueError(f"decode_sharpening must be >= 0, got {self.decode_sharpening}")
        if not self.adaptive_thresh_constant >= 0.0:
            raise ValueError(
                f"adaptive_thresh_constant must be >= 0, got {self.adaptive_thresh_constant}"
            )
        if int(self.adaptive_thresh_win_size_step) < 1:
            raise ValueError(
                "adaptive_thresh_win_size_step must be >= 1, got "
                f"{self.adaptive_thresh_win_size_step}"
            )
        if not 0.0 <= self.error_correction_rate <= 1.0:
            raise ValueError(
                f"error_correction_rate must be in [0, 1], got {self.error_correction_rate}"
            )

    def opencv_overrides(self) -> dict:
        """The OpenCV ``DetectorParameters`` these options set (names -> values)."""
        return {
            "adaptiveThreshConstant": float(self.adaptive_thresh_constant),
            "adaptiveThreshWinSizeStep": int(self.adaptive_thresh_win_size_step),
            "errorCorrectionRate": float(self.error_correction_rate),
        }

    @classmethod
    def from_mapping(cls, values: Any, prefix: str = "") -> DetectorOptions:
        """Options from a mapping of ``prefix + field name`` -> value (node parameters:
        ``prefix="aruco."``); missing names keep their defaults, a negative
        ``min_decision_margin`` means None (the binding's default)."""
        kw = {}
        for f in dataclasses.fields(cls):
            key = prefix + f.name
            try:
                kw[f.name] = values[key]
            except KeyError:
                continue
        if "min_decision_margin" in kw and kw["min_decision_margin"] is not None:
            m = float(kw["min_decision_margin"])
            kw["min_decision_margin"] = None if m < 0 else m
        return cls(**kw)


def supported_dictionaries() -> tuple:
    """Every dictionary name a detector here knows: OpenCV's predefined ``DICT_*`` names (when
    OpenCV has ArUco) and the AprilTag library's family names."""
    names = []
    try:
        import cv2

        names = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
    except (ImportError, AttributeError):
        names = sorted(OPENCV_APRILTAG_FAMILIES)
    return (*names, *APRILTAG_FAMILIES)


def apriltag_family(dictionary: str) -> str | None:
    """The AprilTag library's family of a dictionary name (``DICT_APRILTAG_36h11`` or
    ``tag36h11`` -> ``tag36h11``); None for an ArUco dictionary."""
    if dictionary in APRILTAG_FAMILIES:
        return dictionary
    return OPENCV_APRILTAG_FAMILIES.get(dictionary)


def apriltag_binding() -> tuple[str, Any] | None:
    """The installed AprilTag binding: ``("pupil_apriltags", module)`` (preferred) or
    ``("apriltag", module)`` (Debian's ``python3-apriltag``); None without one. The PyPI
    package also named ``apriltag`` (an AprilTag 2 detector with another API) is not used."""
    try:
        import pupil_apriltags

        return "pupil_apriltags", pupil_apriltags
    except (ImportError, OSError):
        pass
    try:
        import apriltag
    except (ImportError, OSError):
        return None
    if callable(getattr(apriltag, "apriltag", None)):
        return "apriltag", apriltag
    return None


def drop_duplicates(corners: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Detections without the ids found more than once: ``(corners (K, 4, 2), ids (K,),
    number of ids dropped)``, in the input order."""
    ids = np.asarray(ids, dtype=np.int64).ravel()
    if len(ids) < 2 or len(set(ids.tolist())) == len(ids):
        return corners, ids, 0
    u, counts = np.unique(ids, return_counts=True)
    dup = u[counts > 1]
    if len(dup) == 0:
        return corners, ids, 0
    keep = ~np.isin(ids, dup)
    return corners[keep], ids[keep], len(dup)


#: the first window (half size, px) of the staged corner refinement (:func:`refine_corners`)
REFINE_FIRST_WINDOW = 2

#: the larger window of :func:`refine_corners` spans at most this share of a marker cell
REFINE_CELL_SHARE = 0.8

#: px: a corner the larger window moves further than this keeps the first window's position
REFINE_AGREE_PX = 0.15


def _library_detect(detector: Any, gray: np.ndarray, binding: str) -> Any:
    """``detector.detect(gray)``. Debian's binding (``python3-apriltag``) raises
    ``RuntimeError("Unable to create N threads for detector")`` whenever a detection finds no
    tag while the calling thread's ``errno`` is ``EAGAIN``, which any earlier non-blocking call
    of that thread (a lock tried by Python, a socket) leaves behind: the library ran and found
    nothing. That error is taken as what the library returned, no detection; any other error
    is raised."""
    try:
        return detector.detect(gray)
    except RuntimeError as e:
        if binding == "pupil_apriltags" or not str(e).startswith("Unable to create"):
            raise
        return ()


def refine_corners(
    gray: np.ndarray,
    corners: np.ndarray,
    cells: int,
    max_window: int = 3,
    iterations: int = 50,
    accuracy: float = 0.01,
) -> np.ndarray:
    """Marker corners refined to subpixel with OpenCV's ``cornerSubPix`` in two stages.

    OpenCV's own refinement (``CORNER_REFINE_SUBPIX``) runs ``cornerSubPix`` once with a
    window of up to a cell, and ``cornerSubPix`` returns its starting point unchanged when the
    iteration wanders further than the window: such corners stay on the integer pixel the
    contour gave (0.5-1 px off; their count and place then depend on the thresholding). Here:

    1. a window of :data:`REFINE_FIRST_WINDOW` px half size (1 px where that one returns its
       start unchanged);
    2. from there, for markers whose cell is large enough, a window of
       ``floor(REFINE_CELL_SHARE * cell)`` px (at most ``max_window``), kept where it moves
       the corner by less than :data:`REFINE_AGREE_PX` (more pixels of the same edges; a
       larger move means the window reached texture beyond the marker's margin).

    Measured with ``python -m benchmarks.bench_markers --refine-study``: OpenCV's one-window
    refinement leaves 0.48 px median (1.35 px p90) on ``DICT_4X4_250`` markers on textured walls
    at 640x480, these stages 0.25 (0.60) px; on plain walls 0.22 px either way.

    Args:
        gray: (H, W) uint8 image.
        corners: (M, 4, 2) px, integer or subpixel starting corners (OpenCV's pixel-centre
            convention).
        cells: cells across a marker, its border included (``markerSize + 2 *
            markerBorderBits``).
        max_window: largest half window (px; OpenCV's ``cornerRefinementWinSize``).
        iterations, accuracy: ``cornerSubPix``'s stopping criteria (iterations, px).
    Returns:
        (M, 4, 2) float64 refined corners; corners outside the image or not finite as given,
        windows no larger than ``cornerSubPix`` takes in the image (``2 w + 5`` px).
    Raises:
        ValueError: ``gray`` not an (H, W) uint8 image, ``corners`` not (M, 4, 2), ``cells``,
            ``max_window`` or ``iterations`` below 1, ``accuracy`` negative or not finite.
    """
    import cv2

    c = _check_corners(gray, corners, cells)
    if int(max_window) < 1 or int(iterations) < 1:
        raise ValueError(
            f"max_window and iterations must be >= 1, got {max_window} and {iterations}"
        )
    if not (np.isfinite(accuracy) and accuracy >= 0):
        raise ValueError(f"accuracy must be a finite number >= 0 px, got {accuracy}")
    # (cornerSubPix takes windows up to (side - 5) / 2 and points inside the image only)
    max_window = min(int(max_window), (min(gray.shape) - 5) // 2)
    if len(c) == 0 or max_window < 1:
        return c.copy()
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, int(iterations), float(accuracy))
    hi = np.array([gray.shape[1] - 1, gray.shape[0] - 1], np.float32)

    def subpix(pts: np.ndarray, w: int) -> np.ndarray:
        q = np.ascontiguousarray(pts, dtype=np.float32).copy()
        inside = ((q >= 0) & (q <= hi)).all(axis=(1, 2))
        if inside.all():
            cv2.cornerSubPix(gray, q, (int(w), int(w)), (-1, -1), crit)
        elif inside.any():
            r = np.ascontiguousarray(q[inside])
            cv2.cornerSubPix(gray, r, (int(w), int(w)), (-1, -1), crit)
            q[inside] = r
        return q

    p0 = c.reshape(-1, 1, 2).astype(np.float32)
    first = min(REFINE_FIRST_WINDOW, max_window)
    p = subpix(p0, first)
    stuck = (p == p0).all(axis=(1, 2))
    if first > 1 and stuck.any():
        p[stuck] = subpix(p0[stuck], 1)
    side = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=2).mean(axis=1)
    win = np.floor(np.nan_to_num(REFINE_CELL_SHARE * side / int(cells))).astype(int)
    win = np.repeat(np.clip(win, 0, max_window), 4)
    for w in np.unique(win[win > first]):
        idx = np.flatnonzero(win == w)
        q = subpix(p[idx], int(w))
        moved = np.linalg.norm(q - p[idx], axis=2).ravel()
        ok = (moved > 0) & (moved < REFINE_AGREE_PX)
        p[idx[ok]] = q[ok]
    return p.reshape(-1, 4, 2).astype(np.float64)


#: black-square width in cells of the AprilTag families whose black square is framed by the
#: tag's white border (the "classic" layout), whose corners :func:`refine_tag_edges` refines
EDGE_REFINE_CELLS = {"tag36h11": 8, "tag36h10": 8, "tag25h9": 7, "tag16h5": 6}

#: :func:`refine_tag_edges`: profiles across each edge span +-this share of a cell (px at
#: least :data:`EDGE_HALF_WIDTH_MIN`), sampled at :data:`EDGE_PROFILE_SAMPLES` points, at
#: :data:`EDGE_POSITIONS` places along the edge
EDGE_HALF_WIDTH_CELLS = 0.4
EDGE_HALF_WIDTH_MIN = 0.4
EDGE_PROFILE_SAMPLES = 9
EDGE_POSITIONS = 8

#: :func:`refine_tag_edges` keeps the detector's corners of a tag when an edge's contrast is
#: below this (grey levels) or a corner would move by more than :data:`EDGE_MAX_MOVE` px
EDGE_MIN_CONTRAST = 20.0
EDGE_MAX_MOVE = 1.0

#: px: :func:`refine_tag_edges` keeps the detector's corners of a tag when the edge offsets
#: at an edge's places scatter about their fitted line by more than this (RMS): image noise
#: too strong for the profiles. Measured on synthetic tags (25-90 px, noise sigma 35-70 grey
#: levels, some squeezed to 60 % and 15 % width; ``test/frontends/test_tag_edges_degraded.py``
#: renders them): without it 27 of 760 corners ended more than 0.5 px worse than the
#: library's, at 0.2 px none (at most 0.37 px worse). On the room's 640x480 renders
#: (``python -m benchmarks.bench_markers --corner-study``, 20 frames) the median corner error
#: stays 0.032 / 0.031 px at ``quad_decimate`` 1 / 1.5 (p90 0.129 / 0.141 -> 0.143 px)
EDGE_MAX_SCATTER = 0.2

#: :func:`refine_tag_edges` keeps the detector's corners of a tag whose shortest side is below
#: this share of its mean side (a tag squeezed by a grazing view or a strong perspective): the
#: profiles, a share of the mean cell wide, would reach past the one-cell border at the short
#: side (a trapezoid with sides 0.4 of each other moved corners 0.8 px off)
EDGE_MIN_SIDE_SHARE = 0.5


def _check_corners(gray: np.ndarray, corners: np.ndarray, cells: int) -> np.ndarray:
    """The argument checks of :func:`refine_corners` and :func:`refine_tag_edges`: corners
    as (M, 4, 2) float64."""
    g = np.asarray(gray)
    if g.ndim != 2 or g.dtype != np.uint8:
        raise ValueError(f"expected an (H, W) uint8 image, got {g.shape} {g.dtype}")
    c = np.asarray(corners, dtype=np.float64)
    if c.size == 0:
        return c.reshape(0, 4, 2)
    if c.ndim != 3 or c.shape[1:] != (4, 2):
        raise ValueError(f"corners must be (M, 4, 2) px, got shape {c.shape}")
    if isinstance(cells, bool) or not float(cells) >= 1 or float(cells) != int(cells):
        raise ValueError(f"cells must be an integer >= 1 (cells across the marker), got {cells}")
    return c


def refine_tag_edges(gray: np.ndarray, corners: np.ndarray, cells: int) -> np.ndarray:
    """AprilTag corners refined from their edges' grey-level profiles.

    Each edge of a tag's black square (between its corners) separates the black border, one
    cell wide, from the tag's white border, one cell wide. At :data:`EDGE_POSITIONS` places
    along the edge (away from the corners) the image is sampled (bilinear) on a profile across
    it, ``d`` in ``[-w, w]`` px (outward), ``w`` = :data:`EDGE_HALF_WIDTH_CELLS` of a cell.
    For a step from the dark level ``A`` to the bright ``B`` at ``d = c``, blurred by any
    symmetric kernel, the profile's integral gives ``c`` exactly: ``c = w - integral((I(d) -
    A) / (B - A)) dd`` (trapezoid rule; ``A`` and ``B`` the edge's mean profile ends). A
    straight line fitted to the places' ``c`` (least squares) is the edge; adjacent edges
    intersect at the corners. One pass from the library's corners (which ``refine_edges``
    already put within a fraction of a pixel).

    A tag keeps its corners as given when an edge's contrast ``B - A`` is below
    :data:`EDGE_MIN_CONTRAST`, its places scatter about the fitted line by more than
    :data:`EDGE_MAX_SCATTER` px (noise), its shortest side is below
    :data:`EDGE_MIN_SIDE_SHARE` of its mean side, a profile leaves the image, or a corner
    would move by more than :data:`EDGE_MAX_MOVE` px. Measured with
    ``python -m benchmarks.bench_markers`` (640x480 ``apriltag_room``, ``quad_decimate``
    1.5): corner error median 0.118 -> 0.031 px against the renderer's exact corners (p90
    0.252 -> 0.141 px); tags under 20 px keep 0.10-0.12 px (their cells are too narrow for
    the profiles). All tags are processed together: one bilinear sampling (``cv2.remap``) of
    every profile point of the frame, the fits and intersections as array operations over
    all edges.

    Args:
        gray: (H, W) uint8 image.
        corners: (M, 4, 2) px, ArUco order, OpenCV's pixel-centre convention.
        cells: width of the tag's black square in cells (:data:`EDGE_REFINE_CELLS`).
    Returns:
        (M, 4, 2) float64 corners, same order and convention; a tag with a corner that is
        not finite as given.
    Raises:
        ValueError: ``gray`` not an (H, W) uint8 image, ``corners`` not (M, 4, 2), ``cells``
            not an integer >= 1.
    """
    import cv2

    c = _check_corners(gray, corners, cells)
    m = len(c)
    finite = np.isfinite(c).all(axis=(1, 2))
    if m == 0 or not finite.any() or gray.size == 0:  # (an empty image: every profile leaves it)
        return c.copy()
    if not finite.all():
        out = c.copy()
        out[finite] = refine_tag_edges(gray, c[finite], cells)
        return out
    h, w_img = gray.shape
    # all edges of all tags at once, coordinates first: (2, E) for the E = 4 M edges; the
    # places along an edge (J) and samples across it (K) on the leading axes after them
    ct = c.transpose(2, 0, 1)  # (2, M, 4) view
    c32 = ct.astype(np.float32, order="C")
    p0 = c32.reshape(2, -1)
    v = c32.take(_NEXT, axis=2).reshape(2, -1) - p0
    length = np.sqrt(v[0] ** 2 + v[1] ** 2)
    e = v / np.maximum(length, 1e-9)
    n = e[::-1] * _OUTWARD[:, None]  # outward for clockwise corners (ArUco order)
    side = length.reshape(m, 4) @ _QUARTER
    wt = np.maximum(EDGE_HALF_WIDTH_CELLS / cells * side, EDGE_HALF_WIDTH_MIN)  # (M,)
    w = np.repeat(wt, 4)
    a = w + 0.5  # the places stay this far from the corners (the adjacent edge's profile)
    span = np.maximum(length - 2 * a, 0.0)
    t = a + span * _PLACES[:, None]  # (J, E) along the edge
    # (2, J, K, E): the profile points p0 + t e + d n, d = w * _ACROSS across the edge
    along = p0[:, None, :] + t * e[:, None, :]
    across = (_ACROSS[:, None] * w) * n[:, None, :]
    pts = (along[:, :, None, :] + across[:, None, :, :]).reshape(2, -1, len(w))
    prof = cv2.remap(gray, pts[0], pts[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # one product for each place's profile integral (trapezoid rule) and the edge's mean
    # profile ends (dark, bright): (J + 2, E), exact in float32 (grey levels times 1/2, 1/8)
    sums = _PROFILE_SUMS @ prof.astype(np.float32)
    dark = sums[EDGE_POSITIONS]
    contrast = sums[EDGE_POSITIONS + 1] - dark
    area = sums[:EDGE_POSITIONS] - (EDGE_PROFILE_SAMPLES - 1) * dark
    step = w * (2.0 / (EDGE_PROFILE_SAMPLES - 1))
    # (E, J): the edge's offset along n at each place
    cross = np.ascontiguousarray((w - (step / np.maximum(contrast, 1.0)) * area).T)
    c0 = cross @ _MEAN
    slope = (cross @ _CENTRED) / (np.maximum(span, 1e-9) * _CENTRED_NORM)
    # the places' scatter about the fitted line (px, RMS)
    resid = cross - c0[:, None] - (slope * span)[:, None] * _CENTRED
    scatter = np.sqrt((resid * resid) @ _MEAN)
    # the edge: through p0 + (a + span / 2) e + c0 n, direction e + slope n
    nn = n - slope * e
    nn /= np.sqrt(nn[0] ** 2 + nn[1] ** 2)
    x0 = p0 + (a + 0.5 * span) * e + c0 * n
    rho = (nn[0] * x0[0] + nn[1] * x0[1]).reshape(m, 4)
    nn = nn.reshape(2, m, 4)
    n1, r1 = nn.take(_PREV, axis=2), rho.take(_PREV, axis=1)  # corner k: edges k-1 and k
    det = n1[0] * nn[1] - n1[1] * nn[0]
    ok = np.abs(det) > 1e-6
    det = np.where(ok, det, 1.0)
    # x = (r1 ny - rho n1y) / det, y = (rho n1x - r1 nx) / det
    out = (r1 * nn[::-1] - rho * n1[::-1]) * _OUTWARD[:, None, None] / det  # (2, M, 4)
    # a tag keeps its corners where a corner fails: contrast, move, and the profiles stay
    # within w + 1 px of the corners (in the image when these are)
    move = out - ct
    bad = (move[0] * move[0] + move[1] * move[1]) > EDGE_MAX_MOVE**2  # (M, 4)
    bad |= ~(ok & (contrast.reshape(m, 4) >= EDGE_MIN_CONTRAST) & (span.reshape(m, 4) > 0))
    bad |= ~(scatter.reshape(m, 4) <= EDGE_MAX_SCATTER)  # (NaN too)
    bad |= ~(length.reshape(m, 4) >= EDGE_MIN_SIDE_SHARE * side[:, None])
    reach = wt[:, None] + 1.0
    outside = (ct < reach) | (ct > np.array([w_img - 1, h - 1], np.float32)[:, None, None] - reach)
    bad = (outside | bad).any(axis=(0, 2))
    return np.where(bad[:, None, None], c, out.transpose(1, 2, 0))


# constants of :func:`refine_tag_edges`
_NEXT = np.array([1, 2, 3, 0])
_PREV = np.array([3, 0, 1, 2])
_F = np.float32
_OUTWARD = np.array([1.0, -1.0], _F)
_QUARTER = np.full(4, 0.25, _F)
_PLACES = ((np.arange(EDGE_POSITIONS) + 0.5) / EDGE_POSITIONS).astype(_F)
_CENTRED = _PLACES - _F(0.5)
_CENTRED_NORM = _F(_CENTRED @ _CENTRED)
_MEAN = np.full(EDGE_POSITIONS, 1.0 / EDGE_POSITIONS, _F)
_ACROSS = np.linspace(-1.0, 1.0, EDGE_PROFILE_SAMPLES).astype(_F)
_TRAPEZOID = np.r_[0.5, np.ones(EDGE_PROFILE_SAMPLES - 2), 0.5].astype(_F)
#: (J + 2, J K): an edge's profile samples (place-major) -> each place's trapezoid sum, the
#: mean of the places' first samples, the mean of their last samples
_PROFILE_SUMS = np.zeros((EDGE_POSITIONS + 2, EDGE_POSITIONS, EDGE_PROFILE_SAMPLES), _F)
_PROFILE_SUMS[np.arange(EDGE_POSITIONS), np.arange(EDGE_POSITIONS)] = _TRAPEZOID
_PROFILE_SUMS[EDGE_POSITIONS, :, 0] = 1.0 / EDGE_POSITIONS
_PROFILE_SUMS[EDGE_POSITIONS + 1, :, -1] = 1.0 / EDGE_POSITIONS
_PROFILE_SUMS = _PROFILE_SUMS.reshape(EDGE_POSITIONS + 2, -1)


def copy_parameters(params: Any, **overrides: Any) -> Any:
    """A copy of ``cv2.aruco.DetectorParameters`` ``params`` with ``overrides`` set."""
    from ..cv_compat import detector_parameters

    names = [n for n in dir(params) if not n.startswith("_")]
    values = {}
    for n in names:
        v = getattr(params, n)
        if not callable(v):
            values[n] = v
    values.update(overrides)
    return detector_parameters(**values)


#: :meth:`AprilTagDetector.small_tag_look`: candidate tags' side range (full-resolution px;
#: larger tags are left to the decimated pass, :data:`SMALL_TAGS_PASS_DECIMATE`), the
#: smallest ratio of the short to the long side of their box (0.2: a square seen about 78
#: degrees from its normal), the share of their box the dark blob fills, how much darker the
#: blob's pixels are (mean) than a ring around its box as a share of the image's grey range
#: (:data:`SMALL_TAG_CONTRAST_RANGE` percentiles; a share, not grey levels: a dim or hazy
#: image keeps its candidates), and the windows' padding beyond the blob's white border (px:
#: one of the library's 4 px threshold tiles)
SMALL_TAG_SIDE = (10, 160)
SMALL_TAG_MIN_ASPECT = 0.2
SMALL_TAG_FILL = (0.3, 0.9)
SMALL_TAG_CONTRAST_SHARE = 0.35
SMALL_TAG_CONTRAST_RANGE = (5, 95)
SMALL_TAG_PAD = 4

#: with ``small_tags``: the ``quad_decimate`` of the full-frame pass when the frame's own is
#: above 1 and smaller and the frame is large enough for it (:func:`min_image_side`): it
#: finds the tags larger than the look's ``SMALL_TAG_SIDE[1]`` px (20 decimated px), the
#: look, at full resolution, the others; and the decimation of the look's candidate image.
#: A coarser pass leaves more tags to the look, which finds them at full resolution, and
#: costs less (``python -m benchmarks.bench_real_markers --small``, docs/node.md)
SMALL_TAGS_PASS_DECIMATE = 8.0
SMALL_TAGS_LOOK_DECIMATE = 2


def _merge_boxes(boxes: np.ndarray) -> list:
    """Boxes ``(x0, y0, x1, y1)`` (N, 4) with the overlapping ones merged into their union
    (repeated until none overlap): a list of int tuples."""
    out = [tuple(int(v) for v in b) for b in boxes]
    merged = True
    while merged:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                a, b = out[i], out[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    out[i] = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                    del out[j]
                    merged = True
                    break
            if merged:
                break
    return out


#: largest image (pixels) that ``quad_decimate`` 0 decimates by 1.5 (above: by 2)
AUTO_DECIMATE_MAX_PIXELS = 640 * 480


def auto_decimate(shape: tuple) -> float:
    """``quad_decimate`` by image size (``quad_decimate`` 0): 1.5 up to
    :data:`AUTO_DECIMATE_MAX_PIXELS` pixels, else 2 (measured with
    ``python -m benchmarks.bench_markers``: 1280x720 at 2 finds 98% of the tags 1.5 finds,
    in about 60% of the time)."""
    return 1.5 if int(shape[0]) * int(shape[1]) <= AUTO_DECIMATE_MAX_PIXELS else 2.0


#: px: the smallest side, after the AprilTag library's decimation, of an image it is given
#: (:func:`min_image_side`). Measured in child processes (pupil_apriltags 1.0.4, zero, noise
#: and striped images): the library ends the process on images of 2-3 px or less after its
#: decimation (e.g. 5x5 at ``quad_decimate`` 2, 8x8 at 4, 0x0-5x5, 640x1 and 4x640 at 1.5),
#: never at 8 or more px (``quad_decimate`` 1, 1.5, 2, 3, 4, 8)
MIN_DECIMATED_SIDE = 8


def min_image_side(decimate: float = 1.0) -> int:
    """The smallest image side (px) the detectors take at ``quad_decimate`` ``decimate``:
    :data:`~rs_localizer.frontends.image.MIN_IMAGE_SIDE`, and :data:`MIN_DECIMATED_SIDE` px
    after the decimation."""
    from .image import MIN_IMAGE_SIDE

    return max(MIN_IMAGE_SIDE, int(np.ceil(MIN_DECIMATED_SIDE * max(float(decimate), 1.0))))


def _check_gray(gray: np.ndarray, min_side: int | None = None) -> np.ndarray:
    """``gray`` as a contiguous (H, W) uint8 array; raises ValueError for another shape or
    dtype, or a side below ``min_side`` (default :func:`min_image_side` at decimation 1)."""
    from .image import check_image_size

    g = np.asarray(gray)
    if g.ndim != 2 or g.dtype != np.uint8:
        raise ValueError(f"expected an (H, W) uint8 image, got {g.shape} {g.dtype}")
    check_image_size(g.shape, min_image_side() if min_side is None else int(min_side))
    return np.ascontiguousarray(g)


def _no_detections() -> tuple[np.ndarray, np.ndarray, int]:
    return np.zeros((0, 4, 2)), np.zeros(0, np.int64), 0


def clip_window(window: tuple, shape: tuple, min_side: int) -> tuple[int, int, int, int] | None:
    """``window`` ``(x0, y0, x1, y1)`` (px, end exclusive) clipped to an image of ``shape``
    (H, W): None when nothing of it is left (off the image, empty, not finite), else the
    clipped window grown within the image to at least ``min_side`` px on each side (about
    its centre; the image is assumed at least that large).

    Raises:
        ValueError: a window that is not four numbers.
    """
    h, w = int(shape[0]), int(shape[1])
    try:
        x0, y0, x1, y1 = (float(v) for v in window)
    except (TypeError, ValueError):
        raise ValueError(f"a window is (x0, y0, x1, y1), got {window!r}") from None
    if not np.isfinite([x0, y0, x1, y1]).all():
        return None
    x0, x1 = int(max(np.floor(x0), 0)), int(min(np.ceil(x1), w))
    y0, y1 = int(max(np.floor(y0), 0)), int(min(np.ceil(y1), h))
    if x1 <= x0 or y1 <= y0:
        return None

    def grow(a: int, b: int, n: int) -> tuple[int, int]:
        if b - a >= min_side:
            return a, b
        a = min(max((a + b - min_side) // 2, 0), max(n - min_side, 0))
        return a, min(a + min_side, n)

    x0, x1 = grow(x0, x1, w)
    y0, y1 = grow(y0, y1, h)
    return x0, y0, x1, y1


_SAFE_PUPIL_CLASSES: dict = {}


def pupil_detector(module: Any, **kwargs: Any) -> Any:
    """A ``pupil_apriltags.Detector(**kwargs)`` that tears down safely.

    The binding's ``Detector.__del__`` frees its tag families before the library's detector,
    whose destruction then reads the freed families (a use-after-free that aborts the process
    now and then, e.g. when the garbage collector finalizes both in one pass). The detector
    returned here detaches its families from the library's detector first, whatever order
    the objects are finalized in."""
    cls = _SAFE_PUPIL_CLASSES.get(module)
    if cls is None:

        class _Detector(module.Detector):
            def __del__(self):
                ptr = getattr(self, "tag_detector_ptr", None)
                if ptr is not None:
                    self.libc.apriltag_detector_clear_families.restype = None
                    self.libc.apriltag_detector_clear_families(ptr)
                super().__del__()

        cls = _SAFE_PUPIL_CLASSES[module] = _Detector
    return cls(**kwargs)


class AprilTagDetector:
    """One AprilTag family with the AprilTag 3 library (module notes).

    Args:
        family: an AprilTag library family name (:data:`APRILTAG_FAMILIES`).
        options: :class:`DetectorOptions`.
        binding: ``(name, module)`` of :func:`apriltag_binding` (default: the installed one).
        edge_refinement: refine the corners of the families with a white-framed black square
            (:data:`EDGE_REFINE_CELLS`: 36h11, 36h10, 25h9, 16h5) from their edges'
            profiles (:func:`refine_tag_edges`); False: the library's corners; None (default):
            ``options.edge_refinement``.

    ``detect(gray) -> (corners (M, 4, 2) float64 px, ids (M,) int64, weak count)``: ArUco
    corner order, OpenCV pixel convention, weak detections and repeated ids dropped.
    Attributes after each call: ``last_weak`` (refused as weak), ``last_duplicates`` (ids
    dropped for being found more than once; ``last_duplicate_ids`` those ids),
    ``last_margins`` (M,) and ``last_hamming`` (M,)
    of the kept detections.

    Raises:
        ValueError: an unknown family. ImportError: no binding installed.
    """

    backend = "apriltag"
    fallback = None

    def __init__(
        self,
        family: str,
        options: DetectorOptions | None = None,
        binding: Any = None,
        edge_refinement: bool | None = None,
    ):
        if family not in APRILTAG_FAMILIES:
            raise ValueError(
                f"unknown AprilTag family {family!r}; the AprilTag library has "
                f"{', '.join(APRILTAG_FAMILIES)}"
            )
        binding = binding if binding is not None else apriltag_binding()
        if binding is None:
            raise ImportError(f"no AprilTag library binding installed ({APRILTAG_INSTALL})")
        self.family = family
        self.options = options if options is not None else DetectorOptions()
        #: the library's worker threads (``nthreads``)
        self.nthreads = int(self.options.nthreads)
        if edge_refinement is None:
            edge_refinement = bool(self.options.edge_refinement)
        #: cells across the black square when its corners are refined by
        #: :func:`refine_tag_edges` (None: the library's corners as they are)
        self.edge_cells = EDGE_REFINE_CELLS.get(family) if edge_refinement else None
        self.binding, self._mod = binding
        if self.binding == "pupil_apriltags" and family not in PUPIL_FAMILIES:
            raise ValueError(
                f"pupil_apriltags has no family {family!r}; it has {', '.join(PUPIL_FAMILIES)}"
            )
        self._dets: dict = {}  # quad_decimate -> the library's detector
        # made now, not on the first frame: building a family's decoding tables costs about
        # twice a 640x480 detection (36h11: ~23 ms), the slowest frame of a video otherwise
        q = float(self.options.quad_decimate)
        if self.options.small_tags:
            self._detector(1.0)  # (the small-tag look's)
            self._detector(max(q, SMALL_TAGS_PASS_DECIMATE))  # (the coarse pass's)
        self._detector(q if q > 0 else auto_decimate((480, 640)))
        o = self.options
        self.min_decision_margin = (
            DEFAULT_MIN_MARGIN[self.binding]
            if o.min_decision_margin is None
            else float(o.min_decision_margin)
        )
        self.last_weak = 0
        self.last_duplicates = 0
        self.last_duplicate_ids: set = set()
        self.last_margins = np.zeros(0)
        self.last_hamming = np.zeros(0, np.int64)

    def _detector(self, decimate: float) -> Any:
        """The library's detector at ``quad_decimate`` ``decimate``: with ``pupil_apriltags``
        one detector whose decimation is set per call (the library reads it on every
        detection), with the Debian binding one per decimation (made on first use)."""
        if self.binding == "pupil_apriltags" and self._dets:
            det = next(iter(self._dets.values()))
            det.tag_detector_ptr.contents.quad_decimate = float(decimate)
            return det
        det = self._dets.get(decimate)
        if det is not None:
            return det
        o = self.options
        if self.binding == "pupil_apriltags":
            det = pupil_detector(
                self._mod,
                families=self.family,
                nthreads=self.nthreads,
                quad_decimate=float(decimate),
                quad_sigma=float(o.quad_sigma),
                refine_edges=int(bool(o.refine_edges)),
                decode_sharpening=float(o.decode_sharpening),
            )
        else:
            det = self._mod.apriltag(
                self.family,
                threads=self.nthreads,
                maxhamming=int(o.max_hamming),
                decimate=float(decimate),
                blur=float(o.quad_sigma),
                refine_edges=bool(o.refine_edges),
            )
        self._dets[decimate] = det
        return det

    def decimation(self, shape: tuple) -> float:
        """The ``quad_decimate`` used on frames of ``shape`` (H, W, ...)."""
        q = float(self.options.quad_decimate)
        return q if q > 0 else auto_decimate(shape)

    def describe(self) -> str:
        """One line for logs: detector, binding and family."""
        return f"AprilTag 3 library ({self.binding}), {self.family}"

    def settings(self) -> str:
        """The detector's settings, one line (diagnostics)."""
        o = self.options
        dec = "by image size" if o.quad_decimate <= 0 else f"{o.quad_decimate:g}"
        sharp = f"{o.decode_sharpening:g}" if self.binding == "pupil_apriltags" else "0.25"
        return (
            f"quad_decimate {dec}, nthreads {self.nthreads}, quad_sigma {o.quad_sigma:g}, "
            f"refine_edges {bool(o.refine_edges)}, decode_sharpening {sharp}, max_hamming "
            f"{int(o.max_hamming)}, min_decision_margin {self.min_decision_margin:g}, "
            f"edge_refinement {self.edge_cells is not None}, small_tags {bool(o.small_tags)}"
        )

    def raw(
        self, gray: np.ndarray, frame_shape: tuple | None = None, decimate: float | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The library's detections unfiltered: ``(corners (M, 4, 2) in the library's order and
        pixel convention, ids (M,), hamming (M,), decision margins (M,))``; ``frame_shape``:
        the shape of the frame ``gray`` is cut from (the decimation by image size), default
        ``gray``'s; ``decimate``: this ``quad_decimate`` instead of the options'. Images
        smaller than the library can take at that decimation raise ``ValueError``."""
        g = np.asarray(gray)
        dec = self.decimation(frame_shape or g.shape) if decimate is None else float(decimate)
        g = _check_gray(g, min_image_side(dec))
        dets = _library_detect(self._detector(dec), g, self.binding)
        if not len(dets):
            return np.zeros((0, 4, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        if self.binding == "pupil_apriltags":
            c = np.array([d.corners for d in dets], dtype=np.float64)
            ids, ham = np.array([(d.tag_id, d.hamming) for d in dets], dtype=np.int64).T
            mar = np.array([d.decision_margin for d in dets], dtype=np.float64)
        else:
            c = np.array([d["lb-rb-rt-lt"] for d in dets], dtype=np.float64)
            ids, ham = np.array([(d["id"], d["hamming"]) for d in dets], dtype=np.int64).T
            mar = np.array([d["margin"] for d in dets], dtype=np.float64)
        return c.reshape(-1, 4, 2), ids.copy(), ham.copy(), mar

    def raw_frame(
        self, gray: np.ndarray, frame_shape: tuple | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The library's detections of a whole frame as :meth:`raw` returns them; with
        ``small_tags`` and a decimation above 1: a pass at ``quad_decimate``
        :data:`SMALL_TAGS_PASS_DECIMATE` (or the options' when larger; the frame's own when
        the frame is too small for it), then :meth:`small_tag_look` for the tags that pass
        did not find."""
        if not self.options.small_tags:
            return self.raw(gray, frame_shape)
        dec = self.decimation(frame_shape or np.shape(gray))
        if dec <= 1:
            return self.raw(gray, frame_shape)
        coarse = max(dec, SMALL_TAGS_PASS_DECIMATE)
        if min(np.shape(gray)[:2]) < min_image_side(coarse):
            coarse = dec  # (a frame too small for the coarse pass)
        found = self.raw(gray, frame_shape, decimate=coarse)
        more = self.small_tag_look(gray, found[0])
        return tuple(np.concatenate(v) for v in zip(found, more, strict=True))

    def small_tag_look(
        self, gray: np.ndarray, found: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Tags the decimated pass missed, found at full resolution where they may be.

        The decimated pass needs a few decimated pixels per cell; smaller or strongly
        foreshortened tags are lost before decoding. Candidates: the dark blobs of the
        image decimated by :data:`SMALL_TAGS_LOOK_DECIMATE` (adaptive threshold, connected
        components) whose box suits a tag (sides :data:`SMALL_TAG_SIDE`, short to long at
        least :data:`SMALL_TAG_MIN_ASPECT`), that fill :data:`SMALL_TAG_FILL` of their box,
        whose pixels are darker (mean) than a ring around the box (a tag's white border) by
        :data:`SMALL_TAG_CONTRAST_SHARE` of the decimated image's grey range, and whose box
        centre lies inside no quad of ``found``. Their windows (padded by an eighth of their
        size, a tag's white border, and :data:`SMALL_TAG_PAD` px, overlapping ones merged)
        are detected again at ``quad_decimate`` 1.

        Args:
            gray: (H, W) uint8 frame.
            found: (M, 4, 2) the decimated pass's corners (the library's convention).
        Returns:
            the new detections as :meth:`raw` returns them (the library's order and pixel
            convention, unfiltered), empty when the frame's decimation is 1.
        """
        import cv2

        empty = (np.zeros((0, 4, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
        g = _check_gray(gray)
        if self.decimation(g.shape) <= 1:
            return empty
        dec = SMALL_TAGS_LOOK_DECIMATE
        h, w = g.shape
        small = cv2.resize(g, (w // dec, h // dec), interpolation=cv2.INTER_LINEAR)
        dark = cv2.adaptiveThreshold(
            small, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, 11, 15
        )
        # (16-bit labels where they cannot overflow: separate 8-connected blobs start at
        # least 2 px apart in x or y, so at most one in each 2x2 cell of the image)
        cells = ((dark.shape[0] + 1) // 2) * ((dark.shape[1] + 1) // 2)
        ltype = cv2.CV_16U if cells < 65535 else cv2.CV_32S
        n, labels, st, _ = cv2.connectedComponentsWithStats(dark, connectivity=8, ltype=ltype)
        x, y, bw, bh, area = (v.astype(np.int64) for v in st[1:].T)
        side = np.maximum(bw, bh)
        lo, hi = SMALL_TAG_SIDE
        k = (side * dec >= lo) & (side * dec <= hi)
        k &= np.minimum(bw, bh) >= SMALL_TAG_MIN_ASPECT * side
        k &= (area >= SMALL_TAG_FILL[0] * bw * bh) & (area <= SMALL_TAG_FILL[1] * bw * bh)
        x, y, bw, bh, area, blob = x[k], y[k], bw[k], bh[k], area[k], np.flatnonzero(k) + 1
        if len(x):
            integral = cv2.integral(small, sdepth=cv2.CV_64F)
            sh, sw = small.shape

            def box_sum(x0, y0, x1, y1):
                x0, x1 = np.clip(x0, 0, sw), np.clip(x1, 0, sw)
                y0, y1 = np.clip(y0, 0, sh), np.clip(y1, 0, sh)
                s = integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]
                return s, np.maximum((x1 - x0) * (y1 - y0), 1)

            r = np.maximum(np.maximum(bw, bh) // 5, 1)
            s_in, a_in = box_sum(x, y, x + bw, y + bh)
            s_out, a_out = box_sum(x - r, y - r, x + bw + r, y + bh + r)
            ring = (s_out - s_in) / np.maximum(a_out - a_in, 1)
            # the blob's own mean (its dark pixels: a tag's black border and bits)
            grey = np.bincount(labels.ravel(), weights=small.ravel(), minlength=n)[blob] / area
            lo_grey, hi_grey = np.percentile(small[::4, ::4], SMALL_TAG_CONTRAST_RANGE)
            k = ring - grey >= SMALL_TAG_CONTRAST_SHARE * (hi_grey - lo_grey)
            x, y, bw, bh = x[k] * dec, y[k] * dec, bw[k] * dec, bh[k] * dec
        if len(x) and len(found):
            # (a blob whose box centre lies inside a found tag's quad is that tag)
            centre = np.c_[x + bw / 2, y + bh / 2][:, None, None, :]  # (C, 1, 1, 2)
            edge = np.roll(found, -1, axis=1) - found  # (F, 4, 2)
            rel = centre - found[None]  # (C, F, 4, 2)
            cross = edge[None, ..., 0] * rel[..., 1] - edge[None, ..., 1] * rel[..., 0]
            inside = (cross >= 0).all(axis=2) | (cross <= 0).all(axis=2)  # (C, F)
            keep = ~inside.any(axis=1)
            x, y, bw, bh = x[keep], y[keep], bw[keep], bh[keep]
        if not len(x):
            return empty
        pad = np.maximum(bw, bh) // 8 + SMALL_TAG_PAD
        boxes = np.c_[
            np.maximum(x - pad, 0),
            np.maximum(y - pad, 0),
            np.minimum(x + bw + pad, w),
            np.minimum(y + bh + pad, h),
        ]
        out = []
        for box in _merge_boxes(boxes):
            x0, y0, x1, y1 = clip_window(box, g.shape, min_image_side(1.0))
            c, ids, ham, mar = self.raw(np.ascontiguousarray(g[y0:y1, x0:x1]), decimate=1.0)
            if len(ids):
                out.append((c + np.array([x0, y0], float), ids, ham, mar))
        if not out:
            return empty
        c, ids, ham, mar = (np.concatenate(v) for v in zip(*out, strict=True))
        # a tag in two merged windows or beside a found one: kept once
        keep = np.ones(len(c), bool)
        seen = found.mean(axis=1)
        for i, centre in enumerate(c.mean(axis=1)):
            if (np.linalg.norm(seen - centre, axis=1) < 2.0).any():
                keep[i] = False
            else:
                seen = np.vstack([seen, centre])
        return c[keep], ids[keep], ham[keep], mar[keep]

    def detect(
        self, gray: np.ndarray, frame_shape: tuple | None = None
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """Detections of ``gray`` (class notes); ``frame_shape``: see :meth:`raw`."""
        return self._detect(gray, frame_shape)

    def _detect(
        self,
        gray: np.ndarray,
        frame_shape: tuple | None = None,
        frame: np.ndarray | None = None,
        origin: tuple = (0, 0),
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """:meth:`detect` of ``gray``, a window of ``frame`` (None: ``gray`` itself) at
        ``origin`` (x, y px): corners in ``frame``'s pixels, refined on ``frame``."""
        if frame is None:
            c, ids, ham, mar = self.raw_frame(gray, frame_shape)
        else:
            c, ids, ham, mar = self.raw(gray, frame_shape)
        ok = (ham <= int(self.options.max_hamming)) & (mar >= self.min_decision_margin)
        self.last_weak = len(ok) - int(np.count_nonzero(ok))
        if self.last_weak:
            c, ids, ham, mar = c[ok], ids[ok], ham[ok], mar[ok]
        corners = c[:, APRILTAG_TO_ARUCO_ORDER, :] - APRILTAG_PIXEL_OFFSET
        if origin != (0, 0):
            corners = corners + np.array(origin, float)
        if self.edge_cells is not None and len(corners):
            image = _check_gray(gray if frame is None else frame)
            corners = refine_tag_edges(image, corners, self.edge_cells)
        corners, kept, self.last_duplicates = drop_duplicates(corners, ids)
        if self.last_duplicates:
            self.last_duplicate_ids = set(ids.tolist()) - set(kept.tolist())
            keep = np.isin(ids, kept)
            mar, ham = mar[keep], ham[keep]
        else:
            self.last_duplicate_ids = set()
        self.last_margins, self.last_hamming = mar, ham
        return corners, kept, self.last_weak

    def detect_window(self, gray: np.ndarray, window: tuple) -> tuple[np.ndarray, np.ndarray, int]:
        """:meth:`detect` in ``window`` ``(x0, y0, x1, y1)`` (px, end exclusive) of the frame
        ``gray`` with the frame's settings: corners in the frame's pixels. The window's origin
        and end are moved out to the grid of the library's decimation and threshold tiles (4
        decimated pixels), so that a tag away from other edges is found as in the full frame
        (off the grid its corners move by up to ~0.1 px; a tag whose outline runs on into the
        texture may still differ by that much). A window is clipped to the frame (none left:
        no detections, the library not called) and grown to :func:`min_image_side` px.

        Raises:
            ValueError: a frame the library does not take (:func:`min_image_side`), a window
                that is not four numbers.
        """
        dec = self.decimation(np.shape(gray))
        g = _check_gray(gray, min_image_side(dec))
        step = 4 * (3 if dec == 1.5 else max(int(dec), 1))
        win = clip_window(window, g.shape, min_image_side(dec))
        if win is None:
            self.last_weak = self.last_duplicates = 0
            self.last_duplicate_ids = set()
            self.last_margins, self.last_hamming = np.zeros(0), np.zeros(0, np.int64)
            return _no_detections()
        x0, y0, x1, y1 = win
        x0, y0 = x0 - x0 % step, y0 - y0 % step
        x1 = min(g.shape[1], x1 + (-x1) % step)
        y1 = min(g.shape[0], y1 + (-y1) % step)
        return self._detect(np.ascontiguousarray(g[y0:y1, x0:x1]), g.shape, g, (x0, y0))


class OpenCVDetector:
    """A predefined dictionary with OpenCV's ArUco detector
    (:class:`~rs_localizer.cv_compat.MarkerDetector`).

    Args:
        dictionary: OpenCV's predefined dictionary name (``DICT_4X4_250``...) or a custom
            dictionary file (OpenCV's dictionary YAML).
        params: ``cv2.aruco.DetectorParameters``
            (:func:`~rs_localizer.cv_compat.detector_parameters`; default: OpenCV's), changed
            in place by ``options``.
        fallback: why OpenCV detects an AprilTag family here (None: it was asked for).
        options: :class:`DetectorOptions` whose OpenCV settings
            (:meth:`DetectorOptions.opencv_overrides`) are applied to ``params`` (None: none).

    ``detect(gray) -> (corners (M, 4, 2) float64 px, ids (M,) int64, rejected candidates)``
    with repeated ids dropped (``last_duplicates``, ``last_duplicate_ids``); ``last_weak`` is
    always 0 (OpenCV refuses weak codes itself, ``errorCorrectionRate``).

    Raises:
        ValueError: an unknown dictionary. ImportError: OpenCV without ArUco.
    """

    backend = "opencv"

    def __init__(
        self,
        dictionary: str,
        params: Any = None,
        fallback: str | None = None,
        options: DetectorOptions | None = None,
        refine: str = "staged",
    ):
        import cv2

        from ..cv_compat import MarkerDetector, detector_parameters, get_dictionary

        if refine not in ("staged", "opencv"):
            raise ValueError(f"refine must be 'staged' or 'opencv', got {refine!r}")
        self.name = dictionary
        self.dictionary = get_dictionary(dictionary)
        params = params if params is not None else detector_parameters()
        if options is not None:
            for k, v in options.opencv_overrides().items():
                if hasattr(params, k):
                    setattr(params, k, v)
        self.params = params
        self.refine = refine
        subpix = int(params.cornerRefinementMethod) == int(cv2.aruco.CORNER_REFINE_SUBPIX)
        self._staged = refine == "staged" and subpix
        self._det_params = params
        if self._staged:
            # OpenCV finds the integer corners, :func:`refine_corners` refines them
            self._det_params = copy_parameters(params, cornerRefinementMethod=0)
        self._det = MarkerDetector(self.dictionary, self._det_params)
        self._cells = int(self.dictionary.markerSize) + 2 * int(params.markerBorderBits)
        self.fallback = fallback
        self.last_weak = 0
        self.last_duplicates = 0
        self.last_duplicate_ids: set = set()

    def describe(self) -> str:
        """One line for logs: detector and dictionary (and why, after a fallback)."""
        s = f"OpenCV ArUco, {self.name}"
        return s if self.fallback is None else f"{s} ({self.fallback})"

    def settings(self) -> str:
        """The detector's settings, one line (diagnostics)."""
        p = self.params
        return (
            f"adaptiveThreshConstant {p.adaptiveThreshConstant:g}, adaptiveThreshWinSize "
            f"{p.adaptiveThreshWinSizeMin}-{p.adaptiveThreshWinSizeMax} step "
            f"{p.adaptiveThreshWinSizeStep}, errorCorrectionRate {p.errorCorrectionRate:g}, "
            f"minMarkerPerimeterRate {p.minMarkerPerimeterRate:g}, cornerRefinementMethod "
            f"{int(p.cornerRefinementMethod)}"
            + (
                f" (staged: window 2 px, then up to {int(p.cornerRefinementWinSize)} px)"
                if self._staged
                else ""
            )
        )

    def _refine(self, gray: np.ndarray, corners: np.ndarray) -> np.ndarray:
        """The corners refined by :func:`refine_corners` (staged refinement), else as found."""
        if not self._staged or len(corners) == 0:
            return corners
        p = self.params
        return refine_corners(
            gray,
            corners,
            self._cells,
            int(p.cornerRefinementWinSize),
            int(p.cornerRefinementMaxIterations),
            float(p.cornerRefinementMinAccuracy),
        )

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Detections of ``gray`` (class notes)."""
        g = _check_gray(gray)
        corners, ids, rejected = self._det.detect(g)
        corners = self._refine(g, corners)
        found = set(np.asarray(ids, np.int64).ravel().tolist())
        corners, ids, self.last_duplicates = drop_duplicates(corners, ids)
        self.last_duplicate_ids = found - set(ids.tolist())
        return corners, ids, rejected

    def detect_window(self, gray: np.ndarray, window: tuple) -> tuple[np.ndarray, np.ndarray, int]:
        """:meth:`detect` in ``window`` ``(x0, y0, x1, y1)`` (px, end exclusive) of the frame
        ``gray``: corners in the frame's pixels, the smallest marker perimeter kept at the
        frame's (OpenCV scales it by the image size). A window is clipped to the frame (none
        left: no detections) and grown to :func:`min_image_side` px.

        Raises:
            ValueError: a frame smaller than :func:`min_image_side` px, a window that is not
                four numbers.
        """
        from ..cv_compat import MarkerDetector

        g = _check_gray(gray)
        win = clip_window(window, g.shape, min_image_side())
        if win is None:
            self.last_duplicates, self.last_duplicate_ids = 0, set()
            return _no_detections()
        x0, y0, x1, y1 = win
        crop = np.ascontiguousarray(g[y0:y1, x0:x1])
        rate = self._det_params.minMarkerPerimeterRate
        try:
            self._det_params.minMarkerPerimeterRate = rate * max(g.shape) / max(crop.shape)
            corners, ids, rejected = MarkerDetector(self.dictionary, self._det_params).detect(crop)
        finally:
            self._det_params.minMarkerPerimeterRate = rate
        corners = self._refine(g, corners + np.array([x0, y0], float))
        found = set(np.asarray(ids, np.int64).ravel().tolist())
        corners, ids, self.last_duplicates = drop_duplicates(corners, ids)
        self.last_duplicate_ids = found - set(ids.tolist())
        return corners, ids, rejected


def make_marker_detector(
    dictionary: str, options: DetectorOptions | None = None, opencv_params: Any = None
) -> AprilTagDetector | OpenCVDetector:
    """The detector of a marker map's ``dictionary`` (module notes).

    Args:
        dictionary: OpenCV's predefined dictionary name (``DICT_4X4_250``,
            ``DICT_APRILTAG_36h11``...), an AprilTag library family (``tag36h11``,
            ``tagStandard41h12``...) or a custom dictionary: OpenCV's dictionary YAML, a path
            ending ``.yml``/``.yaml`` (:func:`~rs_localizer.cv_compat.read_dictionary`),
            detected with OpenCV.
        options: :class:`DetectorOptions` (default: its defaults).
        opencv_params: ``cv2.aruco.DetectorParameters`` of the OpenCV detector.
    Returns:
        an :class:`AprilTagDetector` or an :class:`OpenCVDetector`; its ``fallback`` is a
        sentence (also issued as a :class:`RuntimeWarning`) when OpenCV stands in for a missing
        AprilTag library, else None.
    Raises:
        ValueError: a dictionary neither detector knows (naming the supported ones), a
            dictionary file that is not one (naming the entry), or
            ``detector="apriltag"`` with an ArUco dictionary, or ``detector="opencv"`` with a
            family OpenCV lacks. ImportError: the AprilTag library is needed (``apriltag``, or a
            family only it has) and missing.
    """
    o = options if options is not None else DetectorOptions()
    family = apriltag_family(dictionary)
    opencv_name = dictionary if str(dictionary).startswith("DICT_") else None
    if family is None:
        from ..cv_compat import get_dictionary, is_dictionary_file

        try:
            get_dictionary(dictionary)
        except ValueError:
            if is_dictionary_file(dictionary):  # (the file's own error names what is wrong)
                raise
            raise ValueError(
                f"unknown marker dictionary {dictionary!r}; supported: "
                f"{', '.join(supported_dictionaries())}"
            ) from None
        if o.detector == "apriltag":
            raise ValueError(
                f"detector 'apriltag' detects AprilTag families only, not {dictionary!r} "
                f"(AprilTag families: {', '.join(APRILTAG_FAMILIES)}, "
                f"{', '.join(OPENCV_APRILTAG_FAMILIES)})"
            )
        return OpenCVDetector(dictionary, opencv_params, options=o)
    if o.detector == "opencv":
        if opencv_name is None:
            raise ValueError(
                f"OpenCV has no AprilTag family {dictionary!r}; its AprilTag dictionaries: "
                f"{', '.join(OPENCV_APRILTAG_FAMILIES)}"
            )
        return OpenCVDetector(opencv_name, opencv_params, options=o)
    binding = apriltag_binding()
    if binding is not None:
        return AprilTagDetector(family, o, binding)
    if o.detector == "apriltag" or opencv_name is None:
        raise ImportError(
            f"{dictionary!r} needs the AprilTag library, which is not installed "
            f"({APRILTAG_INSTALL})"
        )
    why = (
        f"the AprilTag library is not installed ({APRILTAG_INSTALL}): {opencv_name} is "
        "detected with OpenCV's ArUco detector instead: slower (about 1.6x on textured images) "
        "and less exact (about 2.5x the corner error)"
    )
    warnings.warn(why, RuntimeWarning, stacklevel=2)
    return OpenCVDetector(opencv_name, opencv_params, fallback=why, options=o)
