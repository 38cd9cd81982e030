"""``sensor_msgs/Image`` <-> numpy without cv_bridge (works with rclpy and rosbags messages)."""

from __future__ import annotations

import numpy as np

__all__ = ["image_from_msg", "image_fields", "ENCODINGS"]

#: supported encodings -> channels (8-bit)
ENCODINGS = {"mono8": 1, "8uc1": 1, "rgb8": 3, "bgr8": 3, "8uc3": 3, "rgba8": 4, "bgra8": 4,
             "8uc4": 4}


def image_from_msg(msg):
    """Decode an 8-bit ``sensor_msgs/Image``. Returns ``(array, encoding)``: (H, W) for mono8,
    (H, W, C) otherwise, encoding lower-cased (``rgb8``, ``bgr8``...: pass it on to the front
    end's ``process(..., encoding=...)``). Honours ``step`` (row padding).

    Raises:
        ValueError: unsupported encoding (e.g. 16-bit, Bayer) or truncated data.
    """
    enc = str(msg.encoding).lower()
    if enc not in ENCODINGS:
        raise ValueError(f"unsupported image encoding {msg.encoding!r}; "
                         f"supported: {sorted(ENCODINGS)}")
    ch = ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    buf = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data,
                        dtype=np.uint8)
    if step < w * ch or len(buf) < step * h:
        raise ValueError(f"image data too short: {len(buf)} bytes for {h} rows of step {step} "
                         f"({w} x {ch} bytes needed per row)")
    img = buf[:step * h].reshape(h, step)[:, :w * ch]
    img = img.reshape(h, w) if ch == 1 else img.reshape(h, w, ch)
    return np.ascontiguousarray(img), ("mono8" if ch == 1 and enc == "8uc1" else enc)


def image_fields(image: np.ndarray, encoding: str | None = None) -> dict:
    """Field values of a ``sensor_msgs/Image`` for an (H, W) or (H, W, 3) uint8 array:
    ``height, width, encoding, is_bigendian, step, data`` (data as a uint8 array)."""
    img = np.ascontiguousarray(image, dtype=np.uint8)
    if img.ndim == 2:
        enc = encoding or "mono8"
        ch = 1
    elif img.ndim == 3 and img.shape[2] in (3, 4):
        ch = img.shape[2]
        enc = encoding or ("rgb8" if ch == 3 else "rgba8")
    else:
        raise ValueError(f"expected (H, W) or (H, W, 3|4) uint8, got {img.shape}")
    return dict(height=img.shape[0], width=img.shape[1], encoding=enc, is_bigendian=0,
                step=img.shape[1] * ch, data=img.reshape(-1))
