"""A managed node's state and transitions from a client (``rs-localizer lifecycle``, and
``play`` naming a node that is not active): the ``lifecycle_msgs`` services every managed node
offers, ``<node>/get_state`` (``GetState``) and ``<node>/change_state`` (``ChangeState``), as
``ros2 lifecycle get|set`` calls them, without the ``ros2`` command line (which a pip install
lacks)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Any

__all__ = [
    "TRANSITIONS",
    "LifecycleError",
    "change_state",
    "client_session",
    "get_state",
    "inactive_nodes",
    "lifecycle_nodes",
]

#: the transitions a client requests, by the name ``ros2 lifecycle set`` gives them
TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")
GET_STATE = "lifecycle_msgs/srv/GetState"


class LifecycleError(RuntimeError):
    """No managed node of that name answers (no ``get_state`` service, or no reply)."""


@contextlib.contextmanager
def client_session(discovery: float = 0.0) -> Iterator[tuple[Any, Any]]:
    """``(node, executor)``: a client node in a new rclpy context (the environment's
    ``ROS_DOMAIN_ID``), spun ``discovery`` s first (to see the graph); shut down at the end."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node("rs_localizer_lifecycle_client", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        end = time.monotonic() + discovery
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        yield node, executor
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)


def lifecycle_nodes(node: Any) -> list[str]:
    """Full names (``/camera/rs_localizer``) of the managed nodes in the graph ``node`` sees:
    those offering a ``<name>/get_state`` service of type ``lifecycle_msgs/srv/GetState``."""
    return sorted(
        name[: -len("/get_state")]
        for name, kinds in node.get_service_names_and_types()
        if name.endswith("/get_state") and GET_STATE in kinds
    )


def _call(
    node: Any,
    executor: Any,
    srv_type: type,
    service: str,
    request: Any,
    timeout: float,
    resend: bool = False,
):
    """``request`` to ``service``; its reply, or LifecycleError after ``timeout`` s.
    ``resend``: send the request again every 2 s without a reply (a service can take a
    request before it matched the client's reply reader, and the reply is then lost); only
    for ``get_state``, which asking twice does not change (a transition asked twice would
    answer the second time that it is not valid from the new state)."""
    client = node.create_client(srv_type, service)
    try:
        deadline = time.monotonic() + timeout
        while not client.service_is_ready():
            if time.monotonic() > deadline:
                raise LifecycleError(f"no service {service} (is the node running, managed?)")
            executor.spin_once(timeout_sec=0.05)
        while True:
            fut = client.call_async(request)
            until = min(time.monotonic() + 2.0, deadline) if resend else deadline
            while not fut.done() and time.monotonic() < until:
                executor.spin_once(timeout_sec=0.05)
            if fut.done():
                return fut.result()
            client.remove_pending_request(fut)
            if time.monotonic() >= deadline:
                raise LifecycleError(f"{service} did not answer within {timeout:g} s")
    finally:
        node.destroy_client(client)


def get_state(node: Any, executor: Any, target: str, timeout: float = 10.0) -> str:
    """The state label (``unconfigured``, ``inactive``, ``active``, ``finalized``, or a
    transition's) of the managed node ``target`` (full name). Raises LifecycleError."""
    from lifecycle_msgs.srv import GetState

    reply = _call(
        node, executor, GetState, f"{target}/get_state", GetState.Request(), timeout, True
    )
    return str(reply.current_state.label)


def change_state(
    node: Any, executor: Any, target: str, transition: str, timeout: float = 300.0
) -> tuple[bool, str]:
    """Request ``transition`` (one of :data:`TRANSITIONS`) of the managed node ``target``:
    ``(success, state label after)``. ``shutdown`` picks the shutdown transition of the
    node's state; a transition not valid from the node's state is not requested (``(False,
    state)``). ``timeout``: s for the reply (configure compiles the kernels on a cold
    cache: minutes). Raises LifecycleError (no such node, no reply) or ValueError (an unknown
    transition)."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    if transition not in TRANSITIONS:
        raise ValueError(f"unknown transition {transition!r}; one of {', '.join(TRANSITIONS)}")
    before = get_state(node, executor, target)
    valid_from = {
        "configure": ("unconfigured",),
        "activate": ("inactive",),
        "deactivate": ("active",),
        "cleanup": ("inactive",),
        "shutdown": ("unconfigured", "inactive", "active"),
    }[transition]
    if before not in valid_from:  # (the node would not answer the request)
        return False, before
    ids = {
        "configure": Transition.TRANSITION_CONFIGURE,
        "activate": Transition.TRANSITION_ACTIVATE,
        "deactivate": Transition.TRANSITION_DEACTIVATE,
        "cleanup": Transition.TRANSITION_CLEANUP,
        "shutdown": {
            "unconfigured": Transition.TRANSITION_UNCONFIGURED_SHUTDOWN,
            "inactive": Transition.TRANSITION_INACTIVE_SHUTDOWN,
            "active": Transition.TRANSITION_ACTIVE_SHUTDOWN,
        }.get(before, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN),
    }
    req = ChangeState.Request(transition=Transition(id=ids[transition]))
    reply = _call(node, executor, ChangeState, f"{target}/change_state", req, timeout)
    return bool(reply.success), get_state(node, executor, target)


def inactive_nodes(node: Any, executor: Any, timeout: float = 3.0) -> dict[str, str]:
    """``{full name: state}`` of the managed nodes in the graph that are not ``active`` (a
    node that does not answer within ``timeout`` s is left out)."""
    out = {}
    for name in lifecycle_nodes(node):
        try:
            state = get_state(node, executor, name, timeout)
        except LifecycleError:
            continue
        if state != "active":
            out[name] = state
    return out
