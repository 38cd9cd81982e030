"""One converter of a status ``(level, message, values)`` into a
``diagnostic_msgs/DiagnosticStatus``, shared by the localizer node and the rig mode."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from .diagnostics import ERROR, OK, WARN

__all__ = ["LEVEL_NAMES", "status_message"]

#: level names -> the levels of :mod:`.diagnostics` (those of ``DiagnosticStatus``)
LEVEL_NAMES = {"OK": OK, "WARN": WARN, "ERROR": ERROR}
_BYTES = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN, ERROR: DiagnosticStatus.ERROR}


def status_message(
    name: str, hardware_id: str, level: int | str, message: str, values: Mapping[str, Any]
) -> DiagnosticStatus:
    """The ``DiagnosticStatus`` of a status: ``level`` one of :data:`.diagnostics.OK`, ``WARN``,
    ``ERROR`` (0, 1, 2) or their names (:data:`LEVEL_NAMES`); ``values`` in their order, each
    value as ``str(value)``.

    Raises:
        ValueError: an unknown level.
    """
    lv = LEVEL_NAMES.get(level, level) if isinstance(level, str) else level
    if lv not in _BYTES:
        raise ValueError(f"unknown diagnostic level {level!r}; expected one of {list(LEVEL_NAMES)}")
    st = DiagnosticStatus()
    st.name, st.hardware_id = str(name), str(hardware_id)
    st.level, st.message = _BYTES[lv], str(message)
    st.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    return st
