"""Scenes as data: textured planar quads, decals (pictures, ArUco markers) on them.

A scene is a YAML file (see ``scenes/aruco_room.yaml`` for the format)::

    quads:    textured rectangles: origin (top-left corner as seen from the side that shows the
              texture unmirrored), u (right), v (down), size (along u, along v), texture
    decals:   pictures on a quad: quad name, at (a, b) metres along (u, v), size, texture
    markers:  ArUco markers on quads: explicit {id, quad, at, size} or {fill: {...}} grids
    checkerboards: checkerboards on quads: {quad, at, squares: [nu, nv], square} (their inner
              corners: :meth:`Scene.checkerboard_corner_points`)

Every marker corner has a known 3D position: corner ``k`` (ArUco order: top-left, top-right,
bottom-right, bottom-left of the black square) of marker ``id`` is correspondence id
``4 * id + k`` (:meth:`Scene.marker_corner_points`).

Built-in scenes: ``aruco_room`` and ``textured_room`` (rooms), and the single planar boards
``checkerboard`` (6x7 inner corners, 8 cm squares), ``aruco_board`` and ``apriltag_board``
(4x3 markers of 10 cm, DICT_4X4_250 / DICT_APRILTAG_36h11) (:func:`load_scene` by name).
Textures are uint8 RGB arrays; the renderer builds mip-map pyramids from them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ...cv_compat import marker_image
from ...maps.markers import marker_dictionary
from ...maps.scenes import (
    SCENE_DIR,
    as_vector,
    checkerboard_corners,
    checkerboard_layout,
    marker_layout,
    scene_names,
    scene_path,
    scene_quad_frames,
)

__all__ = [
    "SCENE_DIR",
    "Decal",
    "Marker",
    "Quad",
    "Scene",
    "load_scene",
    "marker_dictionary",
    "marker_texture",
    "scene_names",
]


@dataclass
class Quad:
    """A textured rectangle ``origin + a u + b v``, ``0 <= a <= size[0]``, ``0 <= b <= size[1]``.

    ``texture`` (Ht, Wt, 3) uint8 covers the whole quad: texture column ``j`` and row ``i`` sit at
    ``a = (j + 0.5) / Wt * size[0]``, ``b = (i + 0.5) / Ht * size[1]``.
    """

    name: str
    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    size: tuple
    texture: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        """Unit normal on the side that sees the texture unmirrored (``v x u``)."""
        return np.cross(self.v, self.u)

    def point(self, a: float | np.ndarray, b: float | np.ndarray) -> np.ndarray:
        """World point(s) at quad coordinates (a, b) (metres)."""
        a = np.asarray(a, dtype=float)[..., None]
        b = np.asarray(b, dtype=float)[..., None]
        return self.origin + a * self.u + b * self.v

    def corners(self) -> np.ndarray:
        w, h = self.size
        return self.point([0, w, w, 0], [0, 0, h, h])


@dataclass
class Decal:
    """A picture on quad ``quad`` (index) covering ``[a0, a0 + w] x [b0, b0 + h]``."""

    quad: int
    rect: tuple  # (a0, b0, a1, b1)
    texture: np.ndarray
    marker_id: int = -1


@dataclass
class Marker:
    """An ArUco marker: black square of side ``size`` with top-left corner at (a, b) on a quad."""

    id: int
    quad: int
    a: float
    b: float
    size: float


@dataclass
class Scene:
    """Quads, decals and markers (see the module docstring)."""

    name: str
    quads: list
    decals: list = field(default_factory=list)
    markers: list = field(default_factory=list)
    dictionary: str = "DICT_4X4_250"
    viewpoint: dict = field(
        default_factory=lambda: {"position": [0.0, 0.0, 1.5], "look_at": [1.0, 0.0, 1.5]}
    )
    background: tuple = (30, 30, 35)
    source: str | None = None  # YAML path it was loaded from
    #: the renderer's packed arrays of this scene, filled on its first render
    render_cache: object = field(default=None, repr=False, compare=False)
    _checker_corners: tuple = field(default=None, repr=False, compare=False)

    def quad_index(self, name: str) -> int:
        for i, q in enumerate(self.quads):
            if q.name == name:
                return i
        raise KeyError(
            f"scene {self.name!r} has no quad {name!r}; quads: {[q.name for q in self.quads]}"
        )

    # ---------------------------------------------------------------- markers
    def marker_corners(self) -> dict:
        """marker id -> (4, 3) world corners (top-left, top-right, bottom-right, bottom-left)."""
        out = {}
        for m in self.markers:
            q = self.quads[m.quad]
            s = m.size
            out[m.id] = q.point([m.a, m.a + s, m.a + s, m.a], [m.b, m.b, m.b + s, m.b + s])
        return out

    def marker_corner_points(self) -> tuple[np.ndarray, np.ndarray]:
        """(ids (4M,) int64 = 4 * marker_id + corner, points (4M, 3)) of all marker corners."""
        corners = self.marker_corners()
        if not corners:
            return np.zeros(0, np.int64), np.zeros((0, 3))
        ids = np.concatenate([4 * k + np.arange(4) for k in corners])
        return ids.astype(np.int64), np.concatenate(list(corners.values()))

    def checkerboard_corner_points(self) -> tuple[np.ndarray, np.ndarray]:
        """(ids (M,) int64, points (M, 3)) of the inner corners of the scene's checkerboards
        (:func:`rs_localizer.maps.scenes.checkerboard_corners`; empty without checkerboards)."""
        if self._checker_corners is None:
            return np.zeros(0, np.int64), np.zeros((0, 3))
        return self._checker_corners

    def viewpoint_pose(self) -> tuple[np.ndarray, float, float]:
        """(position (3,), yaw, pitch) of the scene's nominal camera viewpoint (rad)."""
        p = np.asarray(self.viewpoint["position"], dtype=float)
        d = np.asarray(self.viewpoint["look_at"], dtype=float) - p
        yaw = float(np.arctan2(d[1], d[0]))
        pitch = float(np.arctan2(d[2], np.hypot(d[0], d[1])))
        return p, yaw, pitch

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        pts = np.concatenate([q.corners() for q in self.quads])
        return pts.min(axis=0), pts.max(axis=0)


# ------------------------------------------------------------------------------- textures
def marker_texture(
    dictionary: str, marker_id: int, texels_per_cell: int = 16, margin_cells: int = 1
) -> np.ndarray:
    """(S, S, 3) uint8 marker image: black-bordered code plus a white quiet zone of
    ``margin_cells`` cells; every cell is exactly ``texels_per_cell`` texels."""
    d = marker_dictionary(dictionary)
    n = d.markerSize + 2
    if marker_id < 0 or marker_id >= len(d.bytesList):
        raise ValueError(
            f"marker id {marker_id} out of range for {dictionary} ({len(d.bytesList)} markers)"
        )
    img = marker_image(d, int(marker_id), n * texels_per_cell, border_bits=1)  # 4.6: drawMarker
    m = margin_cells * texels_per_cell
    img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
    return np.repeat(img[:, :, None], 3, axis=2)


def _as_rgb(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.dtype != np.uint8:
        img = np.clip(img * (255.0 if img.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.shape[2] == 4:
        img = img[:, :, :3]
    return np.ascontiguousarray(img)


def _noise_texture(shape, feature_px: float, seed: int) -> np.ndarray:
    """Procedural texture: band-limited noise at a few octaves (fallback for photographs)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    acc = np.zeros((h, w), np.float32)
    for octave in range(4):
        s = max(feature_px / 2**octave, 1.0)
        small = rng.normal(0, 1, (max(int(h / s), 2), max(int(w / s), 2))).astype(np.float32)
        acc += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) / (octave + 1)
    acc = (acc - acc.mean()) / (acc.std() + 1e-9)
    base = rng.uniform(90, 170, 3)
    tint = rng.uniform(25, 45, 3)
    return _as_rgb(np.clip(base + acc[:, :, None] * tint, 0, 255).astype(np.uint8))


_SKIMAGE_WARNED = set()


def _load_image(ref: str, base: Path | None, seed: int) -> np.ndarray:
    if ref.startswith("skimage:"):
        name = ref.split(":", 1)[1]
        try:
            import skimage.data

            return _as_rgb(getattr(skimage.data, name)())
        except (ImportError, AttributeError, OSError) as e:
            if name not in _SKIMAGE_WARNED:
                warnings.warn(
                    f"scikit-image photograph {name!r} unavailable ({e}); using a "
                    "procedural texture (pip install scikit-image)",
                    stacklevel=3,
                )
                _SKIMAGE_WARNED.add(name)
            return _noise_texture((512, 512), 24.0, seed)
    path = Path(ref)
    if not path.is_absolute() and base is not None:
        path = base / path
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"texture image {path} not found or unreadable")
    return _as_rgb(img[:, :, ::-1])


def _make_texture(spec: dict, size, base: Path | None, seed: int) -> np.ndarray:
    """Texture image for a quad/decal of ``size`` (w, h) metres from a YAML spec."""
    w, h = float(size[0]), float(size[1])
    tpm = float(spec.get("texels_per_metre", 200.0))
    shape = (max(int(round(h * tpm)), 1), max(int(round(w * tpm)), 1))
    if "array" in spec:  # programmatic scenes: an (H, W[, 3]) image covering the quad
        return _as_rgb(spec["array"])
    if "color" in spec:
        c = np.asarray(spec["color"], dtype=np.uint8).reshape(1, 1, 3)
        return np.ascontiguousarray(np.broadcast_to(c, (2, 2, 3)))
    if "checker" in spec:
        sq = float(spec["checker"])
        colors = np.asarray(spec.get("colors", [[20, 20, 20], [235, 235, 235]]), np.uint8)
        jj = (np.arange(shape[1]) + 0.5) / tpm // sq
        ii = (np.arange(shape[0]) + 0.5) / tpm // sq
        parity = ((ii[:, None] + jj[None, :]) % 2).astype(int)
        return np.ascontiguousarray(colors[parity])
    if "noise" in spec:
        return _noise_texture(shape, float(spec["noise"]) * tpm, seed)
    if "image" in spec:
        img = _load_image(str(spec["image"]), base, seed)
        tile = spec.get("tile")
        if tile is None:
            return img
        tw, th = float(tile[0]), float(tile[1])
        tile_px = (max(int(round(tw * tpm)), 1), max(int(round(th * tpm)), 1))
        t = cv2.resize(
            img,
            tile_px,
            interpolation=cv2.INTER_AREA if tile_px[0] < img.shape[1] else cv2.INTER_CUBIC,
        )
        reps = (int(np.ceil(shape[0] / t.shape[0])), int(np.ceil(shape[1] / t.shape[1])), 1)
        return np.ascontiguousarray(np.tile(t, reps)[: shape[0], : shape[1]])
    raise ValueError(f"unknown texture spec {spec!r}: expected color, checker, noise or image")


# ------------------------------------------------------------------------------- loading
def load_scene(name_or_path: str | Path | dict) -> Scene:
    """Load a scene by built-in name (:func:`rs_localizer.maps.scenes.scene_names`: e.g.
    ``aruco_room``, ``textured_room``, ``apriltag_room``), YAML path, or dict.

    Raises:
        FileNotFoundError: unknown name/path. ValueError: malformed scene (non-orthonormal quad
        axes, unknown quad names, duplicate marker ids, markers outside their quad...).
    """
    import yaml

    base = None
    source = None
    if isinstance(name_or_path, dict):
        data = name_or_path
    else:
        p = scene_path(name_or_path)
        data = yaml.safe_load(p.read_text())
        base = p.parent
        source = str(p)
    seed = 0
    quads = []
    for k, ((name, o, u, v, size), qd) in enumerate(
        zip(scene_quad_frames(data), data["quads"], strict=False)
    ):
        size = tuple(size)
        tex = _make_texture(qd.get("texture", {"color": [200, 200, 200]}), size, base, seed + k)
        quads.append(Quad(name, o, u, v, size, tex))
    scene = Scene(
        name=str(data.get("name", "scene")),
        quads=quads,
        dictionary=str(data.get("dictionary", "DICT_4X4_250")),
        viewpoint=data.get("viewpoint")
        or {"position": [0.0, 0.0, 1.5], "look_at": [1.0, 0.0, 1.5]},
        background=tuple(int(c) for c in data.get("background", (30, 30, 35))),
        source=source,
    )
    for k, dd in enumerate(data.get("decals", []) or []):
        qi = scene.quad_index(dd["quad"])
        a0, b0 = as_vector(dd["at"], 2, "at")
        w, h = as_vector(dd["size"], 2, "size")
        tex = _make_texture(dd["texture"], (w, h), base, 100 + k)
        scene.decals.append(Decal(qi, (a0, b0, a0 + w, b0 + h), tex))
    _add_markers(scene, data.get("markers") or {}, marker_layout(data))
    for qi, a, b, nu, nv, sq in checkerboard_layout(data):
        tex = _make_texture(
            {"checker": sq, "texels_per_metre": 64 / sq}, (nu * sq, nv * sq), base, 0
        )
        scene.decals.append(Decal(qi, (a, b, a + nu * sq, b + nv * sq), tex))
    scene._checker_corners = checkerboard_corners(data)
    return scene


def _add_markers(scene: Scene, spec: dict, layout: list):
    """Marker decals of ``layout`` (:func:`rs_localizer.maps.scenes.marker_layout`) with a white
    margin of ``spec['margin_cells']`` cells. Raises ValueError for a marker that does not fit."""
    margin_cells = int(spec.get("margin_cells", 1))
    tpc = int(spec.get("texels_per_cell", 16))
    cells = marker_dictionary(scene.dictionary).markerSize + 2
    placed = [Marker(mid, qi, a, b, size) for mid, qi, a, b, size in layout]
    textures = {}
    for m in placed:
        q = scene.quads[m.quad]
        mg = margin_cells * m.size / cells
        rect = (m.a - mg, m.b - mg, m.a + m.size + mg, m.b + m.size + mg)
        if (
            rect[0] < -1e-9
            or rect[1] < -1e-9
            or rect[2] > q.size[0] + 1e-9
            or rect[3] > q.size[1] + 1e-9
        ):
            raise ValueError(f"marker {m.id} (with its margin) does not fit on quad {q.name}")
        if m.id not in textures:
            textures[m.id] = marker_texture(scene.dictionary, m.id, tpc, margin_cells)
        scene.decals.append(Decal(m.quad, rect, textures[m.id], marker_id=m.id))
        scene.markers.append(m)
