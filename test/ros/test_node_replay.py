"""``rs-localizer replay`` is the node offline: on the sample bags, with the node's parameter
files, replay writes the same poses and twists (fused ``twist`` and ``twist_single_frame``),
stamp by stamp, as the node publishes when the bag is played to it over DDS in lock-step.

The node and replay both run the camera as the rig mode's rig of one camera named "", on the
same frames in the same order with the same camera_infos; the estimator and the tracker are
deterministic (fixed RANSAC seed). With the PyPI wheels the two processes agree bit for bit;
with Debian's NumPy and BLAS they were seen to differ in the last bits (2-4e-15 m on positions
of a few metres), so the values are compared to 1e-12 relative to their magnitude.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from helpers.paths import CONFIG, IMAGES_CONFIG
from helpers.ros import start_node

NS = "/cmp"
TOPICS = ("pose", "twist", "twist_single_frame")


def _by_stamp(messages) -> dict:
    from rs_localizer.ros.conversions import stamp_to_ns

    out = {}
    for m in messages:
        out.setdefault(stamp_to_ns(m.header.stamp), m)
    return out


def _values(topic: str, m) -> np.ndarray:
    if topic == "pose":
        p, q = m.pose.position, m.pose.orientation
        return np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w])
    a, b = m.twist.angular, m.twist.linear
    return np.array([a.x, a.y, a.z, b.x, b.y, b.z])


def _node_outputs(tmp_path, ros_context, bag, files, params, frame_topic):
    """The node's outputs by topic and stamp, the bag played to it in lock-step."""
    from rs_localizer.ros.bags.play import play

    node = start_node(tmp_path, params, namespace=NS, name="cmp", config=files)
    try:
        kind = "image" if frame_topic.endswith("image_raw") else "correspondences"
        res = play(
            bag,
            lockstep=True,
            topics=[frame_topic, "/camera/camera_info"],
            remap={frame_topic: f"{NS}/{kind}", "/camera/camera_info": f"{NS}/camera_info"},
            output_topics=tuple(f"{NS}/{t}" for t in TOPICS),
            late_topics=(f"{NS}/twist",),  # (fused: a frame late)
            context=ros_context,
            timeout=10.0,
            retries=0,
            log=print,
        )
        assert res.timeouts == 0 and res.answered == len(res.frames), node.log
        outputs = {
            t: _by_stamp(
                f["outputs"][f"{NS}/{t}"][1] for f in res.frames if f"{NS}/{t}" in f["outputs"]
            )
            for t in TOPICS
        }
    finally:
        alive, rc = node.alive(), node.stop()
    assert alive and rc == 0, node.log
    return outputs, len(res.frames)


def _replay_outputs(tmp_path, bag, files, params):
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore
    from rs_localizer.ros.bags.replay import replay

    res = replay(bag, params_files=files, params=params, out_bag=tmp_path / "out", progress=None)
    ts = typestore()
    msgs = {t: [] for t in TOPICS}
    for topic, mt, _, raw in iter_messages(
        tmp_path / "out", {f"/rs_localizer/{t}" for t in TOPICS}
    ):
        msgs[topic.rsplit("/", 1)[1]].append(ts.deserialize_cdr(raw, mt))
    return {t: _by_stamp(m) for t, m in msgs.items()}, res


@pytest.mark.parametrize("mode", ["correspondences", "images"])
def test_replay_writes_what_the_node_publishes(
    mode, tmp_path, ros_context, sample_bag, sample_images_bag
):
    from rs_localizer.ros.bags.bag_io import read_bag_info

    if mode == "images":  # (configured as the demo configures the node on this bag)
        bag, files, frame_topic = sample_images_bag, [CONFIG, IMAGES_CONFIG], "/camera/image_raw"
        rs = read_bag_info(bag)["rs"]
        params = {
            "frontend": "aruco",
            "frontend_map": str((bag / "markers.yaml").resolve()),
            "rs.line_delay": float(rs["line_delay"]),
            "rs.readout_time": 0.0,
            "rs.stamp_row": float(rs["stamp_row"]),
        }
    else:
        bag, files, frame_topic = sample_bag, [CONFIG], "/camera/correspondences"
        params = {}
    # The node publishes a frame's fused twist without the next frame once no frame has come
    # for ``tracking.max_gap`` s of wall time; replay never waits. On a busy machine the
    # lock-step player can take longer than the default 0.5 s between two frames: 3 s keeps
    # that early twist to the bag's last frame (the bag's stamps are 33 ms apart).
    params["tracking.max_gap"] = 3.0
    offline, res = _replay_outputs(tmp_path, bag, files, params)
    live, n = _node_outputs(tmp_path, ros_context, bag, files, params, frame_topic)
    assert res.solved == len(res.rows) == n
    assert res.config.tracking is not None and res.config.tracking.fusion.lag == 1
    for topic in TOPICS:
        assert len(offline[topic]) == n, topic
        assert sorted(live[topic]) == sorted(offline[topic]), topic  # the same stamps
        worst = 0.0  # largest difference relative to the value's magnitude (at least 1)
        for stamp, m in offline[topic].items():
            a, b = _values(topic, m), _values(topic, live[topic][stamp])
            worst = max(worst, float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1.0))))
            assert m.header.frame_id == live[topic][stamp].header.frame_id
        print(f"{mode} {topic}: {n} stamps, largest difference {worst:.3g}")
        assert worst <= 1e-12, (topic, worst)
    # the fused twist is not the single-frame one (tracking on, as in the node)
    some = next(iter(offline["twist"]))
    assert not np.array_equal(
        _values("twist", offline["twist"][some]),
        _values("twist_single_frame", offline["twist_single_frame"][some]),
    )
