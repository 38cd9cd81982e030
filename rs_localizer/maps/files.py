"""Writing map files whole or not at all, with the user's umask mode, and opening map files
without blocking on a FIFO or a device: what every map reader and writer of
:mod:`rs_localizer.maps` shares."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path
from typing import IO

__all__ = ["check_regular_file", "file_mode", "open_regular_file", "write_text_atomic"]


def write_text_atomic(path: str | os.PathLike, text: str, overwrite: bool = False) -> Path:
    """Write ``text`` to ``path`` whole or not at all: a temporary file in the same directory,
    then an atomic rename (``os.replace``); on any error (Ctrl-C included) the temporary file
    is removed and ``path`` is untouched. The file gets the user's umask mode
    (:func:`file_mode`), as a plain ``open`` would. The parent directory is created.

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False.
        OSError: the directory cannot be written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (use --overwrite to replace it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, file_mode())  # (mkstemp's 0600 -> the umask's: readable by others)
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def file_mode() -> int:
    """The mode a new file gets from the user's umask (``0o666 & ~umask``): maps written
    through a temporary file (``mkstemp``: 0600) are given it, so that a node running as
    another user can read them."""
    try:  # (Linux: read it without changing it)
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def check_regular_file(path: str | os.PathLike) -> None:
    """Raise ValueError unless ``path`` is a regular file (``os.stat``, which does not block on
    a FIFO or a device the way ``open`` does); OSError (FileNotFoundError...) if it cannot be
    stat'ed."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{path}: not a regular file")


def open_regular_file(path: str | os.PathLike, mode: str = "r") -> IO:
    """``open(path, mode)`` (read-only modes) that never blocks on a FIFO or a device: the file
    is opened non-blocking and checked to be a regular file (``fstat``, so it cannot be swapped
    between check and open). Raises ValueError for anything else, OSError as ``open``."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ValueError(f"{path}: not a regular file")
        os.set_blocking(fd, True)
        return os.fdopen(fd, mode)
    except BaseException:
        os.close(fd)
        raise
