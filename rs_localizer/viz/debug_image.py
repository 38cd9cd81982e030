"""The ``debug_image`` of one frame: what the estimator made of the correspondences.

Drawn with OpenCV on the input image (image mode) or on a dark canvas of the camera's size
(correspondence mode), in BGR:

* every correspondence at its measured (distorted) pixel: inliers as filled green discs,
  outliers as red crosses;
* its residual vector, from the measured pixel towards the pixel the estimate predicts
  (rolling-shutter projection at the point's own capture line,
  :meth:`rs_localizer.camera.CameraModel.project_rs`), ``residual_scale`` times longer, in
  yellow (capped at ``max_residual_px`` so that outliers stay readable);
* a virtual cube, axis-aligned in the map, through the rolling-shutter model (every point at
  the capture time of its own line, cyan) next to the global-shutter projection of the same
  reference-line pose (magenta): where they differ is what a global-shutter pipeline gets wrong
  (paper sec. 4.2, Fig. 8);
* a text line: solver, inliers/total, RMSE (px), |omega| (rad/s), |v| (m/s), and a legend.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike

from ..camera import CameraModel

__all__ = [
    "CANVAS_GREY",
    "COLORS",
    "DebugImageOptions",
    "auto_cube",
    "cube_edge_points",
    "draw_debug_image",
    "frame_residuals",
    "to_bgr",
]

#: BGR colours of the drawing (tests read pixels of these colours)
COLORS = {
    "inlier": (0, 255, 0),
    "outlier": (0, 0, 255),
    "residual": (0, 255, 255),
    "cube_rs": (255, 255, 0),
    "cube_gs": (255, 0, 255),
    "text": (255, 255, 255),
    "unclassified": (200, 200, 200),
}
#: grey level of the canvas in correspondence mode
CANVAS_GREY = 40


@dataclass(frozen=True)
class DebugImageOptions:
    """How the debug image is drawn.

    Attributes:
        residual_scale: residual vectors are drawn this many times longer (0: not drawn).
        max_residual_px: drawn residual vectors are capped at this length (px).
        point_radius: radius of the inlier discs and half-size of the outlier crosses (px).
        cube: draw the virtual cube (RS and GS projections).
        cube_center: (3,) cube centre in the map (m); ``None``: on the optical axis of the
            reference-line pose at the median depth of the inliers (in view by construction).
        cube_side: cube side (m); ``None``: half the image height at that depth.
        cube_samples: points per cube edge (the RS projection of a straight edge is curved).
        background_gain: the input image is multiplied by this (the overlay reads better on a
            darker image).
        legend: add the legend line under the numbers.
    """

    residual_scale: float = 10.0
    max_residual_px: float = 60.0
    point_radius: int = 3
    cube: bool = True
    cube_center: tuple | None = None
    cube_side: float | None = None
    cube_samples: int = 16
    background_gain: float = 0.7
    legend: bool = True


def to_bgr(image: np.ndarray, encoding: str | None = None) -> np.ndarray:
    """(H, W) or (H, W, 3|4) uint8 image -> (H, W, 3) uint8 BGR copy.

    ``encoding`` (``sensor_msgs/Image`` name, e.g. from
    :func:`rs_localizer.ros.image_codec.decode_image`): ``mono8``/``8uc1``, ``rgb8``,
    ``bgr8``/``8uc3``, ``rgba8``, ``bgra8``/``8uc4``; ``None``: 3 channels are taken as RGB.

    Raises:
        ValueError: for another shape or dtype.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"expected a uint8 image, got {img.dtype}")
    enc = (encoding or "").lower()
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.ndim == 3 and img.shape[2] == 3:
        if enc in ("bgr8", "8uc3"):
            return img.copy()
        return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if img.ndim == 3 and img.shape[2] == 4:
        if enc in ("bgra8", "8uc4"):
            return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        return cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    raise ValueError(f"expected an (H, W) or (H, W, 3|4) image, got shape {img.shape}")


def frame_residuals(
    camera: CameraModel, points2d: ArrayLike, points3d: ArrayLike, est: Any
) -> np.ndarray:
    """(N, 2) pixels the estimate predicts for the world points ``points3d`` (N, 3): their
    rolling-shutter projection with ``est.model`` ``(R, C, w, t)``, each at the capture
    time of its own line (:meth:`CameraModel.project_rs`). The residual of a measured pixel
    (a row of ``points2d`` (N, 2) px) is ``prediction - pixel`` (px). ``nan`` rows for points
    behind the camera."""
    return camera.project_rs(points3d, est.model.R, est.model.C, est.model.w, est.model.t)


def auto_cube(
    camera: CameraModel, est: Any, X: ArrayLike, inliers: ArrayLike | None = None
) -> tuple[np.ndarray, float] | None:
    """Default cube: centre (3,) on the optical axis of the reference-line pose at the median
    depth of the (inlier) points ``X`` (N, 3), side = half the image height at that depth (m).
    Returns ``(center, side)``; ``None`` if no point is in front of the camera."""
    X = np.asarray(X, dtype=float).reshape(-1, 3)
    if inliers is not None and np.count_nonzero(inliers) >= 3:
        X = X[np.asarray(inliers, dtype=bool)]
    z = (X @ np.asarray(est.model.R).T + est.model.C)[:, 2]
    z = z[np.isfinite(z) & (z > 0)]
    if not len(z):
        return None
    depth = float(np.median(z))
    center = est.pose.position + depth * est.pose.orientation[:, 2]
    side = 0.5 * depth * camera.height / camera.K[1, 1]
    return center, side


def cube_edge_points(center: ArrayLike, side: float, samples: int = 16) -> np.ndarray:
    """(12, samples, 3) points along the 12 edges of the cube with ``center`` (3,) and ``side``
    (m), axis-aligned in the map frame."""
    c = np.asarray(center, dtype=float).reshape(3)
    h = 0.5 * float(side)
    v = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)]) + c
    edges = [
        (i, j) for i in range(8) for j in range(i + 1, 8) if np.count_nonzero(v[i] != v[j]) == 1
    ]
    s = np.linspace(0.0, 1.0, max(int(samples), 2))[:, None]
    return np.array([v[i] + s * (v[j] - v[i]) for i, j in edges])


def _in_view(camera: CameraModel, est, P) -> np.ndarray:
    """(N,) points in front of the camera and within 1.5x the field of view (distortion
    polynomials fold points far outside it back into the image)."""
    Pc = P @ np.asarray(est.model.R).T + est.model.C
    z = Pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = Pc[:, :2] / z[:, None]
    f = np.diag(camera.K)[:2]
    size = np.array([camera.width, camera.height], dtype=float)
    mid = (0.5 * (size - 1) - camera.K[:2, 2]) / f  # image centre, normalized
    half = 0.75 * size / f  # 1.5x half the field of view
    return (z > 1e-6) & np.all(np.abs(xn - mid) <= half, axis=1)


def _polyline(img, pts, color, thickness):
    """Draw (S, 2) pixels as a polyline, broken at nan rows."""
    ok = np.isfinite(pts).all(axis=1)
    run = []
    for p, good in zip(pts, ok, strict=False):
        if good:
            run.append(p)
            continue
        if len(run) > 1:
            cv2.polylines(
                img,
                [np.round(np.array(run) * 16).astype(np.int32)],
                False,
                color,
                thickness,
                cv2.LINE_AA,
                shift=4,
            )
        run = []
    if len(run) > 1:
        cv2.polylines(
            img,
            [np.round(np.array(run) * 16).astype(np.int32)],
            False,
            color,
            thickness,
            cv2.LINE_AA,
            shift=4,
        )


def _text_lines(img, lines, color):
    """Lines of text on a black band at the top of the image, scaled to fit its width."""
    _h, w = img.shape[:2]
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = float(np.clip(w / 1400.0, 0.35, 1.2))
    widest = max(cv2.getTextSize(s, font, scale, 1)[0][0] for s in lines)
    if widest > w - 8:
        scale *= (w - 8) / widest
    th = cv2.getTextSize("Ag|", font, scale, 1)[0][1]
    step = int(round(th * 1.8)) + 1
    cv2.rectangle(img, (0, 0), (w - 1, step * len(lines) + 4), (0, 0, 0), -1)
    for k, s in enumerate(lines):
        cv2.putText(img, s, (4, step * (k + 1) - 2), font, scale, color, 1, cv2.LINE_AA)


def draw_debug_image(
    camera: CameraModel,
    points2d: ArrayLike,
    points3d: ArrayLike,
    est: Any,
    image: np.ndarray | None = None,
    encoding: str | None = None,
    options: DebugImageOptions | None = None,
) -> np.ndarray:
    """Draw the debug image of one frame (see the module docstring).

    Args:
        camera: the frame's camera model (intrinsics, distortion, RS timing).
        points2d: (N, 2) px, the measured (distorted) pixels, the estimator's input rows.
        points3d: (N, 3) their world points (m, map frame).
        est: the :class:`rs_localizer.estimation.RSPoseEstimate` of the frame (``inliers`` over
            the same N rows). A failed estimate draws the points uncoloured (grey) and its
            failure reason; ``None`` likewise with no reason.
        image: the input image ((H, W) or (H, W, 3|4) uint8) or ``None`` for a dark canvas of
            the camera's size. encoding: its ``sensor_msgs/Image`` encoding (see
            :func:`to_bgr`).
        options: :class:`DebugImageOptions`.
    Returns:
        (H, W, 3) uint8 BGR image (``bgr8``).
    Raises:
        ValueError: ``points2d``/``points3d`` of different lengths or wrong shapes, a bad
            image.
    """
    o = options or DebugImageOptions()
    uv = np.asarray(points2d, dtype=float).reshape(-1, 2)
    X = np.asarray(points3d, dtype=float).reshape(-1, 3)
    if len(uv) != len(X):
        raise ValueError(f"points2d has {len(uv)} rows, points3d {len(X)}")
    if image is None:
        img = np.full((camera.height, camera.width, 3), CANVAS_GREY, np.uint8)
    else:
        img = to_bgr(image, encoding)
        if o.background_gain != 1.0:
            img = cv2.convertScaleAbs(img, alpha=float(o.background_gain))
    ok_est = est is not None and bool(est.success)
    n = len(uv)
    inl = np.zeros(n, dtype=bool)
    if ok_est and len(est.inliers) == n:
        inl = np.asarray(est.inliers, dtype=bool)
    finite = np.isfinite(uv).all(axis=1)
    if ok_est and o.cube:
        _draw_cubes(img, camera, X, est, inl, o)
    if ok_est and o.residual_scale > 0:
        _draw_residuals(img, camera, uv, X, est, finite, o)
    _draw_points(img, uv, finite, inl, ok_est, o)
    _text_lines(img, _caption(est, ok_est, inl, n, o), COLORS["text"])
    return img


def _draw_cubes(
    img: np.ndarray,
    camera: CameraModel,
    X: np.ndarray,
    est: Any,
    inl: np.ndarray,
    o: DebugImageOptions,
) -> None:
    """Stage 1 of :func:`draw_debug_image`: the cube's edges as the global-shutter projection
    (thin) and as the RS projection with the estimated twist (thick), where in view."""
    auto = auto_cube(camera, est, X, inl)
    center = (auto[0] if auto else None) if o.cube_center is None else o.cube_center
    side = (auto[1] if auto else None) if o.cube_side is None else float(o.cube_side)
    if center is None or side is None:
        return
    edges = cube_edge_points(center, side, o.cube_samples)
    P = edges.reshape(-1, 3)
    vis = _in_view(camera, est, P)
    for key, w, t, thick in (("cube_gs", None, None, 1), ("cube_rs", est.model.w, est.model.t, 2)):
        px = np.full((len(P), 2), np.nan)
        px[vis] = camera.project_rs(P[vis], est.model.R, est.model.C, w, t)
        for e in px.reshape(edges.shape[0], edges.shape[1], 2):
            _polyline(img, e, COLORS[key], thick)


def _draw_residuals(
    img: np.ndarray,
    camera: CameraModel,
    uv: np.ndarray,
    X: np.ndarray,
    est: Any,
    finite: np.ndarray,
    o: DebugImageOptions,
) -> None:
    """Stage 2 of :func:`draw_debug_image`: each reprojection error as a line from the
    measured pixel, scaled by ``residual_scale`` and capped to ``max_residual_px``."""
    pred = frame_residuals(camera, uv, X, est)
    d = (pred - uv) * o.residual_scale
    ln = np.linalg.norm(d, axis=1)
    cap = np.where(ln > o.max_residual_px, o.max_residual_px / np.maximum(ln, 1e-12), 1.0)
    end = uv + d * cap[:, None]
    good = finite & np.isfinite(end).all(axis=1)
    a = np.round(uv[good] * 16).astype(np.int64)
    b = np.round(end[good] * 16).astype(np.int64)
    for p, q in zip(a, b, strict=False):
        cv2.line(
            img,
            (int(p[0]), int(p[1])),
            (int(q[0]), int(q[1])),
            COLORS["residual"],
            1,
            cv2.LINE_8,
            shift=4,
        )


def _draw_points(
    img: np.ndarray,
    uv: np.ndarray,
    finite: np.ndarray,
    inl: np.ndarray,
    ok_est: bool,
    o: DebugImageOptions,
) -> None:
    """Stage 3 of :func:`draw_debug_image`: outliers as crosses (grey dots when unsolved),
    then inliers as dots."""
    n = len(uv)
    r = max(int(o.point_radius), 1)
    pix = np.round(uv).astype(np.int64, copy=False) if n else np.zeros((0, 2), np.int64)
    for k in np.flatnonzero(finite & ~inl):
        c = (int(pix[k, 0]), int(pix[k, 1]))
        if ok_est:
            cv2.drawMarker(img, c, COLORS["outlier"], cv2.MARKER_TILTED_CROSS, 2 * r + 1, 2)
        else:
            cv2.circle(img, c, r, COLORS["unclassified"], -1)
    for k in np.flatnonzero(finite & inl):
        cv2.circle(img, (int(pix[k, 0]), int(pix[k, 1])), r, COLORS["inlier"], -1)


def _caption(est: Any, ok_est: bool, inl: np.ndarray, n: int, o: DebugImageOptions) -> list[str]:
    """Stage 4 of :func:`draw_debug_image`: the text lines (solver, inliers, RMSE, twist
    magnitudes and the legend; or the failure reason)."""
    if ok_est:
        w = float(np.linalg.norm(est.pose.angular_velocity))
        v = float(np.linalg.norm(est.pose.linear_velocity))
        lines = [
            f"{est.solver}  inliers {int(inl.sum())}/{n}  RMSE {est.rmse_px:.2f} px  "
            f"|omega| {w:.3f} rad/s  |v| {v:.3f} m/s"
        ]
        if o.legend:
            lines.append(
                f"green inlier  red outlier  yellow residual x{o.residual_scale:g}  "
                "cyan RS cube  magenta global-shutter cube"
            )
        return lines
    why = getattr(est, "failure", None) if est is not None else None
    return [
        f"{getattr(est, 'solver', '') or 'no estimate'}  failed"
        + (f": {why}" if why else "")
        + f"  ({n} points)"
    ]
