"""Rig bags edited for the tests (``rosbags``, no ROS): any rig bag's messages rewritten, and a
2-camera rig bag some of whose clouds cannot be read."""

from __future__ import annotations

from dataclasses import dataclass, replace

#: the left camera's clouds (by index) :func:`bag_with_unread_clouds` writes without their
#: ``x`` field (stamps readable), and the one it writes with a stamp no ROS time holds
NO_X = range(3, 9)
BAD_STAMP = 10


def rewrite_bag(src, dst, edit):
    """Copy the bag ``src`` (a rig's or a camera's) to ``dst`` (its sequence.json and
    rig_params.yaml too, those it has), each message through ``edit(topic, msg,
    log_time_ns)`` -> ``[(log_time_ns, msg), ...]``."""
    import shutil

    from rosbags.rosbag2 import Writer

    from rs_localizer.ros.bags.bag_io import iter_messages, storage_plugin, typestore

    ts = typestore()
    with Writer(dst, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns = {}
        for topic, mt, t, raw in iter_messages(src):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, mt, typestore=ts)
            for t2, msg in edit(topic, ts.deserialize_cdr(raw, mt), t):
                w.write(conns[topic], t2, ts.serialize_cdr(msg, mt))
    for name in ("sequence.json", "rig_params.yaml"):
        if (src / name).exists():
            shutil.copy(src / name, dst / name)
    return dst


def cut_image(camera: str, index: int, width: int = 320, namespace: str = "/rig"):
    """An ``edit`` for :func:`rewrite_bag`: camera ``camera``'s ``index``-th image (from 0)
    cut to its first ``width`` columns (its camera_info keeps the full size: the node's
    ``image_size_mismatch``), every other message as it is."""
    import numpy as np

    seen = []

    def edit(topic, msg, t):
        if topic == f"{namespace}/{camera}/image_raw":
            seen.append(t)
            if len(seen) == index + 1:
                row = msg.step // msg.width * width
                data = np.asarray(msg.data).reshape(msg.height, msg.step)[:, :row].ravel()
                msg = replace(msg, width=width, step=row, data=data)
        return [(t, msg)]

    return edit


@dataclass
class UnreadCloudsBag:
    """:func:`bag_with_unread_clouds`: the bag, the rig's cameras, the frames written (the
    simulated rig video's), every camera's clouds by index (stamps, ns) and the ``(camera,
    stamp ns)`` of the clouds without ``x``."""

    bag: object
    cams: list
    frames: list
    stamps: dict
    no_x: set


def bag_with_unread_clouds(tmp_path, duration: float = 0.5, seed: int = 7) -> UnreadCloudsBag:
    """A 2-camera rig bag (``front``, ``left``, 30 fps) whose left clouds :data:`NO_X` have no
    ``x`` field (their stamps readable: the rig node hands them to the rig as frames skipped,
    ``bad_input``) and whose left cloud :data:`BAD_STAMP` has ``nanosec`` 1.5e9 (a stamp no ROS
    time holds: the node fails it alone, ``bad_stamp``)."""
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=duration, num_points=80, seed=seed)
    clean = write_rig_bag(tmp_path / "clean", frames, cams, traj)
    stamps = {c.name: [f.stamp_ns for f in frames if f.name == c.name] for c in cams}
    assert len(stamps["left"]) > BAD_STAMP
    no_x = {("left", stamps["left"][k]) for k in NO_X}

    def edit(topic, msg, t):
        if topic != "/rig/left/correspondences":
            return [(t, msg)]
        s = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        k = stamps["left"].index(s)
        if k in NO_X:
            msg = replace(msg, fields=[f for f in msg.fields if f.name != "x"])
        elif k == BAD_STAMP:
            bad = replace(msg.header.stamp, nanosec=1_500_000_000)
            msg = replace(msg, header=replace(msg.header, stamp=bad))
        return [(t, msg)]

    bag = rewrite_bag(clean, tmp_path / "unread", edit)
    return UnreadCloudsBag(bag, cams, frames, stamps, no_x)


def recording_of(bag, rec, params):
    """The rig bag ``bag`` as a recording of its cameras at ``rec``: every ``/rig/...`` topic
    moved to ``/...`` (the rig node's topics in the root namespace), no sequence.json, no
    ground truth; the bag's rig_params.yaml copied to ``params``. Returns ``(rec, params)``."""
    import shutil

    from rosbags.rosbag2 import Writer

    from rs_localizer.ros.bags.bag_io import iter_messages, storage_plugin, typestore

    with Writer(rec, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns, ts = {}, typestore()
        for topic, mt, t, raw in iter_messages(bag):
            if topic.startswith("/rig/"):
                topic = topic[len("/rig") :]
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, mt, typestore=ts)
                w.write(conns[topic], t, raw)
    shutil.copy(bag / "rig_params.yaml", params)
    return rec, params
