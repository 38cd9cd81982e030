"""Map files: what the world looks like to a front end or the node, independent of how it was made.

* Landmark maps (``id,x,y,z`` CSV, metres) for the ``keypoints`` input.
* ArUco marker maps (YAML: dictionary + the four 3D corners of each marker) for the ArUco front
  end, or scene YAMLs (``rs_localizer/scenes/``: textured quads with markers placed on them, the
  world the renderer draws) whose marker corners :func:`load_marker_map` computes the same way
  the renderer places them (:func:`marker_layout`).
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

import numpy as np

__all__ = [
    "MARKER_SQUARE_TOLERANCE",
    "SCENE_DIR",
    "check_marker_corners",
    "check_regular_file",
    "checkerboard_corners",
    "checkerboard_layout",
    "file_mode",
    "load_landmarks_csv",
    "load_marker_map",
    "marker_dictionary",
    "marker_layout",
    "open_regular_file",
    "save_landmarks_csv",
    "scene_names",
    "scene_path",
    "scene_quad_frames",
    "write_marker_map",
    "write_text_atomic",
]

#: the built-in scenes (world descriptions shared by the renderer and the ArUco front end)
SCENE_DIR = Path(__file__).resolve().parent / "scenes"


def save_landmarks_csv(path: str | os.PathLike, ids: np.ndarray, points: np.ndarray) -> Path:
    """Write a landmark map ``id,x,y,z`` (header line, metres), atomically
    (:func:`write_text_atomic`). Returns the path."""
    rows = [
        f"{int(i)},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in zip(ids, points, strict=False)
    ]
    return write_text_atomic(path, "id,x,y,z\n" + "".join(rows), overwrite=True)


def write_text_atomic(path: str | os.PathLike, text: str, overwrite: bool = False) -> Path:
    """Write ``text`` to ``path`` whole or not at all: a temporary file in the same directory,
    then an atomic rename (``os.replace``); on any error (Ctrl-C included) the temporary file
    is removed and ``path`` is untouched. The file gets the user's umask mode
    (:func:`file_mode`), as a plain ``open`` would. The parent directory is created.

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False.
        OSError: the directory cannot be written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (use --overwrite to replace it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, file_mode())  # (mkstemp's 0600 -> the umask's: readable by others)
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def file_mode() -> int:
    """The mode a new file gets from the user's umask (``0o666 & ~umask``): maps written
    through a temporary file (``mkstemp``: 0600) are given it, so that a node running as
    another user can read them."""
    try:  # (Linux: read it without changing it)
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


#: relative tolerance on a marker's sides and diagonals (:func:`check_marker_corners`)
MARKER_SQUARE_TOLERANCE = 0.05


def check_marker_corners(corners: np.ndarray, size: float | None = None, what: str = "") -> None:
    """Check that ``corners`` (4, 3) (metres, ArUco order) form a square: finite, the four sides
    and the two diagonals (``sqrt(2)`` sides) equal within :data:`MARKER_SQUARE_TOLERANCE`,
    coplanar within that tolerance of the side, a side > 1 mm, and, if ``size`` is given, a
    side of that length within the tolerance.

    Raises:
        ValueError: naming ``what`` and the first violation.
    """
    c = np.asarray(corners, dtype=float)
    if c.shape != (4, 3) or not np.isfinite(c).all():
        raise ValueError(f"{what}needs 4 finite 3D corners")
    sides = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)
    diag = np.array([np.linalg.norm(c[2] - c[0]), np.linalg.norm(c[3] - c[1])])
    side = float(np.mean(sides))
    tol = MARKER_SQUARE_TOLERANCE
    if not side > 1e-3:
        raise ValueError(f"{what}degenerate corners (side {side:.3g} m)")
    if np.abs(sides - side).max() > tol * side or np.abs(diag - np.sqrt(2) * side).max() > (
        tol * side
    ):
        raise ValueError(
            f"{what}corners are not a square (sides {np.round(sides, 4).tolist()} m, "
            f"diagonals {np.round(diag, 4).tolist()} m)"
        )
    n = np.cross(c[1] - c[0], c[3] - c[0])
    n = n / np.linalg.norm(n)
    if abs(float((c[2] - c[0]) @ n)) > tol * side:
        raise ValueError(f"{what}corners are not coplanar")
    if size is not None and abs(side - float(size)) > tol * float(size):
        raise ValueError(f"{what}side {side:.4f} m, the map states {float(size):.4f} m")


def check_regular_file(path) -> None:
    """Raise ValueError unless ``path`` is a regular file (``os.stat``, which does not block on
    a FIFO or a device the way ``open`` does); OSError (FileNotFoundError...) if it cannot be
    stat'ed."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{path}: not a regular file")


def open_regular_file(path, mode: str = "r"):
    """``open(path, mode)`` (read-only modes) that never blocks on a FIFO or a device: the file
    is opened non-blocking and checked to be a regular file (``fstat``, so it cannot be swapped
    between check and open). Raises ValueError for anything else, OSError as ``open``."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ValueError(f"{path}: not a regular file")
        os.set_blocking(fd, True)
        return os.fdopen(fd, mode)
    except BaseException:
        os.close(fd)
        raise


def load_landmarks_csv(path):
    """Read ``id,x,y,z`` (header optional, ``#`` comments allowed). Returns (ids (M,) int64,
    points (M, 3)). Raises ValueError for malformed rows, no rows, duplicate ids, non-finite
    coordinates or a path that is not a regular file (a FIFO would block the reader), OSError if
    it cannot be opened."""
    ids, pts = [], []
    with open_regular_file(path) as f:
        for lineno, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = [s.strip() for s in line.split(",")]
            if lineno == 1 and parts[0].lower() == "id":
                continue
            if len(parts) != 4:
                raise ValueError(f"{path}:{lineno}: expected 'id,x,y,z', got {line!r}")
            try:
                ids.append(int(parts[0]))
                pts.append([float(s) for s in parts[1:]])
            except ValueError as e:
                raise ValueError(f"{path}:{lineno}: {e}") from None
    if not ids:
        raise ValueError(f"{path}: no landmarks")
    ids = np.asarray(ids, dtype=np.int64)
    if len(np.unique(ids)) != len(ids):
        raise ValueError(f"{path}: duplicate landmark ids")
    pts = np.asarray(pts, dtype=float).reshape(-1, 3)
    if not np.isfinite(pts).all():
        raise ValueError(f"{path}: non-finite coordinates")
    return ids, pts


def marker_dictionary(name: str):
    """cv2.aruco predefined dictionary by name (e.g. ``DICT_4X4_250``).

    Raises ValueError for a name OpenCV does not know."""
    import cv2

    if not hasattr(cv2.aruco, name):
        raise ValueError(f"unknown ArUco dictionary {name!r}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def write_marker_map(path, dictionary: str, corners: dict, scene: str | None = None) -> Path:
    """Write a marker map: ``dictionary`` name and ``corners`` {marker id: (4, 3) world corners
    in ArUco order (TL, TR, BR, BL), metres} as YAML, atomically (:func:`write_text_atomic`).
    Returns the path."""
    import yaml

    data = {
        "dictionary": dictionary,
        **({"scene": scene} if scene is not None else {}),
        "markers": [
            {"id": int(k), "corners": np.round(c, 6).tolist()} for k, c in sorted(corners.items())
        ],
    }
    return write_text_atomic(
        path,
        "# ArUco marker map: corners in ArUco order (TL, TR, BR, BL), metres\n"
        + yaml.safe_dump(data, default_flow_style=None, sort_keys=False),
        overwrite=True,
    )


def scene_names() -> list:
    """Names of the built-in scenes."""
    return sorted(p.stem for p in SCENE_DIR.glob("*.yaml"))


def scene_path(name_or_path) -> Path:
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


def checkerboard_corners(data: dict):
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


def _scene_marker_corners(data: dict) -> dict:
    quads = scene_quad_frames(data)
    out = {}
    for mid, qi, a, b, s in marker_layout(data):
        _, o, u, v, _ = quads[qi]
        A = np.array([a, a + s, a + s, a])[:, None]
        B = np.array([b, b, b + s, b + s])[:, None]
        out[mid] = o + A * u + B * v
    return out


def load_marker_map(path):
    """Read a marker map (:func:`write_marker_map`), or a scene YAML / built-in scene name
    (``aruco_room``: the corners of its markers). Returns ``(dictionary name, {id: (4, 3)
    corners in ArUco order, metres})``.

    Raises:
        FileNotFoundError: no such file or built-in scene. ValueError: neither a marker map nor
        a scene, no markers, a marker without an integer id >= 0 or 4 finite 3D corners, an id
        given twice, corners that are not a square (:func:`check_marker_corners`; of the
        marker's ``size`` or the map's ``marker_size`` in metres when given). Other keys
        (per-marker uncertainty, observations, the anchor) are read by their own users and
        ignored here.
    """
    import yaml

    p = scene_path(path)
    data = yaml.safe_load(p.read_text())
    if isinstance(data, dict) and "quads" in data:
        return str(data.get("dictionary", "DICT_4X4_250")), _scene_marker_corners(data)
    if not isinstance(data, dict) or "markers" not in data:
        raise ValueError(f"{p}: neither a marker map nor a scene")
    markers = data["markers"]
    if not isinstance(markers, list) or not markers:
        raise ValueError(f"{p}: the map has no markers")
    dictionary = data.get("dictionary", "DICT_4X4_250")
    if not isinstance(dictionary, str):
        raise ValueError(f"{p}: 'dictionary' must be a name, got {dictionary!r}")
    size = data.get("marker_size")
    corners = {}
    for k, m in enumerate(markers):
        if not isinstance(m, dict) or "id" not in m or "corners" not in m:
            raise ValueError(f"{p}: marker #{k} needs 'id' and 'corners'")
        mid = m["id"]
        if isinstance(mid, bool) or not isinstance(mid, int) or mid < 0:
            raise ValueError(f"{p}: marker #{k}: id must be an integer >= 0, got {mid!r}")
        if mid in corners:
            raise ValueError(f"{p}: marker id {mid} appears twice")
        try:
            c = np.asarray(m["corners"], dtype=float)
            msize = m.get("size", size)
            msize = None if msize is None else float(msize)
        except (TypeError, ValueError):
            raise ValueError(f"{p}: marker {mid}: corners and size must be numbers") from None
        check_marker_corners(c, msize, f"{p}: marker {mid}: ")
        corners[mid] = c
    return dictionary, corners
