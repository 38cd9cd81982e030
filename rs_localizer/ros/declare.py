"""Declaring the localizer's parameters on an rclpy node, with their descriptors (description,
range, read-only) from :data:`rs_localizer.ros.params.PARAMETERS`."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

from .params import FloatRange, Parameter

__all__ = ["declare_parameters"]


def declare_parameters(
    node: Any, parameters: Mapping[str, Parameter], dynamic: Collection[str] = ()
) -> None:
    """Declare every ``name -> (default, description, range, read_only, ...)`` (a
    :class:`~rs_localizer.ros.params.Parameter`) not declared yet on ``node`` (the value from
    the node's parameter overrides, else the default; one declared already is kept: a rig
    camera's at a configure retried after a value of it was refused declares the rest), in
    the mapping's order with the names of ``dynamic`` after the others. Those are declared
    of any type, not set (None) unless overridden (their default is the one the docs show):
    their value is checked by :func:`.config.build_config`, which names the parameter and the
    fix (``rig.cameras: front`` instead of ``[front]``, a mounting of integers).

    Raises:
        RuntimeError: a value of the wrong type or outside its range, naming the parameter
            (the node refuses to start, or a rig camera's to configure).
    """
    for name in sorted(parameters, key=lambda n: n in dynamic):  # (stable: the order kept)
        if node.has_parameter(name):
            continue
        default, desc, rng, ro = parameters[name][:4]
        if name in dynamic:
            d = ParameterDescriptor(description=desc, read_only=ro, dynamic_typing=True)
            node.declare_parameter(name, None, d)
            continue
        d = ParameterDescriptor(description=desc, read_only=ro)
        if isinstance(rng, FloatRange):
            d.floating_point_range = [
                FloatingPointRange(from_value=rng.from_value, to_value=rng.to_value, step=0.0)
            ]
        elif rng is not None:
            d.integer_range = [
                IntegerRange(from_value=rng.from_value, to_value=rng.to_value, step=rng.step)
            ]
        try:
            node.declare_parameter(name, default, d)
        except InvalidParameterValueException as e:
            raise RuntimeError(f"parameter {name!r}: {e} ({desc})") from None
        except InvalidParameterTypeException as e:
            kind = type(default).__name__
            raise RuntimeError(
                f"parameter {name!r} must be of type {kind}"
                + (" (write e.g. 0.0, not 0, in YAML)" if kind == "float" else "")
                + f": {e}"
            ) from None
