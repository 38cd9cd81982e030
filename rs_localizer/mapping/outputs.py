"""Inputs and outputs of the marker mapper: a camera YAML, marker detections in a folder of
images, the map file (written whole or not at all) and the report (YAML and a picture)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..camera import CameraModel
from ..maps.files import write_text_atomic
from ..maps.markers import write_marker_map
from .marker_model import FrameDetections, MarkerMapResult

if TYPE_CHECKING:  # (imported where a front end is made: OpenCV loads late)
    from ..frontends import ArucoFrontend

__all__ = [
    "IMAGE_SUFFIXES",
    "camera_from_yaml",
    "detect_folder",
    "detect_image",
    "readout_dict",
    "readout_line",
    "write_atomic",
    "write_map",
    "write_report",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


def camera_from_yaml(path: str | Path, line_delay: float = 0.0) -> CameraModel:
    """Camera from a ROS camera calibration YAML (``camera_calibration``'s ``image_width``,
    ``image_height``, ``camera_matrix.data``, ``distortion_model``,
    ``distortion_coefficients.data``) or a ``sensor_msgs/CameraInfo`` YAML (``width``,
    ``height``, ``k``, ``d``, ``distortion_model``).

    Args:
        path: the YAML file. line_delay: seconds between lines (the file has no RS timing;
            0: global shutter).
    Returns:
        :class:`CameraModel` (top-to-bottom readout, reference line: the image centre).
    Raises:
        FileNotFoundError: no such file. ValueError: neither format (or a malformed entry), or
        an invalid camera.
    """
    import yaml

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"camera file {p} not found")
    d = yaml.safe_load(p.read_text())
    if not isinstance(d, dict):
        raise ValueError(f"{p}: not a camera YAML")
    try:
        if "camera_matrix" in d:
            K = d["camera_matrix"]["data"]
            D = (d.get("distortion_coefficients") or {}).get("data", [])
            w, h = d.get("image_width"), d.get("image_height")
        elif "k" in d or "K" in d:
            K = d.get("k", d.get("K"))
            D = d.get("d", d.get("D", []))
            w, h = d.get("width"), d.get("height")
        else:
            raise ValueError("no camera_matrix (calibration YAML) or k (CameraInfo YAML)")
        if w is None or h is None:
            raise ValueError("image size missing")
        K = np.asarray(K, dtype=float).reshape(3, 3)
        D = np.asarray(D, dtype=float)
        w, h = int(w), int(h)
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{p}: not a camera YAML: {e}") from None
    return CameraModel(
        K=K,
        D=D,
        width=w,
        height=h,
        line_delay=float(line_delay),
        distortion_model=str(d.get("distortion_model") or "plumb_bob"),
    )


def detect_folder(
    folder: str | Path,
    camera: CameraModel,
    dictionary: str,
    fps: float,
    progress: bool = True,
    detector_options: object = None,
) -> tuple[list, dict]:
    """Detect markers in every image of a folder (sorted by name; one frame each).

    Detection: :class:`rs_localizer.frontends.aruco.ArucoFrontend` (the AprilTag 3 library for
    AprilTag families, OpenCV's ArUco detector for the ArUco dictionaries:
    :func:`rs_localizer.frontends.marker_detection.make_marker_detector`, with
    ``detector_options``). An id found twice in one image is dropped from that image
    (counted). Frame ``i`` is stamped ``i / fps`` plus the reference line's capture time.

    Args:
        folder: directory of images (:data:`IMAGE_SUFFIXES`). camera: the camera (size check,
            RS timing). dictionary: OpenCV dictionary name, e.g. ``DICT_APRILTAG_36h11``.
        fps: frame rate (Hz). progress: show a progress bar (tqdm). detector_options:
            :class:`~rs_localizer.frontends.marker_detection.DetectorOptions` (None: defaults).
    Returns:
        ``(frames, counts)``: :class:`FrameDetections` per image, and counts ``images``,
        ``without_markers``, ``duplicate_ids``.
    Raises:
        FileNotFoundError: no such folder, or no images in it. ValueError: an image of another
        size than the camera, an unreadable image, an unknown dictionary, fps <= 0.
    """
    import cv2
    from tqdm import tqdm

    from ..frontends import ArucoFrontend

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"image folder {folder} not found")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise FileNotFoundError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    front = ArucoFrontend({}, dictionary, detector_options=detector_options)
    t_ref = float(camera.line_time(camera.reference_line))
    frames, counts = [], {"images": len(files), "without_markers": 0, "duplicate_ids": 0}
    for i, f in enumerate(tqdm(files, desc="detecting markers", disable=not progress)):
        img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise ValueError(f"{f}: not a readable image")
        if img.shape != (camera.height, camera.width):
            raise ValueError(
                f"{f}: image is {img.shape[1]}x{img.shape[0]}, the camera "
                f"{camera.width}x{camera.height}"
            )
        dets, dup = detect_image(front, img)
        counts["duplicate_ids"] += dup
        counts["without_markers"] += not dets
        frames.append(FrameDetections(i / fps + t_ref, dets))
    return frames, counts


def detect_image(front: ArucoFrontend, gray: np.ndarray) -> tuple[dict, int]:
    """Markers in one (H, W) uint8 image with an :class:`ArucoFrontend`: ``({id: (4, 2)
    pixel corners}, number of ids found more than once)``; an id found twice is dropped (by the
    front end's detector, which counts it, or here)."""
    corners, ids = front.detect(gray, "mono8")
    dropped = int(front.detector.last_duplicates)
    ids = [int(m) for m in np.ravel(ids)] if ids is not None else []
    dets, dup = {}, 0
    for m in set(ids):
        idx = [j for j, k in enumerate(ids) if k == m]
        if len(idx) > 1:
            dup += 1
            continue
        dets[m] = np.asarray(corners[idx[0]], dtype=float).reshape(4, 2)
    return dets, dup + dropped


def write_atomic(path: str | Path, text: str, overwrite: bool = False) -> Path:
    """Write ``text`` to ``path`` whole or not at all, with the user's umask mode
    (:func:`rs_localizer.maps.files.write_text_atomic`).

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False.
    """
    return write_text_atomic(path, text, overwrite)


def write_map(
    path: str | Path,
    result: MarkerMapResult,
    dictionary: str,
    overwrite: bool = False,
    lines: int | None = None,
) -> Path:
    """Write the map in the marker-map format through its one writer
    (:func:`rs_localizer.maps.markers.write_marker_map`; :func:`rs_localizer.maps.load_marker_map`,
    the ArUco front end and the node's ``frontend_map`` read it): ``dictionary``, the
    ``anchor`` id, ``frame``: how the frame is fixed (``kind``, ``anchors``) and its own
    uncertainty (``rotation_std_deg``, ``position_std_mm``), and per marker ``id``, ``corners``
    (4, 3) m in ArUco order, plus ``std_position`` (3,) m and ``std_rotation`` (3,) rad (world
    axes; in the map's frame, the frame's own uncertainty included) and ``observations``;
    ``readout``: the line delay used (:func:`readout_dict`; ``lines``: the camera's lines, for
    the readout time). Readers that know only ``dictionary`` and the markers' ``id`` and
    ``corners`` read it as before. Written atomically.

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False.
    """
    fields = {}
    for m in result.corners:
        std = result.marker_std[m]
        fields[m] = {
            "std_position": np.round(std[3:], 6).tolist(),
            "std_rotation": np.round(std[:3], 6).tolist(),
            "observations": int(result.observations[m]),
        }
    return write_marker_map(
        path,
        dictionary,
        result.corners,
        anchor=int(result.anchor),
        frame=None if result.frame is None else _frame_dict(result.frame),
        readout=readout_dict(result, lines),
        marker_fields=fields,
        overwrite=overwrite,
    )


def readout_dict(result: MarkerMapResult, lines: int | None = None) -> dict:
    """The map's ``readout`` entry (:func:`rs_localizer.maps.markers.load_marker_readout`):
    ``line_delay_s`` (s per line; copy it to the node's ``rs.line_delay``), ``readout_time_s``
    (``line_delay_s`` times ``lines`` when given: ``rs.readout_time``), ``calibrated`` and,
    when calibrated, ``line_delay_std_s``, ``observable`` and ``reason`` (why not, empty when
    observable)."""
    out: dict = {"line_delay_s": float(result.line_delay)}
    if lines:
        out["readout_time_s"] = float(result.line_delay * lines)
    out["calibrated"] = result.readout_verdict is not None
    if result.readout_verdict is not None:
        out["line_delay_std_s"] = float(result.line_delay_std)
        out["observable"] = not result.readout_verdict
        out["reason"] = result.readout_verdict
    return out


def readout_line(result: MarkerMapResult, lines: int | None = None) -> str:
    """One line on the line delay the map was built with: value, and when calibrated its std
    and the observable / not observable verdict (the rule of ``calibrate-readout``)."""
    ld = 1e6 * result.line_delay
    rt = f" (readout time {1e3 * result.line_delay * lines:.3f} ms)" if lines else ""
    if result.readout_verdict is None:
        return f"line delay {ld:.3f} us/line{rt}, not calibrated (--calibrate-readout)"
    std = 1e6 * result.line_delay_std
    verdict = (
        "observable"
        if not result.readout_verdict
        else f"NOT observable: {result.readout_verdict}; keep your camera's value"
    )
    return f"line delay {ld:.3f} +- {std:.3f} us/line{rt} (calibrated, std): {verdict}"


def _frame_dict(frame: object) -> dict:
    """The output frame's description for the map file and the report."""
    return {
        "kind": frame.kind,
        "anchors": [int(m) for m in frame.anchors],
        "rotation_std_deg": round(float(frame.rotation_std_deg), 4),
        "position_std_mm": round(float(frame.position_std_mm), 2),
        "surveyed_residual_mm": round(float(frame.residual_mm), 2),
        "shared_error_correlation": round(float(frame.shared_error_correlation), 3),
        **(
            {"up_source": frame.up_source, "up_markers": [int(m) for m in frame.up_markers]}
            if frame.up_source
            else {}
        ),
        **({"note": frame.note} if frame.note else {}),
    }


def write_report(
    folder: str | Path, result: MarkerMapResult, counts: dict | None = None
) -> Sequence[Path]:
    """Write ``report.yaml`` (per marker: observations, position and rotation std; RMSE, line
    delay, the detector's corner offset, rejected detections, skipped frames, markers left out
    and inconsistent ids, videos refused, stage times) and ``map.png`` (matplotlib: markers
    and camera path on the map's x-y plane (from above in a gravity-aligned frame) and x-z
    plane (from the side)) into ``folder``. Returns the two
    paths.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import yaml

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rep = {
        "anchor": int(result.anchor),
        "model": "global shutter" if result.global_shutter else "rolling shutter",
        "reprojection_rmse_px": round(result.rmse_px, 4),
        "line_delay_s": float(result.line_delay),
        "readout": readout_dict(result),
        "corner_offset_px": round(float(result.corner_offset_px), 4),
        "corner_offset_std_px": round(float(result.corner_offset_std_px), 4),
        "rejected_detections": int(result.num_rejected),
        "frames_with_pose": len(result.frame_ids),
        "frames_skipped": int(result.num_frames_skipped),
        **({"frame": _frame_dict(result.frame)} if result.frame is not None else {}),
        "coverage": {int(m): why for m, why in result.coverage.items()},
        **({"detection": dict(counts)} if counts else {}),
        "markers": {
            int(m): {
                "observations": int(result.observations[m]),
                "std_position_mm": np.round(1e3 * result.marker_std[m][3:], 2).tolist(),
                "std_rotation_deg": np.round(np.degrees(result.marker_std[m][:3]), 3).tolist(),
            }
            for m in sorted(result.corners)
        },
        "left_out": {int(m): why for m, why in result.unmapped.items()},
        "inconsistent": {
            int(m): [np.round(p, 3).tolist() for p in ps] for m, ps in result.inconsistent.items()
        },
        **(
            {"refused_videos": {int(v): why for v, why in result.refused_videos.items()}}
            if result.refused_videos
            else {}
        ),
        "timings_s": {k: round(v, 3) for k, v in result.timings.items()},
    }
    yml = write_atomic(folder / "report.yaml", yaml.safe_dump(rep, sort_keys=False), True)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.5))
    for ax, (i, j), title in zip(axes, ((0, 1), (0, 2)), ("top view", "side view"), strict=True):
        ax.plot(result.position[:, i], result.position[:, j], "-", color="0.5", lw=1)
        ax.plot(result.position[:1, i], result.position[:1, j], "o", color="0.3", ms=4)
        for m, c in result.corners.items():
            q = np.vstack([c, c[:1]])
            ax.plot(q[:, i], q[:, j], "-", color="C3" if m == result.anchor else "C0", lw=1.5)
            ax.annotate(str(m), c.mean(0)[[i, j]], fontsize=7)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)" if j == 1 else "z (m)")
        ax.set_title(f"{title}: markers (anchor {result.anchor} red), camera path (grey)")
        if j == 1 and result.frame is not None and result.frame.kind != "gravity":
            ax.set_title(f"x-y plane (not gravity-aligned): markers (anchor {result.anchor} red)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    png = folder / "map.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return yml, png
