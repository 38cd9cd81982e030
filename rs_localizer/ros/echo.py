"""``/diagnostics`` printed live (``rs-localizer diagnostics``): one compact block per status,
its level, name and message on the first line, its key-value pairs (counters, timings) wrapped
below."""

from __future__ import annotations

import fnmatch
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = ["LEVEL_NAMES", "EchoResult", "echo_diagnostics", "format_status", "status_in_ns"]

#: ``diagnostic_msgs/DiagnosticStatus`` levels
LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


def _level(level: Any) -> int:
    """A status level as an int (rclpy gives a ``byte`` field as ``bytes``)."""
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def status_in_ns(name: str, ns: str | None) -> bool:
    """Whether the status ``name`` is a node's in namespace ``ns``: the node's status names
    end with its fully qualified name (``rs_localizer: /camera/rs_localizer``). ``ns`` None:
    every localizer's (names starting ``rs_localizer:``)."""
    if ns is None:
        return name.startswith("rs_localizer:")
    fq = name.rsplit(" ", 1)[-1]
    node_ns = fq.rsplit("/", 1)[0] if fq.startswith("/") else None
    return node_ns == ("/" + ns.strip("/") if ns.strip("/") else "")


def format_status(
    name: str,
    level: Any,
    message: str,
    values: Sequence[tuple[str, str]],
    keys: Sequence[str] | None = None,
    width: int = 100,
    stamp: float | None = None,
) -> str:
    """A status as a compact block: ``HH:MM:SS.s [LEVEL] name: message``, then its ``key=value``
    pairs (only those matching a shell pattern of ``keys`` if given) two spaces apart, wrapped
    at ``width`` characters (a pair is never split), indented by two. ``stamp``: the time
    shown (s since the epoch; default now)."""
    t = time.localtime(stamp if stamp is not None else time.time())
    frac = int(((stamp if stamp is not None else time.time()) % 1) * 10)
    lvl = _level(level)
    head = f"{time.strftime('%H:%M:%S', t)}.{frac} [{LEVEL_NAMES.get(lvl, lvl)}] {name}: {message}"
    pairs = [
        f"{k}={' '.join(str(v).split())}"
        for k, v in values
        if not keys or any(fnmatch.fnmatchcase(k, p) for p in keys)
    ]
    lines, line = [head], ""
    for p in pairs:
        if line and len(line) + 2 + len(p) > width - 2:
            lines.append("  " + line)
            line = p
        else:
            line = f"{line}  {p}" if line else p
    if line:
        lines.append("  " + line)
    return "\n".join(lines)


@dataclass
class EchoResult:
    """What :func:`echo_diagnostics` saw: blocks printed, and the names of the statuses it
    left out (other nodes')."""

    printed: int = 0
    timed_out: bool = False
    others: set[str] = field(default_factory=set)


def echo_diagnostics(
    out: Callable[[str], None],
    ns: str | None = None,
    every_status: bool = False,
    once: bool = False,
    timeout: float = 10.0,
    keys: Sequence[str] | None = None,
    width: int = 100,
    context: Any = None,
    stop: Callable[[], bool] | None = None,
) -> EchoResult:
    """Subscribe ``/diagnostics`` and print (``out``) each status of a localizer (in namespace
    ``ns`` if given; every status with ``every_status``) as :func:`format_status` blocks.

    Returns after the first message with such a status when ``once``; when none arrived for
    ``timeout`` s (0: wait forever) with ``timed_out`` set; at Ctrl-C; or when ``stop()`` is
    true.
    ``context``: an initialized rclpy Context (default: a new one, shut down at the end).
    The subscription is best effort (it receives reliable and best-effort publishers alike).
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(args=[], context=context)
    node = rclpy.create_node("rs_localizer_diagnostics_echo", context=context)
    res = EchoResult()
    last = [time.monotonic()]

    def on_msg(msg: Any) -> None:
        if once and res.printed:
            return
        now = time.time()
        for st in msg.status:
            if not every_status and not status_in_ns(st.name, ns):
                res.others.add(st.name)
                continue
            values = [(kv.key, kv.value) for kv in st.values]
            out(format_status(st.name, st.level, st.message, values, keys, width, now))
            res.printed += 1
            last[0] = time.monotonic()

    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_msg, qos)
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    try:
        while context.ok():
            ex.spin_once(timeout_sec=0.1)
            if once and res.printed:
                break
            if stop is not None and stop():
                break
            if timeout > 0 and time.monotonic() - last[0] > timeout:
                res.timed_out = True
                break
    except KeyboardInterrupt:  # (Ctrl-C: the way to stop it)
        pass
    finally:
        ex.remove_node(node)
        ex.shutdown()
        node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)
    return res
