"""The rig mode of ``rs_localizer_node``: one pose for a rig of rolling-shutter cameras.

With ``rig.cameras`` set (docs/rig_node.md) the process runs this node instead of one localizer
per camera. Every camera of the rig sends its own frames, unsynchronized; the node hands them
to a :class:`~rs_localizer.tracking.rig.RigLocalizer` (frames grouped into rig frames by stamp,
one pose per rig frame from all cameras, tracked, the rig's twist fused) and publishes the rig,
``base_frame``, as one body.

Subscriptions (relative names; remap as usual), per camera ``<c>`` of ``rig.cameras``:
    <c>/correspondences  sensor_msgs/PointCloud2  u, v [px, distorted], x, y, z [m, map frame]
    <c>/camera_info      sensor_msgs/CameraInfo   the camera's intrinsics; until one arrives
                         the camera's frames wait (counted ``<c>.skipped.no_camera_info``) and
                         the rig runs on the others
Publications (reliable, depth 10), the rig's (``base_frame``) pose in ``map_frame``:
    pose, pose_with_covariance, twist_single_frame (the rig frame's own twist), twist and odom
    (the fused twist ``tracking.lag`` rig frames later, stamped with that rig frame's time;
    the own twist without tracking), /tf (map_frame -> base_frame, with ``publish_tf``),
    /diagnostics (one status: the rig's counts and every camera's, with warnings)

The frames are solved in the subscription callbacks (one executor thread; a rig frame of
3 x 150 correspondences takes ~40 ms): the node has no frame queue. The parameters are read
once, at start (changes at run time are refused). The managed node has no rig mode.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, PointCloud2

from ..tracking.rig import RigCameraFrame, RigLocalizer, RigOutput
from . import conversions as cv
from .declare import declare_parameters
from .params import (
    PARAMETERS,
    RIG_CAMERA_PARAMETERS,
    RIG_PARAMETERS,
    ConfigError,
    RigConfig,
    rig_config,
)
from .pointcloud import read_correspondences
from .qos import CLOUD_QOS, RELIABLE, output_events

__all__ = ["RigLocalizerNode", "rig_diagnostics"]

_ARRAY_TYPES = {"rig.cameras": RosParameter.Type.STRING_ARRAY}


class _Log:
    """The rig's warnings to the node's logger, each kind (key) at most once per 5 s."""

    def __init__(self, logger, clock=time.monotonic):
        self.logger, self._clock, self._last = logger, clock, {}

    def warning(self, key: str, text: str, count: int = 0) -> None:
        now = self._clock()
        if now - self._last.get(key, -np.inf) >= 5.0:
            self._last[key] = now
            self.logger.warning(text)

    def info(self, text: str) -> None:
        self.logger.info(text)


def _declare_typed(node: Node, name: str, par, array_type) -> Any:
    """Declare a parameter whose default is an empty array with its type; returns its value
    (None: not set)."""
    d = ParameterDescriptor(description=par.description, read_only=par.read_only)
    node.declare_parameter(name, array_type, d)
    try:
        return node.get_parameter(name).value
    except ParameterUninitializedException:
        return None


def rig_diagnostics(rig: RigLocalizer, waiting_info: set) -> tuple[str, str, dict]:
    """``(level, message, values)`` of the rig's status: level ``OK``, ``WARN`` (a camera
    disagrees with the rig, has stopped, waits for its camera_info, or rig frames failed) or
    ``ERROR`` (rig frames formed and none was posed). Values: ``rig_frames``,
    ``rig_frames_solved``, ``_failed``, ``_skipped``, ``_pending``, ``track_state``, and per
    camera ``<c>.received``, ``.solved``, ``.failed``, ``.skipped``, ``.pending``, ``.state``
    (waiting, running, stopped, disagrees), ``.camera_info`` (received or waiting),
    ``.inliers``, ``.inlier_share``, ``.inlier_ratio`` (of the last rig frame it was in),
    ``.missed`` and ``.skipped.<reason>`` / ``.missed.<reason>`` counts."""
    r = rig.rig_counts()
    values: dict[str, Any] = {
        "rig_frames": r["rig_frames"],
        "rig_frames_solved": r["solved"],
        "rig_frames_failed": r["failed"],
        "rig_frames_skipped": r["skipped"],
        "rig_frames_pending": r["pending"],
        "track_state": rig.track_state,
    }
    warnings = []
    for n in rig.cameras:
        c = rig.camera_counts(n)
        for k, v in c.items():
            values[f"{n}.{k}"] = v
        state = rig.camera_state(n)
        values[f"{n}.state"] = state
        values[f"{n}.camera_info"] = "waiting" if n in waiting_info else "received"
        s = rig.last_share(n)
        values[f"{n}.inliers"] = s.inliers if s else 0
        values[f"{n}.inlier_share"] = f"{s.share:.3f}" if s else "nan"
        values[f"{n}.inlier_ratio"] = f"{s.ratio:.3f}" if s else "nan"
        values[f"{n}.missed"] = sum(
            v for k, v in rig.counts.items() if k.startswith(f"{n}.missed.")
        )
        for k, v in sorted(rig.counts.items()):
            if k.startswith((f"{n}.skipped.", f"{n}.missed.")):
                values[k] = v
        if state == "disagrees":
            warnings.append(f"camera {n} disagrees with the rig: likely a wrong mounting")
        elif state == "stopped":
            warnings.append(f"camera {n} stopped")
        if n in waiting_info:
            warnings.append(f"camera {n} waits for its camera_info")
    if r["rig_frames"] > r["pending"] + r["skipped"] and r["solved"] == 0:
        return "ERROR", "no rig frame posed", values
    if r["failed"]:
        warnings.append(f"{r['failed']} rig frames failed")
    if warnings:
        return "WARN", "; ".join(warnings), values
    return "OK", f"{r['solved']} rig frames posed", values


_LEVELS = {
    "OK": DiagnosticStatus.OK,
    "WARN": DiagnosticStatus.WARN,
    "ERROR": DiagnosticStatus.ERROR,
}


class RigLocalizerNode(Node):
    """The rig mode (module docstring). ``node_name`` and ``kwargs`` go to
    :class:`rclpy.node.Node`.

    Raises:
        RuntimeError: invalid parameters, e.g. a camera without ``rig.<camera>.mounting``
            (the message names it).
    """

    def __init__(self, node_name: str = "rs_localizer", **kwargs: Any):
        Node.__init__(self, node_name, **kwargs)
        declare_parameters(self, PARAMETERS)
        declare_parameters(self, {k: v for k, v in RIG_PARAMETERS.items() if k != "rig.cameras"})
        names = _declare_typed(
            self, "rig.cameras", RIG_PARAMETERS["rig.cameras"], _ARRAY_TYPES["rig.cameras"]
        )
        values = {n: self.get_parameter(n).value for n in PARAMETERS}
        values.update(
            {n: self.get_parameter(n).value for n in RIG_PARAMETERS if n != "rig.cameras"}
        )
        values["rig.cameras"] = list(names or [])
        cams = {}
        for n in values["rig.cameras"]:
            n = str(n).strip()
            if not n or self.has_parameter(f"rig.{n}.line_delay"):
                continue
            own = {k: v for k, v in RIG_CAMERA_PARAMETERS.items() if k != "mounting"}
            declare_parameters(self, {f"rig.{n}.{k}": v for k, v in own.items()})
            cams[n] = {k: self.get_parameter(f"rig.{n}.{k}").value for k in own}
            cams[n]["mounting"] = _declare_typed(
                self,
                f"rig.{n}.mounting",
                RIG_CAMERA_PARAMETERS["mounting"],
                RosParameter.Type.DOUBLE_ARRAY,
            )
        try:
            self.config: RigConfig = rig_config(values, cams)
        except ConfigError as e:
            raise RuntimeError(f"invalid parameters: {e}") from None
        self.map_frame = str(values["map_frame"])
        self._log = _Log(self.get_logger())
        self.rig = RigLocalizer(self.config.settings, log=self._log)
        self.models: dict[str, Any] = {c.name: None for c in self.config.cameras}
        self.bad_input: dict[str, int] = {c.name: 0 for c in self.config.cameras}
        self._pubs = {
            topic: self.create_publisher(t, topic, RELIABLE, event_callbacks=output_events())
            for topic, t in (
                ("pose", PoseStamped),
                ("pose_with_covariance", PoseWithCovarianceStamped),
                ("twist_single_frame", TwistStamped),
                ("twist", TwistStamped),
                ("odom", Odometry),
            )
        }
        if values["publish_tf"] and cv.have_tf2_msgs():
            from tf2_msgs.msg import TFMessage

            self._pubs["tf"] = self.create_publisher(
                TFMessage, "/tf", RELIABLE, event_callbacks=output_events()
            )
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", RELIABLE)
        self._subs = []
        for c in self.config.cameras:
            self._subs.append(
                self.create_subscription(
                    CameraInfo,
                    f"{c.name}/camera_info",
                    lambda msg, c=c: self._on_info(c, msg),
                    qos_profile_sensor_data,
                )
            )
            self._subs.append(
                self.create_subscription(
                    PointCloud2,
                    f"{c.name}/correspondences",
                    lambda msg, n=c.name: self._on_cloud(n, msg),
                    CLOUD_QOS,
                )
            )
        self._timer = self.create_timer(
            float(values["diagnostics_period"]), self.publish_diagnostics
        )
        self.add_on_set_parameters_callback(self._refuse_changes)
        self.get_logger().info(
            f"ready: rig of {len(self.config.cameras)} cameras "
            f"({', '.join(c.name for c in self.config.cameras)}) posed as {self.config.base_frame}"
            f" in {self.map_frame}"
        )

    def _refuse_changes(self, params) -> SetParametersResult:
        """The rig mode reads its parameters once, at start: changes are refused."""
        names = ", ".join(p.name for p in params)
        return SetParametersResult(
            successful=False,
            reason=f"the rig mode reads its parameters at start; restart to change {names}",
        )

    # ---------------------------------------------------------------- inputs
    def _on_info(self, cam, msg) -> None:
        try:
            self.models[cam.name] = cv.camera_model_from_camera_info(
                msg, cam.line_delay, cam.readout_time, cam.direction, self.config.reference_row
            )
        except ValueError as e:
            self.bad_input[cam.name] += 1
            self._log.warning(
                f"info.{cam.name}", f"rig camera {cam.name!r}: camera_info rejected: {e}"
            )

    def _on_cloud(self, name: str, msg) -> None:
        try:
            stamp = cv.checked_stamp_ns(msg.header.stamp)
            c = read_correspondences(msg)
        except ValueError as e:
            self.bad_input[name] += 1
            self._log.warning(f"cloud.{name}", f"rig camera {name!r}: frame not read: {e}")
            return
        frame = RigCameraFrame(name, stamp, self.models[name], c.pixels, c.points)
        for out in self.rig.add(frame):
            self.publish_output(out)

    # ---------------------------------------------------------------- outputs
    def _wanted(self, topic: str) -> bool:
        pub = self._pubs.get(topic)
        return pub is not None and pub.get_subscription_count() > 0

    def publish_output(self, out: RigOutput) -> None:
        """Publish a rig frame: its pose (and own twist) when solved, the fused twists it made
        final (or its own twist without tracking)."""
        base, mf = self.config.base_frame, self.map_frame
        m = out.measurement
        if m is not None:
            stamp = out.stamp_ns
            self._pubs["pose"].publish(cv.pose_stamped(m.pose, stamp, mf))
            if self._wanted("pose_with_covariance"):
                self._pubs["pose_with_covariance"].publish(
                    cv.pose_with_covariance_stamped(m, stamp, mf)
                )
            if self._wanted("twist_single_frame"):
                self._pubs["twist_single_frame"].publish(cv.twist_stamped(m.pose, stamp, base))
            if self.config.settings.tracking is None:
                self._pubs["twist"].publish(cv.twist_stamped(m.pose, stamp, base))
                self._pubs["odom"].publish(cv.odometry(m, stamp, mf, base))
            if "tf" in self._pubs:
                self._pubs["tf"].publish(cv.tf_message(m.pose, stamp, mf, base))
        for f in out.fused:
            self._pubs["twist"].publish(cv.twist_stamped(f.pose, f.pose.stamp_ns, base))
            self._pubs["odom"].publish(cv.odometry(f, f.pose.stamp_ns, mf, base))

    def diagnostics_status(self) -> DiagnosticStatus:
        waiting = {n for n, m in self.models.items() if m is None}
        level, message, values = rig_diagnostics(self.rig, waiting)
        for n, k in self.bad_input.items():
            values[f"{n}.bad_input"] = k
        st = DiagnosticStatus()
        st.name = f"rs_localizer: {self.get_fully_qualified_name()}"
        st.hardware_id = self.config.base_frame
        st.level, st.message = _LEVELS[level], message
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        return st

    def publish_diagnostics(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self.diagnostics_status()]
        self.pub_diag.publish(msg)

    def destroy_node(self) -> None:
        """Solve the rig frames still open and publish them and the pending twists, then
        destroy the node."""
        try:
            for out in self.rig.close():
                self.publish_output(out)
            base, mf = self.config.base_frame, self.map_frame
            for f in self.rig.flush():
                self._pubs["twist"].publish(cv.twist_stamped(f.pose, f.pose.stamp_ns, base))
                self._pubs["odom"].publish(cv.odometry(f, f.pose.stamp_ns, mf, base))
        except Exception:  # (shutting down: the context may be gone)
            pass
        return super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """The rig mode alone (``python -m rs_localizer.ros.rig_node --ros-args ...``);
    ``rs_localizer_node`` starts it when ``rig.cameras`` is set."""
    from .runner import run

    return run(RigLocalizerNode, args, "rs_localizer_node")


if __name__ == "__main__":
    sys.exit(main())
