"""Nodes under test: start one as a subprocess (or in this process), probe its topics and
diagnostics, set its parameters through its service. Nothing here imports rclpy at import time,
so the non-ROS tests run without ROS."""

from __future__ import annotations

import contextlib
import threading
import time

import pytest

from .paths import CONFIG


class LineLog:
    """A logger (``info``, ``warning``, ``error``, as a ``logging.Logger`` or rclpy's) keeping
    each line as ``(level, text)`` in :attr:`lines`."""

    def __init__(self):
        self.lines: list[tuple[str, str]] = []

    def info(self, text):
        self.lines.append(("info", text))

    def warning(self, text):
        self.lines.append(("warning", text))

    def error(self, text):
        self.lines.append(("error", text))

    def warnings(self) -> list[str]:
        """The warnings' texts."""
        return [t for level, t in self.lines if level == "warning"]


@contextlib.contextmanager
def spinning(context, *nodes):
    """Spin ``nodes`` on one executor in a background thread for the ``with`` block; then stop
    the thread, remove the nodes from the executor, destroy them and shut the executor down."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=context)
    for node in nodes:
        ex.add_node(node)
    stop = threading.Event()
    th = threading.Thread(
        target=lambda: [ex.spin_once(timeout_sec=0.02) for _ in iter(stop.is_set, True)]
    )
    th.start()
    try:
        yield
    finally:
        stop.set()
        th.join()
        for node in nodes:
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


def start_node(
    tmp_path, params=None, namespace="/camera", name="node", ready_timeout=120.0, config=(CONFIG,)
):
    """Start rs_localizer_node (``config`` files + ``params`` + reliable input QoS)."""
    from rs_localizer.ros.process import NodeProcess, ros_env, write_params_yaml

    topics = [f"{namespace}/{t}" for t in ("correspondences", "keypoints", "camera_info", "image")]
    overlay = write_params_yaml(
        tmp_path / f"{name}_params.yaml", params or {}, reliable_topics=topics
    )
    node = NodeProcess(
        [*config, overlay], namespace=namespace, env=ros_env(), log=tmp_path / f"{name}.log"
    )
    if not node.wait_ready(ready_timeout):
        log = node.log
        node.stop()
        pytest.fail(f"node did not become ready:\n{log}")
    return node


def stop_node(node, *probes):
    """Close ``probes``, then stop ``node``: ``(alive, rc)``, whether it was still running and
    its exit code. Call it in ``finally`` and assert after it (``assert alive and rc == 0,
    node.log``), so that a failure in the test body is not masked."""
    for p in probes:
        p.close()
    alive = node.alive()
    return alive, node.stop()


def refused_start(tmp_path, param_files, namespace, timeout):
    """Start a node on ``param_files`` that must refuse them and exit by itself. Returns
    ``(exited, rc, log)``: whether it exited within ``timeout`` s, its exit code (a node still
    running then is stopped first) and its log."""
    import contextlib
    import subprocess

    from rs_localizer.ros.process import NodeProcess, ros_env

    n = NodeProcess(
        list(param_files), namespace=namespace, env=ros_env(), log=tmp_path / "refused.log"
    )
    with contextlib.suppress(subprocess.TimeoutExpired):
        n.proc.wait(timeout)
    exited = not n.alive()
    rc = n.stop()
    return exited, rc, n.log


def in_process_parameters(overrides: dict) -> list:
    """``parameter_overrides`` for a localizer node a test builds in its own process: no
    warm-up (the test does not solve frames), no tf, then ``overrides``."""
    from rclpy.parameter import Parameter

    params = {"warmup": False, "publish_tf": False, **overrides}
    return [Parameter(k, value=v) for k, v in params.items()]


def diagnostics_in_process(ctx, name: str, overrides: dict) -> list:
    """Build ``RSLocalizerNode`` ``name`` in namespace ``/<name>`` in this process (no warm-up,
    no tf, diagnostics every 0.1 s, + ``overrides``) and a probe subscribed to ``/diagnostics``
    with rclpy's default QoS; spin both until the node's first status arrives (at most 20 s).
    Returns the node's statuses received (empty: none)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from rs_localizer.ros.node import RSLocalizerNode

    node = RSLocalizerNode(
        name,
        context=ctx,
        namespace=f"/{name}",
        parameter_overrides=in_process_parameters({"diagnostics_period": 0.1, **overrides}),
    )
    probe = rclpy.create_node(f"{name}_probe", context=ctx)
    got = []

    def on_diag(msg):
        got.extend(s for s in msg.status if name in s.name)

    probe.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(probe)
    try:
        deadline = time.monotonic() + 20
        while not got and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.1)
    finally:
        ex.shutdown()
        probe.destroy_node()
        node.destroy_node()
    return got


def assert_dropped(node, st, v, expected):
    """Each ``reason: n`` of ``expected`` is counted ``n`` times in the diagnostics values ``v``
    (``failed.<reason>``) and logged as ``frame dropped (<reason>)``; the diagnostic status
    ``st`` warns and the node is alive. Returns the node's log."""
    for reason, n in expected.items():
        assert int(v.get(f"failed.{reason}", 0)) == n, (reason, v)
    assert st.level == st.WARN
    assert node.alive()
    log = node.log
    for reason in expected:
        assert f"frame dropped ({reason})" in log, reason
    return log


class Probe:
    """Test-side ROS node: publishes inputs (reliable) and records the node's outputs."""

    def __init__(self, context, namespace="/camera"):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistStamped
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CameraInfo, PointCloud2

        self.ns = namespace
        self.node = rclpy.create_node("rs_localizer_test_probe", context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_corr = self.node.create_publisher(PointCloud2, f"{namespace}/correspondences", qos)
        self.pub_kp = self.node.create_publisher(PointCloud2, f"{namespace}/keypoints", qos)
        self.pub_info = self.node.create_publisher(CameraInfo, f"{namespace}/camera_info", qos)
        self.outputs = {"pose": [], "twist": [], "odom": [], "pose_with_covariance": []}
        types = {
            "pose": PoseStamped,
            "twist": TwistStamped,
            "odom": Odometry,
            "pose_with_covariance": PoseWithCovarianceStamped,
        }
        for k, t in types.items():
            self.node.create_subscription(
                t, f"{namespace}/{k}", lambda m, k=k: self.outputs[k].append(m), qos
            )
        self.diag = {}
        self.diag_history = []  # (status name, values) of every diagnostics message
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, qos)

    def _on_diag(self, msg):
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            self.diag[st.name] = (st, values)
            self.diag_history.append((st.name, values))

    def spin(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.02, max(end - time.monotonic(), 0)))

    def wait(self, predicate, timeout=10.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return predicate()

    def wait_matched(self, timeout=30.0):
        ok = self.wait(
            lambda: (
                all(
                    p.get_subscription_count() > 0
                    for p in (self.pub_corr, self.pub_kp, self.pub_info)
                )
                and self.node.count_publishers(f"{self.ns}/pose") > 0
                and self.node.count_publishers("/diagnostics") > 0
            ),
            timeout,
        )
        assert ok, "node did not match the probe's topics"

    def wait_camera_info(self, timeout=30.0):
        """Wait until the node's diagnostics say its intrinsics come from ``camera_info``: a
        reliable message published right after matching can still reach the node after a
        frame sent a moment later (discovery finishes on the node's side later)."""
        name = f"{self.ns}/rs_localizer"
        ok = self.wait(
            lambda: any(
                k.endswith(name) and values.get("camera") == "camera_info"
                for k, (_, values) in self.diag.items()
            ),
            timeout,
        )
        assert ok, "the node did not report the camera_info"

    def pose_near(self, stamp_ns, tol_ns=1_000):
        from rs_localizer.ros.conversions import stamp_to_ns

        for m in self.outputs["pose"]:
            if abs(stamp_to_ns(m.header.stamp) - stamp_ns) <= tol_ns:
                return m
        return None

    def wait_pose(self, stamp_ns, timeout=10.0):
        """Wait for a pose stamped ``stamp_ns`` (+-1 us); returns it or None."""
        self.wait(lambda: self.pose_near(stamp_ns) is not None, timeout)
        return self.pose_near(stamp_ns)

    def node_diag(self):
        for name, (st, values) in self.diag.items():
            if name.startswith("rs_localizer:") and name.endswith(f"{self.ns}/rs_localizer"):
                return st, values
        return None, {}

    def wait_diag(self, predicate, timeout=10.0):
        """Wait until the node's latest diagnostics values satisfy ``predicate(values)``."""
        self.wait(lambda: predicate(self.node_diag()[1]), timeout)
        return self.node_diag()

    def close(self):
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown()


class ParamClient:
    """Sets parameters through the node's ``set_parameters`` service."""

    def __init__(self, ctx, node_name):
        import rclpy
        from rcl_interfaces.srv import SetParameters
        from rclpy.executors import SingleThreadedExecutor

        self.node = rclpy.create_node("rs_localizer_test_param_client", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.cli = self.node.create_client(SetParameters, f"{node_name}/set_parameters")
        assert self.cli.wait_for_service(timeout_sec=20.0)

    def set(self, **values):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        req = SetParameters.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        fut = self.cli.call_async(req)
        self.ex.spin_until_future_complete(fut, timeout_sec=30.0)
        assert fut.done()
        return fut.result().results

    def close(self):
        self.ex.remove_node(self.node)
        self.node.destroy_node()
        self.ex.shutdown()


def camera_status(cfg, snap, tracking, source, lost, latencies=(), stamp_ages=(), rate_hz=None,
                  bias=None, inconsistent=False, idle_s=None, frontend=None):  # fmt: skip
    """``(level, message, values)`` of one camera's status as its node builds it: the
    camera's parts (``rs_localizer.ros.diagnostics.status_parts`` of the camera alone,
    ``CameraAlone``, of its config ``cfg``, its counters ``snap``, camera ``source``,
    messages ``lost``, its front end's values ``frontend``; its ``tracking`` values, with
    ``imu.enabled`` its gyro of ``rate_hz``, ``bias``, ``inconsistent``, ``idle_s``) laid out
    with the node's ``latencies`` and ``stamp_ages`` (s)."""
    from rs_localizer.ros.diagnostics import CameraAlone, GyroState, status, status_parts

    gyro = None
    if cfg.imu is not None:
        gyro = GyroState(cfg.imu, snap.counts, rate_hz, bias, inconsistent, idle_s)
    values = None
    if frontend is not None:
        from rs_localizer.ros.diagnostics import frontend_values

        values = frontend_values(cfg.camera.frontend_kind, frontend, snap)
    alone = CameraAlone(cfg.solver, source, cfg.queue_size, snap, lost, values)
    parts = status_parts([alone.part()], tracking, snap.counts, gyro, snap.stage_times,
                         values is not None, alone)  # fmt: skip
    return status(parts, (latencies, stamp_ages))


def rig_status(rig, waiting=(), inputs=None, timing=None):
    """``(level, message, values)`` of a rig's status as the rig node builds it
    (``rs_localizer.ros.diagnostics.localizer_status_parts`` of the ``rig``, the cameras
    ``waiting`` for their camera_info and the node's ``inputs``, laid out with its
    ``timing``)."""
    from rs_localizer.ros.diagnostics import localizer_status_parts, status

    return status(localizer_status_parts(rig, None, waiting, inputs), timing)
