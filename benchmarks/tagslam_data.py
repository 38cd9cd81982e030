"""TagSLAM's recordings as the benchmarks read them (``../shared/data/real_markers/tagslam``,
next to the checkout; not shipped with rs_localizer): where they are (:data:`DATA`), a
test folder as a rig of cameras with its tag map, detections and TagSLAM's reference poses
(:func:`load_tagslam`, :class:`RealRig`), its reference extrinsics (:func:`extrinsics`), and
the helpers both :mod:`benchmarks.bench_single_tag` and :mod:`benchmarks.bench_real_rig` use
(:func:`tag_corners`, :func:`quat_matrix`, :func:`errors` against the reference).

A test folder holds ``cameras.yaml``, ``tagslam.yaml`` and either ``json/`` (the bags
converted as ``../shared/data/real_markers/README.md`` describes) or the ROS 1 bags
``tag_detections.bag`` and ``reference.bag`` (or their ``.bz2``), read with ``rosbags``.
"""

from __future__ import annotations

import bz2
import json
import shutil
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from rs_localizer.camera import CameraModel
from rs_localizer.estimation.view import View
from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotation_angle_deg

__all__ = [
    "DATA",
    "FOLDER",
    "REFERENCE_TOPIC",
    "TAG_SIDE",
    "RealRig",
    "errors",
    "extrinsics",
    "load_tagslam",
    "load_test2",
    "quat_matrix",
    "read_records",
    "tag_corners",
]

_ROOT = Path(__file__).resolve().parents[1]
#: the TagSLAM recordings (outside the repository, next to the checkout or one level up;
#: absent: the benchmarks' real parts are skipped)
DATA = next(
    (
        p
        for p in (
            _ROOT / up / "shared" / "data" / "real_markers" / "tagslam" for up in ("..", "../..")
        )
        if p.is_dir()
    ),
    _ROOT / ".." / "shared" / "data" / "real_markers" / "tagslam",
)

#: the default recording of ``bench_real_rig`` (absent: it says so and stops; the tests skip)
FOLDER = DATA / "test_2"
#: test_2's tags' side (m): its ``tagslam.yaml``'s ``default_tag_size``
TAG_SIDE = 0.160
#: the odometry topic of the rig's reference poses in ``reference.bag``
REFERENCE_TOPIC = "/tagslam/odom/body_rig"


def tag_corners(side: float) -> np.ndarray:
    """(4, 3) corners (m) of a square marker of ``side`` in its own frame, z = 0, in the
    AprilTag detections' order (TagSLAM's convention)."""
    s = side / 2
    return np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])


def quat_matrix(q) -> np.ndarray:
    """(3, 3) rotation matrix of the unit quaternion ``q`` = ``(x, y, z, w)``."""
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


class RealRig:
    """A TagSLAM test folder loaded (:func:`load_tagslam`).

    Attributes:
        cameras: name -> :class:`~rs_localizer.camera.CameraModel` (``cameras.yaml``'s order;
            global shutter).
        mounts: name -> ``(R (3, 3), c (3,) m)``: the reference's extrinsics as the rig
            estimator's mounting ``x_cam = R x_rig + c``; mountings: the same as
            :class:`~rs_localizer.frames.Mounting` s (built once: a benchmark's timed rig
            frames take them as they are).
        frames: ``(stamp s, {name: (uv (N, 2) px, X (N, 3) m)})`` per rig frame with tags, in
            time order; a camera without tags in that rig frame is absent.
        reference: stamp -> ``(R (3, 3) world -> rig, C (3,))``: TagSLAM's rig pose
            (``x_rig = R X + C``).
        name: the folder's name. stamps_shared: ``(stamps carrying a message of every camera,
            stamps, messages alone at their stamp with another camera's within half a frame
            interval)`` over every detection message. tolerance: s; 0 when a rig frame is one
            stamp, else the tolerance the stamps were grouped with.
        messages: ``(stamp s, camera name, rig frame stamp s)`` of every detection message of
            the cameras (with tags or none), in stamp order: a camera's video.
        tags: tag id -> ``(R (3, 3), p (3,) m, side m)``: the reference's tag pose
            ``x_map = R x_tag + p`` and its side (its corners: ``tag_corners(side) @ R.T + p``).
        tag_ids: stamp -> ``{name: (N // 4,) tag ids}``: the tag of each block of 4 rows of
            that rig frame's view in :attr:`frames`.
        anchors: the ids of the tags ``tagslam.yaml`` gives a pose (TagSLAM's gauge).
    """

    def __init__(self, cameras, mounts, frames, reference, name="", stamps_shared=(0, 0, 0),
                 tolerance=0.0, messages=(), tags=None, tag_ids=None, anchors=()):  # fmt: skip
        self.cameras, self.mounts, self.frames, self.reference = cameras, mounts, frames, reference
        self.mountings = {n: Mounting(*m) for n, m in mounts.items()}
        self.name, self.stamps_shared, self.tolerance = name, stamps_shared, tolerance
        self.messages = list(messages)
        self.tags, self.tag_ids = tags or {}, tag_ids or {}
        self.anchors = frozenset(anchors)

    def views(self, stamp: float, views: dict, mountings: dict | None = None) -> list:
        """The rig frame ``views`` (``{name: (uv, X)}``, :attr:`frames`' item at ``stamp``) as
        the rig estimator's :class:`~rs_localizer.estimation.view.View` s: each camera at its
        mounting (``mountings``: name -> :class:`~rs_localizer.frames.Mounting`, default
        :attr:`mountings`), its corners grouped by tag (:attr:`tag_ids`; none where the
        frame's tags are not known)."""
        mountings = self.mountings if mountings is None else mountings
        return [
            View(uv, X, self.cameras[n], mountings[n], name=n, groups=self.groups(stamp, n))
            for n, (uv, X) in views.items()
        ]

    def groups(self, stamp: float, name: str) -> np.ndarray | None:
        """Camera ``name``'s corners in the rig frame at ``stamp`` (:attr:`frames`) grouped
        by tag: (N,) int64, each corner's tag id (:attr:`tag_ids`), as a marker front end's
        :attr:`~rs_localizer.correspondences.Correspondences.groups`; None where the frame's
        tags are not known."""
        ids = self.tag_ids.get(stamp, {})
        return np.repeat(np.asarray(ids[name], np.int64), 4) if name in ids else None


def _pose(t: dict) -> tuple[np.ndarray, np.ndarray]:
    return quat_matrix(t["quat_xyzw"]), np.asarray(t["translation"], dtype=float)


def _stamp(header) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _bag(folder: Path, name: str, tmp: Path) -> Path:
    """``folder/name``, or ``folder/name.bz2`` decompressed into ``tmp``."""
    if (folder / name).is_file():
        return folder / name
    src = folder / f"{name}.bz2"
    if not src.is_file():
        raise FileNotFoundError(f"{folder}: neither json/ nor {name}[.bz2]")
    out = tmp / name
    with bz2.open(src, "rb") as f, out.open("wb") as g:
        shutil.copyfileobj(f, g)
    return out


def read_records(folder: Path) -> tuple[list, list, list]:
    """The recording's detection messages, reference odometry and last transforms, as the
    ``json/`` layout's records (``../shared/data/real_markers/README.md``): from ``json/``
    when present, else from the ROS 1 bags (``rosbags``; a ``.bz2`` decompressed into a
    temporary file).

    Returns:
        ``(detections, odometry, transforms)``: lists of dicts with ``topic``, ``stamp`` (s),
        ``tags`` (each ``id``, ``corners`` 4 x [x, y] px); ``stamp``, ``position``,
        ``quat_xyzw`` (the rig in ``map``); ``parent``, ``child``, ``translation``,
        ``quat_xyzw`` (the last transform of each pair).
    Raises:
        FileNotFoundError: neither ``json/`` nor the bags.
    """
    js = folder / "json"
    if js.is_dir():
        det = [json.loads(s) for s in (js / "detections.jsonl").read_text().splitlines()]
        odo = [json.loads(s) for s in (js / "reference_odom.jsonl").read_text().splitlines()]
        tf = json.loads((js / "reference_final_tf.json").read_text())
        return det, odo, tf
    from rosbags.highlevel import AnyReader

    det, odo, last = [], [], {}
    with tempfile.TemporaryDirectory(prefix="bench_real_rig_") as tmp:
        with AnyReader([_bag(folder, "tag_detections.bag", Path(tmp))]) as r:
            for c, _, raw in r.messages():
                m = r.deserialize(raw, c.msgtype)
                if not hasattr(m, "apriltags"):
                    continue
                tags = [{"id": int(a.id), "corners": [[float(p.x), float(p.y)] for p in a.corners]}
                        for a in m.apriltags]  # fmt: skip
                det.append({"topic": c.topic, "stamp": _stamp(m.header), "tags": tags})
        with AnyReader([_bag(folder, "reference.bag", Path(tmp))]) as r:
            for c, _, raw in r.messages():
                m = r.deserialize(raw, c.msgtype)
                if c.msgtype == "nav_msgs/msg/Odometry":
                    p, q = m.pose.pose.position, m.pose.pose.orientation
                    odo.append({"topic": c.topic, "stamp": _stamp(m.header),
                                "position": [p.x, p.y, p.z],
                                "quat_xyzw": [q.x, q.y, q.z, q.w]})  # fmt: skip
                elif c.msgtype.lower().endswith("tfmessage"):
                    for tr in m.transforms:
                        t, q = tr.transform.translation, tr.transform.rotation
                        last[(tr.header.frame_id, tr.child_frame_id)] = {
                            "parent": tr.header.frame_id, "child": tr.child_frame_id,
                            "translation": [t.x, t.y, t.z], "quat_xyzw": [q.x, q.y, q.z, q.w],
                        }  # fmt: skip
    return det, odo, list(last.values())


def _cameras(folder: Path) -> tuple[dict, dict]:
    """``cameras.yaml`` -> (name -> CameraModel, detection topic -> name)."""
    import yaml

    cams, topics = {}, {}
    for name, c in yaml.safe_load((folder / "cameras.yaml").read_text()).items():
        fx, fy, cx, cy = c["intrinsics"]
        model = c.get("distortion_model", "none")
        cams[name] = CameraModel(
            K=np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]),
            D=list(c.get("distortion_coeffs", [])),
            width=int(c["resolution"][0]),
            height=int(c["resolution"][1]),
            distortion_model={"radtan": "plumb_bob"}.get(model, model),
        )
        topics[c["tagtopic"]] = name
    return cams, topics


def _tag_sizes(folder: Path) -> tuple[dict, dict, set]:
    """``tagslam.yaml`` -> (tag id -> its own size, body -> its tags' default size (m), the
    ids of the tags given a pose)."""
    import yaml

    cfg = yaml.safe_load((folder / "tagslam.yaml").read_text())
    own, default, anchors = {}, {}, set()
    for entry in cfg.get("bodies", []):
        for body, b in entry.items():
            size = b.get("default_tag_size", (b.get("board") or {}).get("tag_size"))
            if size is not None:
                default[body] = float(size)
            for t in b.get("tags") or []:
                if "size" in t:
                    own[int(t["id"])] = float(t["size"])
                if "pose" in t:
                    anchors.add(int(t["id"]))
    return own, default, anchors


def _in_map(tf: list) -> dict:
    """frame -> (R, p) of ``x_map = R x_frame + p``, composing the transforms' chain to
    ``map`` (a chain's root other than ``map`` is taken as the map)."""
    parent = {t["child"]: (t["parent"], *_pose(t)) for t in tf}
    out: dict = {}

    def pose(frame, depth=0):
        if frame in out:
            return out[frame]
        if frame not in parent or depth > 50:
            return np.eye(3), np.zeros(3)
        up, R, p = parent[frame]
        Ru, pu = pose(up, depth + 1)
        out[frame] = (Ru @ R, Ru @ p + pu) if up in parent else (R, p)
        return out[frame]

    for f in parent:
        pose(f)
    return {f: v for f, v in out.items()}


def load_tagslam(folder: Path = FOLDER, tolerance: float | None = None) -> RealRig:
    """A TagSLAM test folder as a :class:`RealRig`: the cameras (``cameras.yaml``), the
    reference's extrinsics, tag map (``tagslam.yaml``'s sizes) and rig poses, and every rig
    frame's detections of tags in the map.

    ``tolerance``: s; None groups the detections by stamp when the cameras are stamped
    together (no more than 5 % of the messages lack another camera's message at their stamp
    but have one within half a frame interval, the median interval between a camera's
    messages; a camera's dropped frame is no such miss), else within half a frame interval;
    a number groups them within it (0: by stamp).

    Raises:
        FileNotFoundError: a file missing. KeyError: a tag of the map without a size.
    """
    cameras, topics = _cameras(folder)
    det, odo, tf = read_records(folder)
    own, default, anchors = _tag_sizes(folder)
    in_map = _in_map(tf)
    tags, mounts, poses = {}, {}, {}
    for t in tf:
        c = t["child"]
        if c.startswith("tag_") and c[4:].isdigit():
            i = int(c[4:])
            side = own.get(i, default.get(t["parent"]))
            if side is None:
                raise KeyError(f"{folder}: tag {i} (on {t['parent']}) has no size")
            R, p = in_map[c]  # tag -> map
            tags[i] = tag_corners(side) @ R.T + p
            poses[i] = (R, p, side)
        elif t["parent"] == "rig" and c in cameras:
            R, p = _pose(t)  # camera -> rig
            mounts[c] = (R.T, -R.T @ p)
    reference = {}
    topics_odo = {m.get("topic") for m in odo}
    for m in odo:
        if len(topics_odo) > 1 and m.get("topic") != REFERENCE_TOPIC:
            continue
        R = quat_matrix(m["quat_xyzw"]).T  # (rig -> map, transposed)
        reference[round(m["stamp"], 6)] = (R, -R @ np.asarray(m["position"], dtype=float))
    msgs = [m for m in det if m["topic"] in topics]
    per_stamp: dict = defaultdict(set)
    own_stamps: dict = defaultdict(list)
    for m in msgs:
        per_stamp[round(m["stamp"], 6)].add(m["topic"])
        own_stamps[m["topic"]].append(round(m["stamp"], 6))
    shared = (sum(len(v) == len(topics) for v in per_stamp.values()), len(per_stamp))
    # a message without another camera's at its stamp but with one within half a frame
    # interval: the cameras are not stamped together (a camera's dropped frame is no miss)
    interval = float(np.median([np.median(np.diff(sorted(set(v)))) for v in own_stamps.values()
                                if len(set(v)) > 1] or [0.0]))  # fmt: skip
    near = 0
    for tp, ss in own_stamps.items():
        others = np.array(sorted({x for t2, v in own_stamps.items() if t2 != tp for x in v}))
        for x in ss:
            if len(per_stamp[x]) == 1 and len(others):
                near += bool(np.min(np.abs(others - x)) < 0.5 * interval)
    if tolerance is None:
        tolerance = 0.5 * interval if near > 0.05 * len(msgs) else 0.0
    groups: dict = {}  # message stamp -> rig frame stamp
    start = None
    for s in sorted(per_stamp):
        if start is None or s - start > tolerance:
            start = s
        groups[s] = start
    if tolerance > 0:  # (a rig frame's stamp: its member with a reference pose, if any)
        members: dict = defaultdict(list)
        for s, g in groups.items():
            members[g].append(s)
        for g, ss in members.items():
            with_ref = [s for s in ss if s in reference]
            for s in ss:
                groups[s] = with_ref[0] if with_ref else g
    by_stamp: dict = defaultdict(dict)
    ids: dict = defaultdict(dict)
    for m in msgs:
        known = [t for t in m["tags"] if t["id"] in tags]
        if not known:
            continue
        uv = np.concatenate([np.asarray(t["corners"], dtype=float) for t in known])
        X = np.concatenate([tags[t["id"]] for t in known])
        g = groups[round(m["stamp"], 6)]
        by_stamp[g][topics[m["topic"]]] = (uv, X)
        ids[g][topics[m["topic"]]] = np.array([t["id"] for t in known])
    frames = sorted(by_stamp.items())
    messages = sorted((round(m["stamp"], 6), topics[m["topic"]], groups[round(m["stamp"], 6)])
                      for m in msgs)  # fmt: skip
    return RealRig(cameras, mounts, frames, reference, folder.name, (*shared, near), tolerance,
                   messages, poses, dict(ids), anchors)  # fmt: skip


def load_test2(folder: Path = FOLDER) -> RealRig:
    """TagSLAM's ``test_2`` (or ``folder``) as a :class:`RealRig` (:func:`load_tagslam`)."""
    return load_tagslam(folder)


def errors(R, C, ref) -> tuple[float, float]:
    """Rotation (deg) and position (mm) error of ``x = R X + C`` against ``ref`` ``(R, C)``."""
    Rr, Cr = ref
    return rotation_angle_deg(R, Rr), 1e3 * float(np.linalg.norm(R.T @ C - Rr.T @ Cr))


def extrinsics(folder: Path) -> dict:
    """Another recording's reference extrinsics of the same rig (its
    ``reference_final_tf.json`` or ``reference.bag``): camera -> ``(R, c)`` as
    :attr:`RealRig.mounts`."""
    out = {}
    for t in read_records(folder)[2]:
        if t["parent"] == "rig":
            R, p = _pose(t)
            out[t["child"]] = (R.T, -R.T @ p)
    return out
