"""The node's ROS 2 parameter files, read without ROS: the values they give the node, for
``rs-localizer replay``, ``compile`` and the rig bags (the node gets them from ROS).

:func:`read_params_file` reads the sections of a file that apply to the node;
:func:`parameter_values` gives every parameter's value from its default, the files and
overrides, each checked against :data:`.params.PARAMETERS`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .params import OTHER_NODE_PARAMETERS, PARAMETERS, ConfigError, check_parameter, default_values

__all__ = ["checked_value", "parameter_values", "read_params_file"]


def _flatten(tree: Mapping, prefix: str = "") -> dict[str, Any]:
    out = {}
    for k, v in tree.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


def _section_applies(section: str, node_name: str) -> bool:
    """Whether a parameter-file section applies to a node named ``node_name`` outside any
    namespace: the wildcards (``/**``, ``/*``) and the node's own name (``rs_localizer``,
    ``/rs_localizer``, ``/**/rs_localizer``)."""
    s = str(section).strip()
    return s in ("/**", "**", "/*", "*") or s.lstrip("/") in (node_name, f"**/{node_name}")


def read_params_file(path: str | os.PathLike, node_name: str = "rs_localizer") -> dict[str, Any]:
    """The parameters a ROS 2 parameter file gives a node named ``node_name`` (no namespace):
    its sections ``/**`` and ``rs_localizer`` (also ``/rs_localizer``, ``/**/rs_localizer``) in
    file order, each ``ros__parameters`` tree flattened to dotted names (``ransac:
    {seed: 3}`` -> ``ransac.seed``). Sections of other nodes or namespaces
    (``/camera/rs_localizer``) are not read. Values are as YAML parses them (checked later,
    against :data:`PARAMETERS`, by :func:`check_parameter`).

    Raises:
        ConfigError: the file is not a ROS 2 parameter file (YAML mapping of node name ->
            ``ros__parameters`` mapping). OSError: the file cannot be read.
    """
    import yaml

    try:
        tree = yaml.safe_load(Path(path).read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not YAML: {e}") from None
    if not isinstance(tree, Mapping):
        raise ConfigError(f"{path}: not a ROS 2 parameter file (node name: ros__parameters: ...)")
    out: dict[str, Any] = {}
    for section, body in tree.items():
        if not isinstance(body, Mapping) or not isinstance(body.get("ros__parameters"), Mapping):
            raise ConfigError(f"{path}: section {section!r} has no ros__parameters mapping")
        if _section_applies(section, node_name):
            out.update(_flatten(body["ros__parameters"]))
    return out


def checked_value(name: str, value: Any) -> Any:
    """A parameter file's or an override's ``value`` of the node parameter ``name``, as the
    camera's and the rig's readers take it: a string parameter written with no value (YAML
    null, ``base_frame:``) is the empty string, then the value is checked against the
    parameter's type and range (:func:`~.params.check_parameter`).

    Raises:
        ConfigError: unknown parameter, wrong type, or outside the declared range (naming
            the parameter).
    """
    if value is None and name in PARAMETERS and isinstance(PARAMETERS[name].default, str):
        value = ""
    check_parameter(name, value)
    return value


def parameter_values(
    files: Iterable[str | os.PathLike] = (), overrides: Mapping[str, Any] | None = None
) -> tuple[dict[str, Any], list[str]]:
    """Every parameter's value from its default, then each parameter file in order
    (:func:`read_params_file`), then ``overrides``, each value checked
    (:func:`checked_value`). Returns ``(values, ignored)``: ``ignored`` lists file entries
    that are not localizer parameters (``viz.*``, ``qos_overrides.*`` and ``cameras`` belong
    to the node but not to the estimation; other names are unknown to the node, which ignores
    them too).

    Raises:
        ConfigError: a file that is not a parameter file, an unknown override, or a value of
            the wrong type or outside its range. OSError: a file cannot be read.
    """
    values = default_values()
    ignored = []
    for f in files:
        for name, value in read_params_file(f).items():
            if name not in PARAMETERS:
                if not name.startswith(OTHER_NODE_PARAMETERS):
                    ignored.append(name)
                continue
            values[name] = checked_value(name, value)
    for name, value in (overrides or {}).items():
        values[name] = checked_value(name, value)
    return values, ignored
