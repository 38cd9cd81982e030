"""The rig node driven over DDS by a probe node on one executor (the rig node's tests)."""

from __future__ import annotations

import time

from .rig import T0


def rig_parameters(cams, mountings=None, **extra):
    """The rig node's parameters for the rig cameras ``cams`` (``sim.trajectory.RigCameraSim``):
    each one's mounting (``mountings``: name -> rotation to use instead of the true one),
    line delay and readout direction, plus ``extra``; no warm-up, no ``/tf``."""
    from rclpy.parameter import Parameter

    from rs_localizer.ros.conversions import quaternion_from_matrix

    p = {
        "warmup": False,
        "publish_tf": False,
        "diagnostics_period": 0.1,
        "rig.cameras": [c.name for c in cams],
        **extra,
    }
    for c in cams:
        R = c.R_rig_cam if mountings is None else mountings.get(c.name, c.R_rig_cam)
        q = quaternion_from_matrix(R)
        p[f"rig.{c.name}.mounting"] = [float(x) for x in (*c.p_rig_cam, *q)]
        p[f"rig.{c.name}.line_delay"] = float(c.camera.line_delay)
        p[f"rig.{c.name}.direction"] = c.camera.readout
    return [Parameter(k, value=v) for k, v in p.items()]


class RigHarness:
    """A rig node (or the managed one) under ``/rig`` and a probe on one executor: the probe
    publishes each camera's camera_info, images and clouds (reliable, lock-step on the node's
    counts) and records pose, odom and the node's diagnostics. ``timeout``: s, how long
    :meth:`wait` waits by default."""

    def __init__(self, ctx, cams, node, timeout: float = 30.0):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CameraInfo, Image, PointCloud2

        self.node = node
        self.timeout = timeout
        self.probe = rclpy.create_node("rig_probe", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.ex.add_node(self.probe)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = {
            c.name: {
                "image": self.probe.create_publisher(Image, f"/rig/{c.name}/image_raw", qos),
                "cloud": self.probe.create_publisher(
                    PointCloud2, f"/rig/{c.name}/correspondences", qos
                ),
                "info": self.probe.create_publisher(CameraInfo, f"/rig/{c.name}/camera_info", qos),
                "keypoints": self.probe.create_publisher(
                    PointCloud2, f"/rig/{c.name}/keypoints", qos
                ),
            }
            for c in cams
        }
        self.poses, self.odom, self.diag = [], [], []
        self.probe.create_subscription(PoseStamped, "/rig/pose", self.poses.append, qos)
        self.probe.create_subscription(Odometry, "/rig/odom", self.odom.append, qos)

        def on_diag(msg):
            self.diag += [s for s in msg.status if "/rig/rs_localizer" in s.name]

        self.probe.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos)

    def matched(self, kinds=("image", "info"), outputs=("pose",)) -> bool:
        """Whether the node subscribed the probe's ``kinds`` of every camera and the probe
        its ``outputs`` (waits up to :attr:`timeout`)."""
        return self.wait(
            lambda: (
                all(ps[k].get_subscription_count() > 0 for ps in self.pub.values() for k in kinds)
                and all(self.probe.count_publishers(f"/rig/{o}") > 0 for o in outputs)
                and all(self.node._pubs[o].get_subscription_count() > 0 for o in outputs)
            )
        )

    def wait(self, predicate, timeout: float | None = None) -> bool:
        end = time.monotonic() + (self.timeout if timeout is None else timeout)
        while time.monotonic() < end:
            if predicate():
                return True
            self.ex.spin_once(timeout_sec=0.01)
        return predicate()

    def send_info(self, cams):
        from rs_localizer.ros.conversions import camera_info_msg

        for c in cams:
            self.pub[c.name]["info"].publish(camera_info_msg(c.camera, c.name, T0))
        assert self.wait(lambda: all(self.node.inputs[c.name].newest is not None for c in cams))

    def send(self, name, kind, msg, taken=True):
        """Publish one frame; with ``taken``, wait until the node counted it."""
        key = f"{name}.received"
        n = self.node.mode.rig.counts[key]
        self.pub[name][kind].publish(msg)
        if taken:
            assert self.wait(lambda: self.node.mode.rig.counts[key] > n), (name, kind)

    def send_clouds(self, frames):
        """Each rig camera frame's correspondences in turn (lock-step)."""
        from rs_localizer.ros.conversions import ns_to_stamp
        from rs_localizer.ros.pointcloud import correspondence_cloud

        for f in frames:
            cloud = correspondence_cloud(
                f.uv, f.xyz, frame_id=f.name, stamp=ns_to_stamp(f.stamp_ns)
            )
            self.send(f.name, "cloud", cloud)

    def last_diag(self, until=None):
        """The node's newest diagnostics status and its values, two statuses after the call;
        with ``until`` (a predicate of the values), the first later status of which it holds
        (the worker may still be solving the frames sent: a loaded machine), or the last one
        within :attr:`timeout`."""
        n = len(self.diag)
        assert self.wait(lambda: len(self.diag) > n + 1)
        if until is not None:
            self.wait(lambda: until({kv.key: kv.value for kv in self.diag[-1].values}))
        st = self.diag[-1]
        return st, {kv.key: kv.value for kv in st.values}

    def close(self):
        self.ex.shutdown()
        self.probe.destroy_node()
        self.node.destroy_node()
