"""The Fast DDS profile shipped with the package, and when it is applied.

Fast DDS (``rmw_fastrtps_cpp``, the default middleware of ROS 2 Jazzy) puts samples into a
shared-memory segment of 512 KB per participant by default. A camera image is larger (640x480
rgb8: 921,600 bytes; 1280x720 rgb8: 2,764,800 bytes), so it travels as fragmented UDP on the
loopback instead, and a best-effort reader (the sensor-data QoS of camera drivers and of the
node's image input) loses the whole sample when any fragment is lost: at 30 Hz most frames.
``fastdds_profile.xml`` (next to this module; installed to ``share/rs_localizer/config``) gives
every participant a 16 MB segment, which carries every frame at 30 Hz up to 1280x720 RGB
(docs/node.md "Image input", measured there). Only the sending process's segment matters: a
driver must run with the profile as well.

This module does not import rclpy: :func:`apply_default_profile` must run before ``rclpy.init``.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

__all__ = ["PROFILE_ENV", "PROFILE_PATH", "apply_default_profile"]

#: the shipped profile
PROFILE_PATH = Path(__file__).with_name("fastdds_profile.xml")
#: the environment variables Fast DDS reads its XML profile file from (older and newer name)
PROFILE_ENV = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def apply_default_profile(environ: MutableMapping[str, str] | None = None) -> str | None:
    """Point Fast DDS at the shipped profile unless the user chose a configuration.

    Sets ``FASTRTPS_DEFAULT_PROFILES_FILE`` in ``environ`` (default ``os.environ``, read by
    Fast DDS when the first participant is created, i.e. at ``rclpy.init``/node creation)
    when: neither profile variable is set, ``RMW_IMPLEMENTATION`` is unset or a Fast DDS one,
    ``RS_LOCALIZER_DDS_PROFILE`` is not ``0``, there is no ``DEFAULT_FASTRTPS_PROFILES.xml``
    in the working directory (which Fast DDS would load), and the shipped file exists.

    Returns:
        The path set, or None when nothing was changed.
    """
    env = os.environ if environ is None else environ
    if any(env.get(k) for k in PROFILE_ENV):
        return None
    if env.get("RS_LOCALIZER_DDS_PROFILE", "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    rmw = env.get("RMW_IMPLEMENTATION", "")
    if rmw and not rmw.startswith("rmw_fastrtps"):
        return None
    if Path("DEFAULT_FASTRTPS_PROFILES.xml").exists() or not PROFILE_PATH.is_file():
        return None
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(PROFILE_PATH)
    return str(PROFILE_PATH)
