"""Feature maps from photos: a COLMAP reconstruction as the map of the features front end.

The paper's real-data protocol (sec. 4.2): a 3D model of the place built from global-shutter
(or slowly taken) photos, then the rolling-shutter frames matched against it. COLMAP builds such
models (structure from motion, global shutter); ``pycolmap`` (optional extra ``mapping``) reads
them and runs the reconstruction:

* :func:`reconstruct`: photos + known intrinsics -> a COLMAP sparse model (feature extraction,
  sequential or exhaustive matching, incremental mapping; pycolmap);
  :func:`reconstruct_aligned`: the same, aligned on a marker map, reconstructed again with the
  other matching when the alignment refuses a bent model.
* :func:`feature_map_from_colmap`: a sparse model + its database -> a
  :class:`~rs_localizer.maps.features.FeatureMap` (kind ``sift``): one map row per 3D
  point, its descriptor the medoid of its track, its id the COLMAP point id, track length and
  reprojection error kept as quality.
* :func:`align_to_markers` / :func:`scale_feature_map`: a reconstruction has no scale; markers
  seen in the photos give the similarity transform to the marker map's (metric) frame.

Conventions: COLMAP puts the centre of the top-left pixel at (0.5, 0.5), OpenCV (and this
package) at (0, 0): COLMAP pixel = OpenCV pixel + 0.5 (:func:`colmap_camera`, marker
triangulation). COLMAP's SIFT descriptors are uint8 RootSIFT (``L1_ROOT``: L1-normalised, square
root, x512); OpenCV's are float32 L2-normalised x512: :func:`opencv_sift_from_colmap` converts
the map's so that the front end compares like with like.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import cv2
import numpy as np

from ..camera import CameraModel
from ..frontends import representative_descriptors
from ..maps.features import FeatureMap

__all__ = [
    "INSTALL_HINT",
    "Attempt",
    "BentModelError",
    "MarkerAlignment",
    "align_feature_map",
    "align_to_markers",
    "colmap_camera",
    "feature_map_from_colmap",
    "import_pycolmap",
    "opencv_sift_from_colmap",
    "read_model",
    "reconstruct",
    "reconstruct_aligned",
    "scale_feature_map",
]

INSTALL_HINT = "pip install 'rs_localizer[mapping]' (or: pip install 'pycolmap>=4.2')"

#: COLMAP camera model per distortion model (coefficients in OpenCV order)
_COLMAP_MODELS = {"none": "PINHOLE", "plumb_bob": "FULL_OPENCV", "rational_polynomial": None}


def import_pycolmap() -> Any:
    """The ``pycolmap`` module. Raises ModuleNotFoundError naming how to install it."""
    try:
        import pycolmap
    except ModuleNotFoundError as e:
        raise ModuleNotFoundError(f"pycolmap is not installed: {INSTALL_HINT}") from e
    return pycolmap


@contextmanager
def _quiet(pycolmap: Any) -> Iterator[None]:
    """COLMAP's own log down to errors while it runs. Its info lines (one per step) would
    bury the progress; its warnings are mostly Ceres' "Linear solver failure. Failed to compute
    a step: Eigen failure" from the bundle adjustments: at an iteration where the normal
    equations are not positive definite (a point or photo barely constrained yet, early in the
    reconstruction) Ceres rejects the step, raises its damping and goes on. They say nothing
    about the model; its registered photos, reprojection error and the marker alignment do."""
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = level


def colmap_camera(camera: CameraModel) -> Any:
    """The ``pycolmap.Camera`` of ``camera``: ``PINHOLE`` (no distortion), ``FULL_OPENCV``
    (plumb_bob / rational_polynomial: the same radial-tangential model) or ``OPENCV_FISHEYE``
    (equidistant); principal point + 0.5 px (COLMAP's pixel-centre convention).

    Raises:
        ModuleNotFoundError: pycolmap missing.
    """
    pycolmap = import_pycolmap()
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    cx, cy = camera.K[0, 2] + 0.5, camera.K[1, 2] + 0.5
    D = np.zeros(8)
    D[: len(camera.D)] = camera.D
    if not camera.has_distortion:
        model, params = "PINHOLE", [fx, fy, cx, cy]
    elif camera.distortion_model == "equidistant":
        model, params = "OPENCV_FISHEYE", [fx, fy, cx, cy, *D[:4]]
    else:
        model, params = "FULL_OPENCV", [fx, fy, cx, cy, *D]
    return pycolmap.Camera(
        model=model, width=camera.width, height=camera.height, params=np.asarray(params, float)
    )


def opencv_sift_from_colmap(descriptors: np.ndarray) -> np.ndarray:
    """COLMAP's uint8 RootSIFT descriptors (N, 128) -> OpenCV's SIFT normalisation (N, 128)
    float32 (L2 norm 512). RootSIFT is ``sqrt(h / |h|_1)`` of the clipped SIFT histogram
    ``h``, stored x512 (COLMAP ``Normalization.L1_ROOT``): squaring recovers ``h / |h|_1``, which
    is rescaled to OpenCV's ``512 h / |h|_2`` (the clipping at 0.2 was applied before both)."""
    h = (np.asarray(descriptors, dtype=np.float64) / 512.0) ** 2
    n = np.linalg.norm(h, axis=1, keepdims=True)
    return (512.0 * h / np.where(n > 0, n, 1.0)).astype(np.float32)


def read_model(model_dir: str | Path) -> Any:
    """Read a COLMAP sparse model (``cameras``, ``images``, ``points3D``; ``.bin`` or ``.txt``).

    Returns:
        ``pycolmap.Reconstruction``.
    Raises:
        FileNotFoundError: no such directory. ValueError: a directory without a COLMAP model,
        or one pycolmap cannot read. ModuleNotFoundError: pycolmap missing.
    """
    pycolmap = import_pycolmap()
    d = Path(model_dir)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: no such model directory")
    names = ("cameras", "images", "points3D")
    if not any(all((d / f"{n}.{ext}").is_file() for n in names) for ext in ("bin", "txt")):
        raise ValueError(
            f"{d}: not a COLMAP sparse model (needs cameras, images, points3D as .bin or .txt; "
            "e.g. the sparse/0 directory of a COLMAP project)"
        )
    try:
        with _quiet(pycolmap):
            return pycolmap.Reconstruction(str(d))
    except Exception as e:  # pycolmap raises its own (RuntimeError / ValueError) on bad files
        raise ValueError(f"{d}: COLMAP cannot read the model: {e}") from None


def _find_database(model_dir: Path) -> Path:
    for d in (model_dir, model_dir.parent, model_dir.parent.parent):
        if (d / "database.db").is_file():
            return d / "database.db"
    raise FileNotFoundError(
        f"{model_dir}: no database.db beside the model or two levels up; pass the COLMAP "
        "database of this model"
    )


def feature_map_from_colmap(
    model_dir: str | Path,
    database: str | Path | None = None,
    min_track: int = 3,
    max_error: float | None = None,
    descriptors_per_landmark: int = 1,
    opencv_normalisation: bool = True,
) -> FeatureMap:
    """A COLMAP sparse model and its database -> a ``sift`` :class:`FeatureMap`.

    Each 3D point with at least ``min_track`` observations (and mean reprojection error <=
    ``max_error`` px when given) becomes a landmark (id = COLMAP ``point3D_id``). Its
    descriptors are those of its track's observations read from the database, converted to
    OpenCV's SIFT normalisation (:func:`opencv_sift_from_colmap`); the medoid (smallest summed
    L2 distance to the track's other descriptors; ``descriptors_per_landmark`` > 1 keeps that
    many, 0 all) is kept. The model's camera may differ from the camera that localizes.

    Args:
        model_dir: COLMAP sparse model directory (binary or text).
        database: its ``database.db`` (default: found beside the model or up to two levels up).
        min_track: smallest track length kept. max_error: largest reprojection error (px).
        descriptors_per_landmark: descriptors per point (see above).
        opencv_normalisation: convert the descriptors (default); False keeps COLMAP's values
            (as float32), for comparing the two (``bench_feature_map``).
    Returns:
        :class:`FeatureMap` with ``points`` (M, 3) in the model's frame and scale (``metric``
        False), ``track_length`` and ``reprojection_error`` (M,).
    Raises:
        FileNotFoundError: model or database missing. ValueError: not a COLMAP model, a database
        whose images (ids, names, feature counts) do not match the model, no point left after
        the filters. ModuleNotFoundError: pycolmap missing.
    """
    pycolmap = import_pycolmap()
    rec = read_model(model_dir)
    db_path = Path(database) if database is not None else _find_database(Path(model_dir))
    if not db_path.is_file():
        raise FileNotFoundError(f"{db_path}: no such COLMAP database")
    rows: list[tuple[int, int, int]] = []  # (point id, image id, point2D index)
    ids, xyz, tracks, errors = [], [], [], []
    for pid, pt in rec.points3D.items():
        els = pt.track.elements
        if len(els) < int(min_track) or (max_error is not None and pt.error > max_error):
            continue
        ids.append(int(pid))
        xyz.append(np.asarray(pt.xyz, float))
        tracks.append(len(els))
        errors.append(float(pt.error))
        rows.extend((int(pid), int(e.image_id), int(e.point2D_idx)) for e in els)
    if not ids:
        raise ValueError(
            f"{model_dir}: no 3D point with a track of >= {min_track} images"
            + ("" if max_error is None else f" and error <= {max_error} px")
        )
    needed = sorted({r[1] for r in rows})
    descs: dict[int, np.ndarray] = {}
    try:
        db = pycolmap.Database.open(str(db_path))
    except Exception as e:
        raise ValueError(f"{db_path}: not a COLMAP database: {e}") from None
    try:
        for iid in needed:
            image = rec.images[iid]
            if not db.exists_image(iid) or db.read_image(iid).name != image.name:
                raise ValueError(
                    f"{db_path}: image id {iid} ({image.name}) of the model is not in the "
                    "database under that name: the database is not this model's"
                )
            d = np.asarray(db.read_descriptors(iid).data)
            if d.shape != (image.num_points2D(), 128):
                raise ValueError(
                    f"{db_path}: image {image.name} has {d.shape[0]} descriptors, the model "
                    f"{image.num_points2D()} keypoints: the database is not this model's"
                )
            descs[iid] = d
    finally:
        db.close()
    order = {pid: k for k, pid in enumerate(ids)}
    labels = np.array([order[r[0]] for r in rows], dtype=np.int64)
    raw = np.stack([descs[r[1]][r[2]] for r in rows])
    des = opencv_sift_from_colmap(raw) if opencv_normalisation else raw.astype(np.float32)
    keep = (
        representative_descriptors(des, labels, int(descriptors_per_landmark), "sift")
        if descriptors_per_landmark
        else np.arange(len(labels))
    )
    lab = labels[keep]
    return FeatureMap(
        np.asarray(xyz)[lab],
        des[keep],
        np.asarray(ids, dtype=np.int64)[lab],
        "sift",
        track_length=np.asarray(tracks, dtype=np.int64)[lab],
        reprojection_error=np.asarray(errors)[lab],
        metric=False,
    )


def scale_feature_map(feature_map: FeatureMap, scale: float) -> FeatureMap:
    """The map with its points multiplied by ``scale`` (model units -> metres), marked metric.

    Raises:
        ValueError: a scale that is not finite and > 0."""
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"scale must be finite and > 0, got {scale}")
    fm = feature_map.subset(np.arange(len(feature_map)))
    fm.points = fm.points * float(scale)
    fm.metric = True
    return fm


class BentModelError(ValueError):
    """The marker alignment refused a model: its RMS corner residual exceeds the bound (a
    bent reconstruction, or photos and marker map that disagree)."""


@dataclass
class MarkerAlignment:
    """Similarity ``x_map = scale * R @ x_model + t`` found by :func:`align_to_markers`.

    ``markers``: ids of the markers used; ``residual_rms`` / ``residual_max`` (m, map frame):
    distances between the marker map's corners and the transformed triangulated ones;
    ``corners`` (K, 3) triangulated corners (model frame), ``reference`` (K, 3) map corners;
    ``reprojection_errors`` (D,) px: per detection of a marker in a photo, the distance between
    the centre of the detected marker and that of the map's marker projected into the photo
    with the model's pose moved by the similarity (on the undistorted image plane, scaled by
    the focal length); empty when the similarity was not refined on them.
    """

    scale: float
    R: np.ndarray
    t: np.ndarray
    markers: list
    residual_rms: float
    residual_max: float
    corners: np.ndarray
    reference: np.ndarray
    reprojection_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) model points -> (N, 3) map points (m)."""
        return self.scale * np.asarray(points, float) @ self.R.T + self.t


def _triangulate(rays_o: np.ndarray, rays_d: np.ndarray) -> np.ndarray:
    """Least-squares intersection (3,) of rays (origins (K, 3), unit directions (K, 3))."""
    P = np.eye(3)[None] - rays_d[:, :, None] * rays_d[:, None, :]
    return np.linalg.solve(P.sum(axis=0), np.einsum("kij,kj->i", P, rays_o))


def _triangulate_robust(
    rays_o: np.ndarray, rays_d: np.ndarray, cos_min_angle: float, max_angle: float
) -> np.ndarray | None:
    """Intersection (3,) of the rays that agree: every pair spanning more than the minimum
    angle is a hypothesis, the one that most rays pass within ``max_angle`` (rad) of wins and
    is refitted on them (a photo that COLMAP registered at a wrong pose does not bend it).
    None when no pair spans the angle or fewer than two rays agree."""
    best, best_in = None, 1
    n = len(rays_d)
    for i in range(n):
        for j in range(i + 1, n):
            if rays_d[i] @ rays_d[j] > cos_min_angle:
                continue
            X = _triangulate(rays_o[[i, j]], rays_d[[i, j]])
            v = X - rays_o
            cos = np.einsum("kj,kj->k", v, rays_d) / np.maximum(np.linalg.norm(v, axis=1), 1e-12)
            inl = cos > np.cos(max_angle)
            if inl.sum() > best_in:
                best, best_in = inl, int(inl.sum())
    if best is None:
        return None
    return _triangulate(rays_o[best], rays_d[best])


def _marker_rays(rec: Any, images_dir: str | Path, corners3d: dict, dictionary: str) -> tuple:
    """The map's markers detected in every registered photo of the model ``rec``: per corner
    key ``4 * id + corner`` the rays ``[(origin (3,), unit direction (3,))]`` in the model's
    frame, and per detection ``(id, (4, 2) undistorted normalized corners, Rc, tc, focal)``
    (the photo's model pose ``x_cam = Rc x + tc``, its focal length in px).

    Raises:
        FileNotFoundError: a registered photo missing from ``images_dir``."""
    from ..frontends import ArucoFrontend

    det = ArucoFrontend(corners3d, dictionary)
    obs: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    dets: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, float]] = []
    for iid in sorted(rec.reg_image_ids()):
        image = rec.images[iid]
        path = Path(images_dir) / image.name
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise FileNotFoundError(f"{path}: registered photo missing or unreadable")
        px, mids = det.detect(gray, "mono8")
        if len(mids) == 0:
            continue
        xy = np.asarray(image.camera.cam_from_img(px.reshape(-1, 2).astype(float) + 0.5))
        world_from_cam = image.cam_from_world().inverse()
        Rw = np.asarray(world_from_cam.rotation.matrix())
        o = np.asarray(world_from_cam.translation, float)
        d = np.c_[xy, np.ones(len(xy))] @ Rw.T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        cam_from_world = image.cam_from_world()
        Rc = np.asarray(cam_from_world.rotation.matrix())
        tc = np.asarray(cam_from_world.translation, float)
        focal = float(image.camera.mean_focal_length())
        for k, m in enumerate(np.repeat(np.asarray(mids).ravel(), 4)):
            if int(m) in corners3d:
                obs.setdefault(4 * int(m) + k % 4, []).append((o, d[k]))
                if k % 4 == 3:
                    dets.append((int(m), xy[k - 3 : k + 1], Rc, tc, focal))
    return obs, dets


def _triangulate_corners(
    obs: dict, corners3d: dict, cos_min: float, max_ray_angle: float
) -> tuple[list, list, set]:
    """Corners seen from two or more photos, triangulated robustly
    (:func:`_triangulate_robust`): ``(model points [(3,)], their map corners [(3,)], ids of
    the markers used)``."""
    model_pts, map_pts, used = [], [], set()
    for key, views in sorted(obs.items()):
        if len(views) < 2:
            continue
        X = _triangulate_robust(
            np.array([v[0] for v in views]), np.array([v[1] for v in views]), cos_min, max_ray_angle
        )
        if X is None:  # too narrow a baseline, or no two photos agree
            continue
        model_pts.append(X)
        map_pts.append(corners3d[key // 4][key % 4])
        used.add(key // 4)
    return model_pts, map_pts, used


def align_to_markers(
    model_dir: str | Path,
    images_dir: str | Path,
    markers: str | Path,
    min_markers: int = 3,
    max_residual: float = 0.02,
    min_angle_deg: float = 2.0,
    max_ray_angle: float = 0.005,
    refine: bool = True,
    loss_scale_px: float = 1.0,
) -> MarkerAlignment:
    """Similarity transform from a COLMAP model's frame to a marker map's (metric) frame.

    ArUco markers are detected in every registered photo
    (:class:`~rs_localizer.frontends.aruco.ArucoFrontend`, the map's dictionary); each corner
    seen in two or more photos whose rays span at least ``min_angle_deg`` is triangulated with
    the model's poses and camera (pixels + 0.5 for COLMAP; least-squares intersection of the
    rays that pass within ``max_ray_angle`` rad of a common point, chosen over the pairs of
    rays, so that a photo registered at a wrong pose is left out), and
    scale, rotation and translation come from Umeyama's method on the corners common to the map
    (``cv2.estimateAffine3D(..., force_rotation=True)``).

    With ``refine`` (default) that similarity is then refined on every detection of a marker
    of the map: the 7 parameters minimise, over all photos, the distance between the centre
    of the detected marker (mean of its four corners) and that of the map's marker projected
    into the photo, whose model pose the similarity moves to the map frame
    (``scipy.optimize.least_squares``, Cauchy loss of scale ``loss_scale_px``: a marker
    detected wrongly, or a photo at a wrong pose, weighs little). Each detection then counts
    with the precision it has, where the triangulation weighs a corner seen only along a
    narrow baseline (its depth uncertain) as much as one seen from all sides; and the centre
    cancels the detector's pull of the four corners towards the inside of the marker (0.18 px
    on the benchmark's photos, against the true projections). On the benchmark's
    reconstruction (``bench_feature_map``) the rotation error of the alignment drops from
    0.09 deg to 0.014 deg, and a frame localized against the map inherits it
    (docs/feature_maps.md).

    Args:
        model_dir: COLMAP sparse model. images_dir: the photos it was built from.
        markers: marker map YAML or scene (:func:`rs_localizer.maps.load_marker_map`).
        min_markers: fewest markers common to model and map. max_residual: largest RMS corner
            residual (m) accepted (triangulated corners, final similarity).
        min_angle_deg, max_ray_angle: the corner triangulation (above).
        refine: refine on the detections (above); False: Umeyama's similarity on the
            triangulated corners only.
        loss_scale_px: scale (px) of the refinement's Cauchy loss.
    Returns:
        :class:`MarkerAlignment`.
    Raises:
        ValueError: fewer than ``min_markers`` markers triangulated and in the map, or an RMS
        residual over ``max_residual`` (photos or map of another place, a moved marker).
        FileNotFoundError: a registered photo missing from ``images_dir``.
    """
    from ..maps import load_marker_map

    rec = read_model(model_dir)
    dictionary, corners3d = load_marker_map(markers)
    obs, dets = _marker_rays(rec, images_dir, corners3d, dictionary)
    model_pts, map_pts, used = _triangulate_corners(
        obs, corners3d, np.cos(np.deg2rad(min_angle_deg)), max_ray_angle
    )
    if len(used) < int(min_markers):
        raise ValueError(
            f"marker alignment needs >= {min_markers} markers of the map triangulated in the "
            f"model, found {len(used)} ({sorted(used)}): take photos that see more markers "
            "from two or more viewpoints, or use --scale"
        )
    src = np.asarray(model_pts)
    dst = np.asarray(map_pts, dtype=float)
    Rt, scale = cv2.estimateAffine3D(src, dst, force_rotation=True)
    Rt = np.asarray(Rt, float)
    R, t, scale = Rt[:, :3], Rt[:, 3], float(scale)
    reprojection = np.zeros(0)
    if refine and np.isfinite(scale) and scale > 0:
        X = np.array([corners3d[dd[0]] for dd in dets], dtype=float)
        scale, R, t, reprojection = _refine_on_detections(
            scale,
            R,
            t,
            X,
            np.array([dd[1] for dd in dets]),
            np.array([dd[2] for dd in dets]),
            np.array([dd[3] for dd in dets]),
            np.array([dd[4] for dd in dets]),
            float(loss_scale_px),
        )
    res = np.linalg.norm(scale * src @ R.T + t - dst, axis=1)
    rms = float(np.sqrt(np.mean(res**2)))
    if not np.isfinite(rms) or rms > max_residual:
        raise BentModelError(
            f"marker alignment residual {rms * 100:.1f} cm RMS over {len(res)} corners exceeds "
            f"{max_residual * 100:.1f} cm: the reconstruction is bent (photos registered at "
            "wrong poses where textures repeat: reconstruct again with the other --matching, "
            "more overlap), or the photos and the marker map do not agree (another place, a "
            "moved marker, a wrong marker size)"
        )
    return MarkerAlignment(scale, R, t, sorted(used), rms, float(res.max()), src, dst, reprojection)


def _refine_on_detections(
    scale: float,
    R: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    xy: np.ndarray,
    Rc: np.ndarray,
    tc: np.ndarray,
    focal: np.ndarray,
    loss_scale: float,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """The similarity ``x_map = scale R x_model + t`` refined on D marker detections: the
    marker's map corners X (D, 4, 3) m, detected at undistorted normalised coordinates xy
    (D, 4, 2) by photos with model poses ``x_cam = Rc x_model + tc`` (Rc (D, 3, 3), tc (D, 3))
    and focal lengths (D,) px. The residual of a detection is the mean of its four projected
    corners minus the mean of the four detected ones (px). Returns (scale, R, t, that
    residual's length per detection (D,) px)."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    def unpack(p: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        return scale * np.exp(p[6]), Rotation.from_rotvec(p[:3]).as_matrix() @ R, t + p[3:6]

    centre = xy.mean(axis=1)

    def residuals(p: np.ndarray) -> np.ndarray:
        s, Rp, tp = unpack(p)
        xc = np.einsum("dij,dkj->dki", Rc, ((X - tp) @ Rp) / s) + tc[:, None]
        z = np.where(xc[..., 2:] > 1e-9, xc[..., 2:], np.nan)
        r = focal[:, None] * ((xc[..., :2] / z).mean(axis=1) - centre)
        return np.nan_to_num(r, nan=1e6).ravel()

    sol = least_squares(residuals, np.zeros(7), loss="cauchy", f_scale=loss_scale, x_scale=1e-3)
    s, Rp, tp = unpack(sol.x)
    return float(s), Rp, tp, np.linalg.norm(residuals(sol.x).reshape(-1, 2), axis=1)


def align_feature_map(feature_map: FeatureMap, alignment: MarkerAlignment) -> FeatureMap:
    """The map's points moved by ``alignment`` (model frame -> marker map frame, metres)."""
    fm = feature_map.subset(np.arange(len(feature_map)))
    fm.points = alignment.apply(fm.points)
    fm.metric = True
    return fm


def _photo_names(src: Path, camera: CameraModel) -> list[str]:
    """Names of the photos (png/jpg) in ``src``, sorted, each checked to be readable and of
    the camera's size. Raises FileNotFoundError (none) or ValueError (a wrong size)."""
    names = (
        sorted(p.name for p in src.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
        if src.is_dir()
        else []
    )
    if not names:
        raise FileNotFoundError(f"{src}: no .png/.jpg photos")
    for n in names:
        img = cv2.imread(str(src / n), cv2.IMREAD_UNCHANGED)
        if img is None or img.shape[:2] != (camera.height, camera.width):
            got = "unreadable" if img is None else f"{img.shape[1]}x{img.shape[0]}"
            raise ValueError(
                f"{src / n}: {got}, the camera is {camera.width}x{camera.height}: photos and "
                "camera file do not belong together"
            )
    return names


def _extract(pycolmap: Any, db: Path, src: Path, names: list, camera: CameraModel, n: int):
    """COLMAP SIFT extraction (``n`` features per photo) with the fixed intrinsics."""
    cam = colmap_camera(camera)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cam.model_name
    reader.camera_params = ",".join(f"{v:.10g}" for v in cam.params)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = int(n)
    extraction.num_threads = 2
    pycolmap.extract_features(
        str(db),
        str(src),
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )


def _match(pycolmap: Any, db: Path, matching: str, overlap: int, seed: int) -> None:
    """COLMAP matching with geometric verification: every pair, or each photo with its next
    ``overlap`` (and quadratically further) ones in name order."""
    match_opts = pycolmap.FeatureMatchingOptions()
    match_opts.num_threads = 2
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(seed)
    if matching == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = int(overlap)
        pycolmap.match_sequential(
            str(db),
            matching_options=match_opts,
            pairing_options=pairing,
            verification_options=verification,
            device=pycolmap.Device.cpu,
        )
    else:
        pycolmap.match_exhaustive(
            str(db),
            matching_options=match_opts,
            verification_options=verification,
            device=pycolmap.Device.cpu,
        )


def _incremental_mapping(
    pycolmap: Any, db: Path, src: Path, out: Path, seed: int, bar: Any
) -> dict:
    """COLMAP incremental mapping, intrinsics fixed, on one thread with a fixed seed: with
    several threads COLMAP's mapper does not repeat its model for a seed (the order in which
    threads finish changes the registrations), on one it does (same photos, same model)."""
    opts = pycolmap.IncrementalPipelineOptions()
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.num_threads = 1
    opts.random_seed = int(seed)
    opts.mapper.random_seed = int(seed)
    opts.triangulation.random_seed = int(seed)

    def registered() -> None:
        bar.update(1)

    out.mkdir(exist_ok=True)
    return pycolmap.incremental_mapping(
        str(db), str(src), str(out), options=opts, next_image_callback=registered
    )


def reconstruct(
    images_dir: str | Path,
    camera: CameraModel,
    workdir: str | Path,
    min_registered: float = 0.5,
    progress: TextIO | None = sys.stderr,
    max_features: int = 4096,
    matching: str = "sequential",
    overlap: int = 10,
    seed: int = 0,
) -> Path:
    """COLMAP reconstruction of photos taken with one known camera (pycolmap): SIFT extraction
    with the fixed intrinsics (:func:`colmap_camera`), matching with geometric verification,
    incremental mapping (intrinsics not refined, one thread: repeatable); the largest model is
    kept.

    Args:
        images_dir: the photos (png/jpg), all ``camera.width`` x ``camera.height``.
        camera: their intrinsics and distortion.
        workdir: gets ``database.db``, COLMAP's models ``sparse/N`` and the largest of them
            as ``model``.
        min_registered: smallest fraction of photos the model must register.
        progress: stream for stage lines and progress bars (tqdm; None: quiet).
        max_features: SIFT features per photo.
        matching: ``sequential`` (each photo with the next ``overlap`` in name order, and
            quadratically further ones: photos taken along a walk; few wrong pairs where a
            texture repeats across the place) or ``exhaustive`` (every pair of photos: photos
            in no particular order; on tiled textures it can bend the model).
        seed: seed of COLMAP's RANSAC (verification, registration, triangulation).
    Returns:
        the model directory (``workdir/model``).
    Raises:
        FileNotFoundError: no photos. ValueError: an unknown ``matching``, a photo of
        another size than the camera, fewer than ``min_registered`` of the photos (or 3)
        registered. ModuleNotFoundError: pycolmap missing.
    """
    from tqdm import tqdm

    pycolmap = import_pycolmap()
    if matching not in ("exhaustive", "sequential"):
        raise ValueError(f"unknown matching {matching!r}; expected 'exhaustive' or 'sequential'")
    src = Path(images_dir)
    names = _photo_names(src, camera)
    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    if db.exists():
        db.unlink()

    def say(msg: str) -> None:
        if progress is not None:
            print(msg, file=progress, flush=True)

    t0 = time.perf_counter()
    with _quiet(pycolmap):
        say(f"[1/3] extracting SIFT features from {len(names)} photos ...")
        _extract(pycolmap, db, src, names, camera, max_features)
        t1 = time.perf_counter()
        say(f"[2/3] {matching} matching of {len(names)} photos ({t1 - t0:.1f} s) ...")
        _match(pycolmap, db, matching, overlap, seed)
        t2 = time.perf_counter()
        say(f"[3/3] incremental mapping ({t2 - t1:.1f} s) ...")
        with tqdm(
            total=len(names),
            initial=2,
            desc="registering photos",
            unit="photo",
            file=progress,
            disable=progress is None,
        ) as bar:
            models = _incremental_mapping(pycolmap, db, src, work / "sparse", seed, bar)
    best = max(models.values(), key=lambda r: r.num_reg_images(), default=None)
    n_reg = 0 if best is None else best.num_reg_images()
    if n_reg < max(3, int(np.ceil(min_registered * len(names)))):
        raise ValueError(
            f"{src}: COLMAP registered {n_reg} of {len(names)} photos (needs "
            f"{max(3, int(np.ceil(min_registered * len(names))))}): too little overlap or "
            "texture, or the camera file does not match the photos"
        )
    model_dir = work / "model"
    model_dir.mkdir(exist_ok=True)
    best.write(str(model_dir))
    say(
        f"model: {n_reg}/{len(names)} photos, {best.num_points3D()} points, reprojection "
        f"error {best.compute_mean_reprojection_error():.2f} px ({time.perf_counter() - t0:.1f} s)"
    )
    return model_dir


@dataclass
class Attempt:
    """One reconstruction tried by :func:`reconstruct_aligned`: its ``matching`` and ``seed``,
    and the marker ``alignment`` when accepted, else ``error`` (why it was refused)."""

    matching: str
    seed: int
    alignment: MarkerAlignment | None = None
    error: str = ""


def reconstruct_aligned(
    images_dir: str | Path,
    camera: CameraModel,
    workdir: str | Path,
    markers: str | Path,
    matching: str = "sequential",
    attempts: int = 3,
    max_residual: float = 0.02,
    seed: int = 0,
    progress: TextIO | None = sys.stderr,
) -> tuple[Path, MarkerAlignment, list[Attempt]]:
    """Reconstruct the photos (:func:`reconstruct`) and align the model on a marker map
    (:func:`align_to_markers`); a model the alignment refuses (residual over
    ``max_residual``: bent, photos registered at wrong poses where textures repeat) is
    reconstructed again, up to ``attempts`` times: the other matching, then the first with
    another seed, alternating. The first model that aligns is kept.

    Args:
        images_dir, camera, workdir: as :func:`reconstruct`. markers: marker map YAML or scene.
        matching: the first attempt's matching. attempts: most reconstructions (>= 1).
        max_residual: largest RMS corner residual (m). seed: the first attempt's seed.
        progress: stream for stage lines (None: quiet).
    Returns:
        ``(model dir, alignment, attempts)``: every attempt with its outcome, in order.
    Raises:
        ValueError: no attempt aligned; the message names every attempt's residual, the
        likely cause and what to try. Others as :func:`reconstruct` and
        :func:`align_to_markers` (too few markers is not retried: another matching does not
        add markers).
    """
    if attempts < 1:
        raise ValueError(f"attempts must be >= 1, got {attempts}")
    other = {"sequential": "exhaustive", "exhaustive": "sequential"}[matching]
    tried: list[Attempt] = []
    for i in range(int(attempts)):
        a = Attempt(matching if i % 2 == 0 else other, int(seed) + i // 2)
        tried.append(a)
        if progress is not None and i:
            print(
                f"attempt {i + 1}/{attempts}: {a.matching} matching, seed {a.seed}",
                file=progress,
                flush=True,
            )
        model = reconstruct(
            images_dir, camera, workdir, progress=progress, matching=a.matching, seed=a.seed
        )
        try:
            a.alignment = align_to_markers(model, images_dir, markers, max_residual=max_residual)
            return model, a.alignment, tried
        except BentModelError as e:
            a.error = str(e)
            if progress is not None:
                print(f"refused: {e}", file=progress, flush=True)
    summary = "; ".join(f"{a.matching} matching, seed {a.seed}: {a.error}" for a in tried)
    raise ValueError(
        f"no reconstruction of {images_dir} agrees with the marker map after {len(tried)} "
        f"attempt(s) ({summary}). Residuals of decimetres that change from attempt to attempt "
        "mean a bent reconstruction (photos registered at wrong poses where textures repeat): "
        "take photos with more overlap in walking order (name order) and fewer views of "
        "repeated texture alone, or more markers in view. Residuals that stay alike point at "
        "the marker map instead (another place, a moved marker, a wrong marker size)."
    )
