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
:func:`profile_in_effect` says which profile the process runs with, and why (the node logs it
at start): a profile file that is missing or not well-formed is not in effect, and neither is
the package's (applied only when the user chose none).
"""

from __future__ import annotations

import filecmp
import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "PROFILE_ENV",
    "PROFILE_PATH",
    "ProfileState",
    "apply_default_profile",
    "profile_in_effect",
]

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
    if _turned_off(env):
        return None
    rmw = env.get("RMW_IMPLEMENTATION", "")
    if rmw and not rmw.startswith("rmw_fastrtps"):
        return None
    if Path("DEFAULT_FASTRTPS_PROFILES.xml").exists() or not PROFILE_PATH.is_file():
        return None
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(PROFILE_PATH)
    return str(PROFILE_PATH)


#: the file Fast DDS loads from the working directory when no profile variable is set
CWD_PROFILE = "DEFAULT_FASTRTPS_PROFILES.xml"


def _turned_off(env: Mapping[str, str]) -> bool:
    return env.get("RS_LOCALIZER_DDS_PROFILE", "1").strip().lower() in ("0", "false", "no", "off")


@dataclass(frozen=True)
class ProfileState:
    """Which Fast DDS profile a process runs with (:func:`profile_in_effect`).

    Attributes:
        source: ``package`` (the shipped profile, set by :func:`apply_default_profile` or the
            launch file), ``user`` (the user's file), ``none`` (Fast DDS's built-in defaults)
            or ``other middleware`` (not Fast DDS: no Fast DDS profile applies).
        path: the profile file in effect, or the one that was asked for and is not; None.
        reason: why, for the user (names the variable and the file).
        ok: False when a profile was asked for (a variable or the working directory's file)
            and cannot be in effect (missing, unreadable, not well-formed, not a Fast DDS
            profile), or the package's profile is missing: neither it nor the package's is.
    """

    source: str
    path: str | None
    reason: str
    ok: bool = True

    def message(self) -> str:
        """One line for the node's log at start."""
        what = {
            "package": "the package's",
            "user": "the user's",
            "none": "none (Fast DDS's defaults)",
            "other middleware": "none (not Fast DDS)",
        }.get(self.source, self.source)
        line = f"DDS profile in effect: {what}" + (f" {self.path}" if self.ok and self.path else "")
        line += f": {self.reason}"
        if not self.ok:
            line += (
                "; images larger than 512 KB travel as fragmented UDP and a best-effort reader "
                "loses most frames (docs/node.md, Image input)"
            )
        return line


def _check_profile_file(path: Path) -> str | None:
    """None when ``path`` is a readable, well-formed Fast DDS XML profile file, else why not."""
    if not path.exists():
        return "no such file"
    if not path.is_file():
        return "not a regular file"
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        return f"not well-formed XML ({e})"
    except OSError as e:
        return f"cannot be read ({e.strerror or e})"
    tag = root.tag.rsplit("}", 1)[-1]
    if tag not in ("profiles", "dds"):
        return f"not a Fast DDS profile (root element <{tag}>, expected <profiles> or <dds>)"
    return None


def _is_shipped(path: Path) -> bool:
    """``path`` is the shipped profile or a copy of it (the installed one the launch file
    sets)."""
    try:
        return path.resolve() == PROFILE_PATH.resolve() or (
            PROFILE_PATH.is_file() and filecmp.cmp(path, PROFILE_PATH, shallow=False)
        )
    except OSError:
        return False


def profile_in_effect(
    environ: Mapping[str, str] | None = None, cwd: str | os.PathLike | None = None
) -> ProfileState:
    """Which Fast DDS profile a process started with ``environ`` (default ``os.environ``,
    after :func:`apply_default_profile`) in the working directory ``cwd`` (default the
    current one) runs with, and why: ``RMW_IMPLEMENTATION`` another middleware; a profile
    variable (:data:`PROFILE_ENV`, the first set) naming the shipped profile or a copy of it
    (the package's), or another file (the user's), checked to exist and to be a well-formed
    Fast DDS XML profile (else none is in effect: Fast DDS reports XML errors and runs with
    its defaults); the working directory's ``DEFAULT_FASTRTPS_PROFILES.xml``, checked the
    same way; the package's profile turned off (``RS_LOCALIZER_DDS_PROFILE=0``) or missing.

    Returns:
        :class:`ProfileState`. Reads the files named; never raises for them.
    """
    env = os.environ if environ is None else environ
    rmw = env.get("RMW_IMPLEMENTATION", "")
    if rmw and not rmw.startswith("rmw_fastrtps"):
        return ProfileState("other middleware", None, f"RMW_IMPLEMENTATION={rmw}")
    var = next((k for k in PROFILE_ENV if env.get(k)), None)
    if var is not None:
        path = Path(env[var])
        bad = _check_profile_file(path)
        if bad is not None:
            return ProfileState(
                "none",
                str(path),
                f"{var}={path}: {bad}; neither that profile nor the package's (applied only "
                f"when {var} is unset) is in effect: fix the file or unset {var}",
                ok=False,
            )
        if _is_shipped(path):
            return ProfileState("package", str(path), f"{var} names the package's profile")
        return ProfileState("user", str(path), f"from {var}")
    here = Path.cwd() if cwd is None else Path(cwd)
    local = here / CWD_PROFILE
    if local.exists():
        bad = _check_profile_file(local)
        if bad is not None:
            return ProfileState(
                "none",
                str(local),
                f"{CWD_PROFILE} in the working directory {here}: {bad}; neither it nor the "
                "package's (applied only without that file) is in effect: fix or remove it",
                ok=False,
            )
        return ProfileState("user", str(local), f"{CWD_PROFILE} in the working directory")
    if _turned_off(env):
        off = env.get("RS_LOCALIZER_DDS_PROFILE")
        return ProfileState(
            "none", None, f"the package's turned off (RS_LOCALIZER_DDS_PROFILE={off})"
        )
    if not PROFILE_PATH.is_file():
        missing = f"the package's profile is missing ({PROFILE_PATH})"
        return ProfileState("none", str(PROFILE_PATH), missing, ok=False)
    return ProfileState(
        "none",
        None,
        f"no profile variable set ({', '.join(PROFILE_ENV)}) and the package's not applied "
        "(rs_localizer.ros.dds_profile.apply_default_profile, before rclpy.init)",
        ok=False,
    )
