"""Scene YAMLs (``rs_localizer/scenes/``): textured quads with markers and checkerboards placed
on them, the world the renderer draws and the ArUco front end reads as a marker map. Where a
scene's quads, markers and checkerboard corners are (world frame, metres); the renderer
(:mod:`rs_localizer.sim.render.scene`) draws them from these."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = [
    "SCENE_DIR",
    "as_vector",
    "checkerboard_corners",
    "checkerboard_layout",
    "marker_layout",
    "scene_marker_corners",
    "scene_names",
    "scene_path",
    "scene_quad_frames",
]

#: the built-in scenes (world descriptions shared by the renderer and the ArUco front end)
SCENE_DIR = Path(__file__).resolve().parents[1] / "scenes"


def scene_names() -> list:
    """Names of the built-in scenes."""
    return sorted(p.stem for p in SCENE_DIR.glob("*.yaml"))


def scene_path(name_or_path: str | Path) -> Path:
    """Path of a scene YAML: a built-in name (``aruco_room``) or a path.

    Raises FileNotFoundError when neither exists."""
    p = Path(str(name_or_path))
    if not p.suffix and (SCENE_DIR / f"{p}.yaml").exists():
        p = SCENE_DIR / f"{p}.yaml"
    if not p.exists():
        raise FileNotFoundError(
            f"map file {str(name_or_path)!r} not found (expected a marker map or scene YAML, "
            f"or a built-in scene: {', '.join(scene_names())})"
        )
    return p


def as_vector(x: object, n: int = 3, what: str = "vector") -> np.ndarray:
    """``x`` (a YAML list, a tuple, an array) as a float array of shape (n,).

    Raises:
        ValueError: ``x`` is not ``n`` finite numbers (the message names it ``what``).
    """
    a = np.asarray(x, dtype=float).ravel()
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ValueError(f"{what} must be {n} finite numbers, got {x!r}")
    return a


def scene_quad_frames(data: dict) -> list:
    """The quads of a scene (parsed YAML): ``[(name, origin (3,), u (3,), v (3,), size (2,))]``
    with unit, orthogonal ``u``, ``v`` (metres, world frame); a quad's point at quad
    coordinates (a, b) is ``origin + a u + b v``.

    Raises ValueError: no ``quads`` list, non-finite or non-orthogonal axes, size <= 0."""
    if not isinstance(data, dict) or "quads" not in data:
        raise ValueError("a scene needs a 'quads' list")
    out = []
    for k, qd in enumerate(data["quads"]):
        name = str(qd.get("name", f"quad{k}"))
        o = as_vector(qd["origin"], what="origin")
        u = as_vector(qd["u"], what="u")
        v = as_vector(qd["v"], what="v")
        u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
        if abs(u @ v) > 1e-9:
            raise ValueError(f"quad {name}: u and v must be orthogonal")
        size = as_vector(qd["size"], 2, "size")
        if min(size) <= 0:
            raise ValueError(f"quad {name}: size must be positive")
        out.append((name, o, u, v, size))
    return out


def marker_layout(data: dict) -> list:
    """Markers of a scene (parsed YAML, its ``markers.placements``: single markers ``{id, quad,
    at: [a, b], size}`` or grids ``{fill: {quad, size, pitch, border, first_id}}``).

    Returns ``[(marker id, quad index, a, b, size)]``: the marker's top-left corner at quad
    coordinates (a, b), side ``size`` (m). Raises ValueError for unknown quads or duplicate ids.
    """
    quads = scene_quad_frames(data)
    names = [q[0] for q in quads]

    def index(name):
        if name not in names:
            raise ValueError(f"scene has no quad {name!r}; quads: {names}")
        return names.index(name)

    placed = []
    for pl in (data.get("markers") or {}).get("placements", []) or []:
        if "fill" in pl:
            f = pl["fill"]
            qi = index(f["quad"])
            qsize = quads[qi][4]
            size, pitch = float(f["size"]), float(f.get("pitch", 2 * float(f["size"])))
            border = float(f.get("border", 0.1))
            nc = int(np.floor((qsize[0] - size - 2 * border) / pitch + 1e-9)) + 1
            nr = int(np.floor((qsize[1] - size - 2 * border) / pitch + 1e-9)) + 1
            a0 = 0.5 * (qsize[0] - (nc - 1) * pitch - size)
            b0 = 0.5 * (qsize[1] - (nr - 1) * pitch - size)
            mid = int(f.get("first_id", 0))
            for r in range(nr):
                for c in range(nc):
                    placed.append((mid, qi, a0 + c * pitch, b0 + r * pitch, size))
                    mid += 1
        else:
            qi = index(pl["quad"])
            a, b = as_vector(pl["at"], 2, "at")
            placed.append((int(pl["id"]), qi, float(a), float(b), float(pl["size"])))
    ids = [m[0] for m in placed]
    if len(set(ids)) != len(ids):
        raise ValueError("duplicate marker ids")
    return placed


def checkerboard_layout(data: dict) -> list:
    """Checkerboards of a scene (parsed YAML, its ``checkerboards`` list of ``{quad, at: [a, b],
    squares: [nu, nv], square}``: ``nu`` x ``nv`` squares of side ``square`` m whose top-left
    corner sits at quad coordinates (a, b); the top-left square is dark).

    Returns ``[(quad index, a, b, nu, nv, square)]``. Raises ValueError for unknown quads, fewer
    than 2 squares along a side, a non-positive square, or a board that does not fit its quad."""
    quads = scene_quad_frames(data)
    names = [q[0] for q in quads]
    out = []
    for cb in data.get("checkerboards") or []:
        if cb["quad"] not in names:
            raise ValueError(f"scene has no quad {cb['quad']!r}; quads: {names}")
        qi = names.index(cb["quad"])
        a, b = as_vector(cb["at"], 2, "at")
        nu, nv = (int(n) for n in cb["squares"])
        sq = float(cb["square"])
        if nu < 2 or nv < 2 or not sq > 0:
            raise ValueError(f"checkerboard needs >= 2 x 2 squares and square > 0, got {cb}")
        qsize = quads[qi][4]
        if a < -1e-9 or b < -1e-9 or a + nu * sq > qsize[0] + 1e-9 or b + nv * sq > qsize[1] + 1e-9:
            raise ValueError(f"checkerboard {cb} does not fit on quad {cb['quad']}")
        out.append((qi, float(a), float(b), nu, nv, sq))
    return out


def checkerboard_corners(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """Inner corners of the scene's checkerboards (parsed YAML, :func:`checkerboard_layout`):
    ``(ids (M,) int64, points (M, 3) world, metres)``. Board ``k`` with ``nu`` x ``nv`` squares
    has ``(nu - 1) (nv - 1)`` inner corners, row-major along u then v (OpenCV's
    ``findChessboardCorners`` order for ``patternSize = (nu - 1, nv - 1)`` when the top-left
    square is at the image's top left); corner (i, j) has id ``1000 k + j (nu - 1) + i``."""
    quads = scene_quad_frames(data)
    ids, pts = [], []
    for k, (qi, a, b, nu, nv, sq) in enumerate(checkerboard_layout(data)):
        _, o, u, v, _ = quads[qi]
        jj, ii = np.meshgrid(np.arange(nv - 1), np.arange(nu - 1), indexing="ij")
        A = a + (ii.ravel() + 1) * sq
        B = b + (jj.ravel() + 1) * sq
        pts.append(o + A[:, None] * u + B[:, None] * v)
        ids.append(1000 * k + jj.ravel() * (nu - 1) + ii.ravel())
    if not pts:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate(ids).astype(np.int64), np.concatenate(pts)


def scene_marker_corners(data: dict) -> dict:
    """Corners of a scene's markers (parsed YAML, :func:`marker_layout`): ``{marker id: (4, 3)
    world corners in ArUco order (TL, TR, BR, BL), metres}``, placed as the renderer places them.

    Raises:
        ValueError: as :func:`marker_layout`.
    """
    quads = scene_quad_frames(data)
    out = {}
    for mid, qi, a, b, s in marker_layout(data):
        _, o, u, v, _ = quads[qi]
        A = np.array([a, a + s, a + s, a])[:, None]
        B = np.array([b, b, b + s, b + s])[:, None]
        out[mid] = o + A * u + B * v
    return out
