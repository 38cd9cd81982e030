"""Frames of a bag as 2D-3D correspondences (offline, rosbags; no middleware), and its gyro:
a camera's, or every camera's of a rig bag.

:func:`read_bag_frames` turns every frame of a bag into ``(stamp_ns, points2d, points3d,
scores)``: from a correspondence cloud, from keypoints with the bag's landmark map, or from
images through an image front end (ArUco or feature map). :func:`read_gyro` reads the angular
velocity of ``sensor_msgs/Imu`` messages. Used by ``rs-localizer calibrate-readout``.

A rig bag's cameras (:func:`is_rig_bag`: ``make-bag --rig``, ``render-bag --rig``, or a
recording with the rig node's parameters, :func:`rig_parameter_values`) are read as the rig
node reads them: :func:`iter_rig_frames` (each camera's messages through its
:class:`~rs_localizer.ros.camera_input.CameraInput`, what ``replay`` runs) and
:func:`read_rig_frames` (all of them, without mountings: ``calibrate-rig``, ``play
--lockstep``).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...camera import CameraModel
from .. import conversions as cv
from ..config import LocalizerConfig, build_config, load_maps, rig_camera_names
from ..param_files import checked_value, read_params_file
from ..params import (
    PARAMETERS,
    RIG_CAMERA_PARAMETERS,
    RIG_PARAMETERS,
    ConfigError,
    default_values,
)
from .bag_io import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    IMAGE,
    IMU,
    RigTopics,
    bag_topics,
    iter_messages,
    read_bag_info,
    rig_namespace,
    typestore,
)

if TYPE_CHECKING:
    import os

    from ...tracking.localizer import CameraFrame
    from ...tracking.video import LocalizerSettings
    from ..camera_input import CameraInput, DroppedFrame, ImageFrame

__all__ = [
    "READ_COUNTS",
    "SOURCES",
    "BagFrames",
    "QuietLog",
    "RigFrames",
    "camera_messages",
    "frame_topic",
    "is_rig_bag",
    "iter_rig_frames",
    "read_bag_frames",
    "read_gyro",
    "read_rig_frames",
    "rig_bag_config",
    "rig_frontends",
    "rig_kinds",
    "rig_landmarks",
    "rig_parameter_values",
]

#: where the correspondences of a frame come from
SOURCES = ("correspondences", "keypoints", "image")


@dataclass
class BagFrames:
    """Frames of a bag. ``camera``: from the first ``camera_info`` (line delay 0, the bag's
    readout direction, reference line at the image centre); ``frames``: list of ``(stamp_ns,
    points2d (N, 2), points3d (N, 3), scores (N,) or None)``; ``skipped``: reason ->
    count of frames without usable correspondences; ``stamp_row``: the line whose capture time
    the stamps are (from ``sequence.json``, default 0)."""

    camera: CameraModel | None = None
    frames: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    stamp_row: float = 0.0
    direction: str = "top_to_bottom"


def frame_topic(topics: Mapping[str, str], source: str, compressed: bool = False,
                prefer: Iterable[str | None] = ()) -> str | None:  # fmt: skip
    """The topic of a bag's frames for ``source`` (``topics``: topic -> msgtype): of
    ``correspondences`` or ``keypoints`` the first ``*/<source>`` topic; of ``image`` the
    first of ``prefer`` that is an image topic (``sensor_msgs/CompressedImage`` with
    ``compressed``, else ``sensor_msgs/Image``), else the first image topic; None: none."""
    if source != "image":
        return next((t for t in topics if t.rstrip("/").endswith("/" + source)), None)
    images = [t for t, mt in topics.items() if mt == (COMPRESSED_IMAGE if compressed else IMAGE)]
    return next((t for t in prefer if t in images), images[0] if images else None)


def read_bag_frames(
    path: str | Path,
    source: str = "correspondences",
    landmarks_file: str | Path | None = None,
    frontend: str | None = None,
    frontend_map: str | Path | None = None,
    direction: str | None = None,
) -> BagFrames:
    """Read every frame of a bag as correspondences.

    Args:
        path: bag directory.
        source: ``correspondences`` (``*/correspondences`` clouds), ``keypoints``
            (``*/keypoints`` clouds + the landmark CSV ``landmarks_file``, default the bag's
            ``landmarks.csv``) or ``image`` (``sensor_msgs/Image`` + a front end: ``frontend``
            and ``frontend_map``, default the ``frontend`` entry of ``sequence.json``, whose
            map path is relative to the bag).
        direction: readout direction (default: the bag's ``sequence.json``, else top to
            bottom).
    Returns:
        :class:`BagFrames`.
    Raises:
        ValueError: unknown source, no such topic in the bag, no camera_info, no front end.
        FileNotFoundError: missing bag, landmark file or front-end map.
    """
    from ...maps import load_landmarks_csv
    from ..pointcloud import read_correspondences, read_keypoints

    if source not in SOURCES:
        raise ValueError(f"unknown source {source!r}; expected one of {SOURCES}")
    path = Path(path)
    if not (path / "metadata.yaml").exists():
        raise FileNotFoundError(f"{path}: not a bag directory (no metadata.yaml)")
    info = read_bag_info(path)
    rs = info.get("rs", {})
    direction = direction or rs.get("direction", "top_to_bottom")
    out = BagFrames(stamp_row=float(rs.get("stamp_row", 0.0)), direction=direction)
    topics = bag_topics(path)
    frames = frame_topic(topics, source)
    info_topic = next((t for t, mt in topics.items() if mt == CAMERA_INFO), None)
    if frames is None:
        raise ValueError(f"{path}: no {source} topic (topics: {sorted(topics)})")
    lm_index = None
    fe = None
    if source == "keypoints":
        ids, pts = load_landmarks_csv(
            Path(landmarks_file) if landmarks_file else path / "landmarks.csv"
        )
        order = np.argsort(ids)
        lm_index = (ids[order], pts[order])
    elif source == "image":
        from ...frontends import make_frontend
        from ..image_codec import decode_image

        spec = info.get("frontend", {})
        kind = frontend or spec.get("kind")
        fmap = frontend_map or (path / spec["map"] if "map" in spec else None)
        if kind is None:
            raise ValueError(
                f"{path}: no front end given and none in sequence.json "
                "(use --frontend and --frontend-map)"
            )
        if fmap is None:
            hint = (
                "; without a marker map, `rs-localizer map-markers BAG -o map.yaml "
                "--marker-size M --calibrate-readout` builds one and estimates the readout "
                "time from the same video"
                if kind == "aruco"
                else ""
            )
            raise ValueError(
                f"{path}: the {kind} front end needs its map: --frontend-map MAP "
                f"(sequence.json names none){hint}"
            )
        fe = make_frontend(kind, fmap)
    ts = typestore()
    for topic, msgtype, _, raw in iter_messages(path, {frames, info_topic}):
        msg = ts.deserialize_cdr(raw, msgtype)
        if topic == info_topic:
            if out.camera is None:
                out.camera = cv.camera_model_from_camera_info(msg, 0.0, 0.0, direction, None)
            continue
        stamp = cv.stamp_to_ns(msg.header.stamp)
        try:
            if source == "keypoints":
                kp = read_keypoints(msg)
                j = np.clip(np.searchsorted(lm_index[0], kp.ids), 0, len(lm_index[0]) - 1)
                known = lm_index[0][j] == kp.ids
                uv, xyz = kp.uv[known], lm_index[1][j[known]]
                scores = None if kp.scores is None else kp.scores[known]
            elif source == "image":
                img, enc = decode_image(msg)
                uv, xyz, _ = fe.process(img, out.camera, encoding=enc)
                scores = None
            else:
                c = read_correspondences(msg)
                uv, xyz, scores = c.points2d, c.points, c.scores
        except ValueError as e:
            reason = getattr(e, "reason", "bad_frame")
            out.skipped[reason] = out.skipped.get(reason, 0) + 1
            continue
        out.frames.append((stamp, uv, xyz, scores))
    if out.camera is None:
        raise ValueError(f"{path}: no camera_info message")
    out.frames.sort(key=lambda f: f[0])
    return out


def read_gyro(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Angular velocities of the ``sensor_msgs/Imu`` messages on ``topic``: ``(t_ns (M,),
    omega (M, 3) rad/s)`` in the IMU frame, by header stamp.

    Raises:
        ValueError: no such topic, or it is not ``sensor_msgs/Imu``, or it is empty.
    """
    topics = bag_topics(path)
    if topics.get(topic) != IMU:
        raise ValueError(f"{path}: no sensor_msgs/Imu topic {topic!r} (topics: {sorted(topics)})")
    ts = typestore()
    t, om = [], []
    for _, msgtype, _, raw in iter_messages(path, {topic}):
        msg = ts.deserialize_cdr(raw, msgtype)
        t.append(cv.stamp_to_ns(msg.header.stamp))
        a = msg.angular_velocity
        om.append((a.x, a.y, a.z))
    if not t:
        raise ValueError(f"{path}: {topic} has no messages")
    order = np.argsort(t)
    return np.asarray(t, dtype=np.int64)[order], np.asarray(om, dtype=float)[order]


def rig_parameter_values(
    bag: str | os.PathLike | None,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> tuple[dict, dict]:
    """``(values, camera values)`` for :func:`~rs_localizer.ros.config.build_config`: the
    defaults, then the bag's ``rig_params.yaml`` (``bag`` None: none), each parameter file,
    then ``params``, the node's parameters (:data:`~rs_localizer.ros.params.PARAMETERS`)
    checked as a camera's are (:func:`~rs_localizer.ros.param_files.checked_value`);
    ``rig.cameras``' names as the rig node reads them (stripped of spaces), and by each its
    camera values, its ``rig.<camera>.*`` parameters.

    Raises:
        ~rs_localizer.ros.params.ConfigError: a node parameter's value of the wrong type or
            outside its range (naming it); a file that is not a parameter file.
    """
    values = default_values()
    values.update({k: (list(p.default) if isinstance(p.default, list) else p.default)
                   for k, p in RIG_PARAMETERS.items()})  # fmt: skip
    tree: dict[str, Any] = {}
    own = None if bag is None else Path(bag) / "rig_params.yaml"
    for f in ([own] if own is not None and own.is_file() else []) + list(params_files):
        tree.update(read_params_file(f))
    tree.update(params or {})
    values.update({k: checked_value(k, v) if k in PARAMETERS else v
                   for k, v in tree.items() if k in values})  # fmt: skip
    names = values["rig.cameras"]
    if isinstance(names, (list, tuple)):  # (as the rig node names them: stripped)
        values["rig.cameras"] = names = [n.strip() if isinstance(n, str) else n for n in names]
    cams = {}
    for n in names:
        cams[n] = {k: tree.get(f"rig.{n}.{k}", p.default) for k, p in RIG_CAMERA_PARAMETERS.items()}
        cams[n]["mounting"] = tree.get(f"rig.{n}.mounting")
    return values, cams


#: the mounting every camera is read with where the mountings play no part (the frames of a
#: rig bag read for ``calibrate-rig`` and ``play --lockstep``): the identity
_ANY_MOUNTING = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


def rig_bag_config(
    bag: str | os.PathLike | None,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    *,
    mountings: bool = True,
) -> tuple[dict, dict, LocalizerConfig]:
    """``(values, camera values, config)``: the parameter values of
    :func:`rig_parameter_values` and the rig's configuration of them
    (:func:`~rs_localizer.ros.config.build_config`), as the rig node takes them.

    ``mountings`` False: the cameras' mountings are not read (the config's are the identity;
    the camera values keep the parameters' own), for readers of the cameras' frames alone
    (:func:`read_rig_frames`): a rig without mountings yet is read as well.

    Raises:
        ~rs_localizer.ros.params.ConfigError: the parameters (e.g. a camera without mounting,
            no ``rig.cameras``); a front end (``frontend`` not ``none``) for a bag without the
            cameras' images (``<namespace>/<camera>/image_raw``).
    """
    values, cams = rig_parameter_values(bag, params_files, params)
    kind = str(values.get("frontend", "none")).strip() or "none"
    if bag is not None and kind != "none":
        names = tuple(rig_camera_names(values["rig.cameras"]))
        wanted = RigTopics(rig_namespace(bag, names), names).of(("image",))
        if not set(wanted) & set(bag_topics(bag)):
            raise ConfigError(
                f"frontend {kind}: the rig bag has no camera images ({', '.join(wanted)}); "
                "without a front end (frontend: none) its correspondences are read"
            )
    given = cams
    if not mountings:
        given = {n: {**c, "mounting": _ANY_MOUNTING, "mounting_covariance": None}
                 for n, c in cams.items()}  # fmt: skip
    return values, cams, build_config(values, given)


def is_rig_bag(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> bool:
    """The bag is a rig's: its ``sequence.json`` has a ``rig`` entry (``make-bag --rig``,
    ``render-bag --rig``), or the parameter files and ``params`` name ``rig.cameras`` (a
    recording of a rig's cameras, replayed with the rig node's parameters)."""
    if "rig" in read_bag_info(bag):
        return True
    if not params_files and not (params or {}).get("rig.cameras"):
        return False
    values = rig_parameter_values(None, params_files, params)[0]
    return any(str(n).strip() for n in values["rig.cameras"] or ())


def rig_frontends(cfg: LocalizerConfig, owner: object) -> dict | None:
    """Each camera's front end of the rig's configuration ``cfg`` (:func:`rig_bag_config`: its
    cameras' ``frontend``, ``frontend_map``, ``aruco.*``, ...; one map loaded, a front end
    object per camera, as the rig node makes them, on behalf of ``owner``: release with
    ``rs_localizer.frontends.shared.SHARED_MAPS.release(owner)``), camera name -> front end;
    None when ``frontend`` is ``none`` (the bag's correspondences are read instead).

    Raises:
        ~rs_localizer.ros.params.ConfigError: a front-end map that does not load.
    """
    if cfg.camera.frontend_kind == "none":
        return None
    return {c.name: load_maps(c, owner=owner).frontend for c in cfg.cameras}


def rig_landmarks(cfg: LocalizerConfig, owner: object) -> tuple | None:
    """The landmarks of the parameter ``landmarks_file`` that the cameras' keypoints name
    (``(ids (M,), points (M, 3) m)``), loaded as the rig node loads them (on behalf of
    ``owner``: release with ``rs_localizer.frontends.shared.SHARED_MAPS.release(owner)``);
    None without one.

    Raises:
        ~rs_localizer.ros.params.ConfigError: a landmark table that does not load.
    """
    if not str(cfg.camera.landmarks_file).strip():
        return None
    return load_maps(replace(cfg.camera, frontend_kind="none"), owner=owner).landmarks


class QuietLog:
    """The cameras' inputs' log in a replay: nothing logged (what they drop is counted)."""

    def info(self, text: str) -> None:
        pass

    def error(self, text: str) -> None:
        pass

    def warning(self, key: str, text: str) -> None:
        pass


@dataclass
class RigFrames:
    """What :func:`read_rig_frames` read: ``items`` (every camera's clouds in log-time order,
    as :func:`iter_rig_frames` yields them: a
    :class:`~rs_localizer.tracking.localizer.CameraFrame`, or an
    :class:`~rs_localizer.ros.camera_input.DroppedFrame` for a cloud not read), ``values`` (the
    parameter values), ``cameras`` (the cameras' values, :func:`rig_parameter_values`) and
    ``counts``: camera -> :data:`READ_COUNTS`, the counts of its rows, ``points_dropped``
    (rows with a NaN or inf), ``capped_clouds`` (clouds capped to ``max_points``) and
    ``capped_points`` (the rows the cap left out), and of its clouds not read, ``bad_input``
    (no u, v, x, y, z fields: the rig node's ``<camera>.skipped.bad_input``), then the other
    reasons its messages were left out for (``bad_stamp``: a header stamp out of range, the rig
    node's ``<camera>.failed.bad_stamp``; an image's); ``settings``: the rig's
    :class:`~rs_localizer.tracking.video.LocalizerSettings` of those parameters (every mounting the
    identity: not read)."""

    items: list
    values: dict
    cameras: dict
    counts: dict
    settings: LocalizerSettings

    @property
    def frames(self) -> list:
        """The frames read (every :class:`~rs_localizer.tracking.localizer.CameraFrame` of
        :attr:`items`), in log-time order."""
        from ..camera_input import DroppedFrame

        return [f for f in self.items if not isinstance(f, DroppedFrame)]


#: the counts of a camera's rows and clouds :func:`read_rig_frames` reports
READ_COUNTS = ("points_dropped", "capped_clouds", "capped_points", "bad_input")


def read_rig_frames(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> RigFrames:
    """Every camera's frames of a rig bag, without mountings (what ``calibrate-rig`` reads).

    The cameras are ``rig.cameras`` of :func:`rig_parameter_values` (the bag's
    ``rig_params.yaml``, the parameter files, ``params``), configured as the rig node
    configures them (:func:`rig_bag_config`, the mountings not read); each camera's frames
    are read through its :class:`~rs_localizer.ros.camera_input.CameraInput`
    (:func:`iter_rig_frames`), as the rig node and ``replay`` read them: each cloud with the
    model of the camera_info of its stamp (None before the camera's first camera_info), its
    rows with a NaN or inf dropped, then at most ``max_points`` rows, counted per camera
    (:attr:`RigFrames.counts`); a cloud that cannot be read (no u, v, x, y, z fields) is in
    no frame, counted ``bad_input`` for its camera (as the rig node's
    ``<camera>.skipped.bad_input``), nor one whose header stamp is out of range, counted
    ``bad_stamp`` (the rig node's ``<camera>.failed.bad_stamp``).

    Raises:
        ValueError: no ``rig.cameras``;
            :class:`~rs_localizer.ros.params.ConfigError` (a ValueError): parameters the rig
            node refuses (e.g. an unknown readout direction).
    """
    from ...frontends.shared import SHARED_MAPS
    from ..camera_input import CameraCounts, DroppedFrame, rig_camera_inputs

    values = rig_parameter_values(bag, params_files, params)[0]
    if not [str(n).strip() for n in values["rig.cameras"]]:
        raise ValueError(f"{bag}: no rig.cameras (not a rig bag, and no --params-file with them)")
    values, cams, cfg = rig_bag_config(bag, params_files, params, mountings=False)
    counts = {c.name: CameraCounts(c.name) for c in cfg.cameras}

    def count(name: str, key: str, n: int = 1) -> None:
        counts[name].add(key, n)

    owner = object()  # (the front ends' maps, released once read)
    try:
        frontends = rig_frontends(cfg, owner)
        landmarks = rig_landmarks(cfg, owner)
        inputs = rig_camera_inputs(cfg, QuietLog(), count, landmarks=landmarks)
        items = list(iter_rig_frames(bag, inputs, frontends))
    finally:
        SHARED_MAPS.release(owner)
    for f in items:
        if isinstance(f, DroppedFrame):
            count(f.camera_name, f.reason)
    rows = {}
    for n, cc in counts.items():  # (READ_COUNTS, then the images' skip reasons counted)
        c = cc.counts()
        rows[n] = {k: int(c.get(k, 0)) for k in READ_COUNTS}
        rows[n].update({k: int(v) for k, v in c.items() if k not in READ_COUNTS})
    return RigFrames(items, values, cams, rows, cfg.settings)


def iter_rig_frames(
    bag: str | os.PathLike,
    inputs: Mapping[str, CameraInput],
    frontends: Mapping | None = None,
    images: bool = False,
) -> Iterator[CameraFrame | ImageFrame | DroppedFrame]:
    """The one reader of a rig bag's camera frames: every camera of ``inputs`` (camera name ->
    its :class:`~rs_localizer.ros.camera_input.CameraInput`,
    :func:`~rs_localizer.ros.camera_input.rig_camera_inputs`), in log-time order, from
    ``<namespace>/<camera>/correspondences``, read through the camera's input stage as the
    rig node reads them: its camera_infos checked and kept by their stamps (one rejected is
    counted ``camera_info_rejected.<reason>``, the previous ones stay) and each cloud given
    the model of its own stamp (:meth:`~rs_localizer.ros.camera_input.CameraInput.camera_of`:
    the newest camera_info stamped at or before it, the oldest for a cloud older than all;
    None before the camera's first camera_info is received), its rows with a NaN or inf
    dropped, counted ``points_dropped``, then at most its ``max_points``, highest scores
    first, counted ``capped_clouds``, ``capped_points``
    (:meth:`~rs_localizer.ros.camera_input.CameraInput.take`). One that cannot be read (no
    x, y, z / u, v fields) is yielded as a
    :class:`~rs_localizer.ros.camera_input.DroppedFrame` (``bad_input``), which the node
    counts received and skipped and hands to the rig as a frame skipped
    (:func:`~rs_localizer.ros.camera_input.to_rig`); one whose header stamp is out of range
    as a ``DroppedFrame`` without a stamp (``bad_stamp``), which the node counts received and
    failed and the rig never sees. With the cameras' landmarks
    (``landmarks_file``, :func:`rig_landmarks`, given to :func:`rig_camera_inputs`) each
    camera's keypoints (``.../keypoints``: u, v, id) are read too, beside its clouds, as the
    rig node reads them (each row the 3D point of its id; unknown ids counted
    ``unknown_landmark_ids``).

    With ``images`` each camera's images (``.../image_raw``) are read instead, as
    :class:`~rs_localizer.ros.camera_input.ImageFrame` (decoded and checked against the camera
    model of their stamp; one refused is a ``DroppedFrame`` with its reason, ``bad_image``,
    ``image_size_mismatch``), for the rig's front ends. With ``frontends`` (camera name -> its
    front end, :func:`rig_frontends`) too, each image's frame is the front end's
    correspondences on the whole image, without a rig to predict it (what ``calibrate-rig``
    reads; :func:`_found_frame`).

    Yields:
        :class:`~rs_localizer.tracking.localizer.CameraFrame` (name, header stamp ns, model,
        pixels (N, 2) px, points (N, 3) m, tagged with its ``frame_id``),
        :class:`~rs_localizer.ros.camera_input.ImageFrame` or
        :class:`~rs_localizer.ros.camera_input.DroppedFrame`.
    """
    from ..camera_input import ImageFrame

    kinds = rig_kinds(inputs, frontends is not None or images)
    topics = RigTopics(rig_namespace(bag, inputs), tuple(inputs)).of(("info", *kinds))
    for kind, n, msg, _ in camera_messages(bag, topics, inputs):  # (camera_infos taken there)
        if kind == "info":
            continue
        inp = inputs[n]
        stamp = inp.check(msg, kind)
        item = inp.take(msg, kind, stamp, inp.camera_of(stamp))
        if frontends is not None and isinstance(item, ImageFrame):
            item = _found_frame(inp, item, frontends[n])
        yield item


def _found_frame(inp: CameraInput, item: ImageFrame, frontend: Any) -> CameraFrame | DroppedFrame:
    """A camera's decoded image ``item`` as a frame of its front end's correspondences,
    without a rig to predict it (``calibrate-rig``): ``frontend.process(image, camera,
    encoding)`` (a :class:`~rs_localizer.correspondences.Frontend`) on the whole image, its
    rows as a cloud's (:meth:`~rs_localizer.ros.camera_input.CameraInput.usable`: non-finite
    rows dropped, at most ``max_points``), each with its group (a marker's corners: the
    marker's id, :attr:`~rs_localizer.correspondences.Correspondences.groups`), which the
    pose's covariance takes as a shift the marker's corners share. Without a camera model: a
    frame without rows, as the rig takes a frame before its camera_info. A front end that raises: a
    :class:`~rs_localizer.ros.camera_input.DroppedFrame` (``frontend_error``)."""
    from ...tracking.localizer import CameraFrame
    from ..camera_input import DroppedFrame

    name, stamp, camera, tag = item.camera_name, item.stamp_ns, item.camera, item.tag
    if camera is None:
        return CameraFrame(stamp, None, np.zeros((0, 2)), np.zeros((0, 3)), tag=tag,
                           camera_name=name)  # fmt: skip
    try:
        found = frontend.process(item.image, camera, item.encoding)
    except Exception as e:  # (any front end's failure: the frame is left out, counted)
        return DroppedFrame(name, stamp, camera, ValueError(f"{type(e).__name__}: {e}"),
                            "frontend_error")  # fmt: skip
    c = inp.usable(found)
    return CameraFrame(stamp, camera, c.points2d, c.points, tag=tag, camera_name=name,
                       groups=c.groups)  # fmt: skip


def rig_kinds(inputs: Mapping[str, CameraInput], images: bool = False) -> tuple[str, ...]:
    """The kinds of frame messages a rig's cameras (``inputs``, camera name -> its
    :class:`~rs_localizer.ros.camera_input.CameraInput`) are read from: with ``images`` their
    images (``image``), else their clouds (``cloud``) and, with the cameras' landmarks, their
    keypoints (``keypoints``)."""
    if images:
        return ("image",)
    if any(inp.landmarks is not None for inp in inputs.values()):
        return ("cloud", "keypoints")
    return ("cloud",)


def camera_messages(
    bag: str | os.PathLike, topics: Mapping[str, tuple[str, str]], inputs: Mapping[str, Any]
) -> Iterator[tuple[str, str, Any, int]]:
    """The one reader of a bag's camera messages (a camera's replay, a rig's, the rig's frames
    of :func:`iter_rig_frames`): the messages of ``topics`` (topic -> ``(kind, camera name)``,
    kind ``info`` for a ``sensor_msgs/CameraInfo``) in log-time order, deserialized, each
    camera_info given to its camera's input as it comes (``inputs[camera name].
    add_camera_info(msg)``: a :class:`~rs_localizer.ros.camera_input.CameraInput`).

    Yields:
        ``(kind, camera name, message, log time ns)`` of every message, camera_infos included.
    """
    ts = typestore()
    for topic, msgtype, t_log, raw in iter_messages(bag, set(topics)):
        kind, name = topics[topic]
        msg = ts.deserialize_cdr(raw, msgtype)
        if kind == "info":
            inputs[name].add_camera_info(msg)
        yield kind, name, msg, t_log
