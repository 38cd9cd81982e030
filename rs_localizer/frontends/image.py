"""``sensor_msgs/Image`` <-> numpy without cv_bridge (works with rclpy and rosbags messages), and
``sensor_msgs/CompressedImage`` (JPEG, PNG) -> numpy with OpenCV, and the grayscale image the
front ends detect in (:func:`to_gray`)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "COMPRESSED_FORMATS",
    "ENCODINGS",
    "MIN_IMAGE_SIDE",
    "check_image_size",
    "compressed_fields",
    "image_fields",
    "image_from_compressed",
    "image_from_msg",
    "to_gray",
]

#: supported encodings -> channels (8-bit)
ENCODINGS = {
    "mono8": 1,
    "8uc1": 1,
    "rgb8": 3,
    "bgr8": 3,
    "8uc3": 3,
    "rgba8": 4,
    "bgra8": 4,
    "8uc4": 4,
}


#: px: the smallest image width and height the front ends take. The AprilTag 3 library
#: (pupil_apriltags 1.0.4) ends the process (SIGFPE, SIGSEGV) on images whose side is 2-3 px
#: or less after its decimation (0x0-5x5, 640x1, 1x640 and 4x640 at ``quad_decimate`` 1.5);
#: OpenCV raises on empty images and on ``cornerSubPix`` windows larger than the image. No
#: marker, board or feature map is localized from fewer pixels than this.
MIN_IMAGE_SIDE = 16


def check_image_size(shape: tuple, min_side: int = MIN_IMAGE_SIDE, what: str = "image") -> None:
    """Refuse an image of ``shape`` (H, W, ...) whose width or height is below ``min_side``
    px (default :data:`MIN_IMAGE_SIDE`).

    Raises:
        ValueError: a side below ``min_side`` (naming the size and the minimum), or fewer
            than two dimensions.
    """
    if len(shape) < 2:
        raise ValueError(f"{what} has shape {tuple(shape)}, expected (H, W) or (H, W, C)")
    h, w = int(shape[0]), int(shape[1])
    if min(h, w) < min_side:
        raise ValueError(
            f"{what} is {w}x{h} px, smaller than the {min_side}x{min_side} px the front ends take"
        )


def image_from_msg(msg: Any) -> tuple[np.ndarray, str]:
    """Decode an 8-bit ``sensor_msgs/Image``. Returns ``(array, encoding)``: (H, W) for mono8,
    (H, W, C) otherwise, encoding lower-cased (``rgb8``, ``bgr8``...: pass it on to the front
    end's ``process(..., encoding=...)``). Honours ``step`` (row padding).

    Raises:
        ValueError: unsupported encoding (e.g. 16-bit, Bayer) or truncated data.
    """
    enc = str(msg.encoding).lower()
    if enc not in ENCODINGS:
        raise ValueError(
            f"unsupported image encoding {msg.encoding!r}; supported: {sorted(ENCODINGS)}"
        )
    ch = ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    buf = np.frombuffer(
        bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data, dtype=np.uint8
    )
    if step < w * ch or len(buf) < step * h:
        raise ValueError(
            f"image data too short: {len(buf)} bytes for {h} rows of step {step} "
            f"({w} x {ch} bytes needed per row)"
        )
    img = buf[: step * h].reshape(h, step)[:, : w * ch]
    img = img.reshape(h, w) if ch == 1 else img.reshape(h, w, ch)
    return np.ascontiguousarray(img), ("mono8" if ch == 1 and enc == "8uc1" else enc)


#: payload formats :func:`image_from_compressed` decodes (the ``format`` field names one of them)
COMPRESSED_FORMATS = ("jpeg", "png")
_CHANNELS_TO_ENCODING = {1: "mono8", 3: "bgr8", 4: "bgra8"}


def _compressed_kind(fmt: str) -> str | None:
    """``jpeg``/``png`` from a CompressedImage ``format``: ``jpeg``, ``png``, ``jpg`` or
    image_transport's ``"<encoding>; jpeg compressed bgr8"``; ``None`` when it names neither
    (e.g. ``compressedDepth``, ``h264``, ``tiff``); empty = not stated."""
    f = fmt.strip().lower()
    if not f:
        return ""
    if "compresseddepth" in f.replace(" ", ""):
        return None
    words = f.replace(";", " ").split()
    if "jpeg" in words or "jpg" in words:
        return "jpeg"
    if "png" in words:
        return "png"
    return None


def _payload_kind(buf: np.ndarray) -> str | None:
    if len(buf) >= 3 and buf[0] == 0xFF and buf[1] == 0xD8 and buf[2] == 0xFF:
        return "jpeg"
    if len(buf) >= 8 and bytes(buf[:8]) == b"\x89PNG\r\n\x1a\n":
        return "png"
    return None


def image_from_compressed(msg: Any) -> tuple[np.ndarray, str]:
    """Decode a ``sensor_msgs/CompressedImage`` (JPEG or PNG, 8-bit) with ``cv2.imdecode``.

    ``msg.format`` is ``jpeg``/``png`` or image_transport's ``"rgb8; jpeg compressed bgr8"``
    (empty: taken from the payload). Returns ``(array, encoding)`` like :func:`image_from_msg`:
    (H, W) ``mono8`` for a gray payload, (H, W, 3) ``bgr8`` or (H, W, 4) ``bgra8`` (OpenCV's
    channel order) otherwise.

    Raises:
        ValueError: a format other than JPEG/PNG (``compressedDepth``, ``h264``, ...), a payload
            that is not what the format says, does not decode (truncated, corrupt, empty) or is
            not 8-bit (16-bit PNG).
    """
    import cv2

    kind = _compressed_kind(str(msg.format))
    if kind is None:
        raise ValueError(
            f"unsupported compressed image format {msg.format!r}; supported: "
            f"{', '.join(COMPRESSED_FORMATS)}"
        )
    buf = np.frombuffer(
        bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data, dtype=np.uint8
    )
    if len(buf) == 0:
        raise ValueError("empty compressed image")
    actual = _payload_kind(buf)
    if actual is None or (kind and actual != kind):
        raise ValueError(
            f"payload is not a {kind or 'JPEG/PNG'} image (format {msg.format!r}, "
            f"{len(buf)} bytes starting {bytes(buf[:4]).hex()})"
        )
    if actual == "jpeg" and b"\xff\xd9" not in bytes(buf[-32:]):
        # (some libjpeg builds decode a cut-off JPEG into a gray-filled image with a warning)
        raise ValueError(f"truncated JPEG ({len(buf)} bytes, no end-of-image marker)")
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ValueError(f"{actual} payload of {len(buf)} bytes does not decode")
    if img.dtype != np.uint8:
        raise ValueError(f"{actual} image is {img.dtype}, only 8-bit images are supported")
    ch = 1 if img.ndim == 2 else img.shape[2]
    if ch == 1 and img.ndim == 3:
        img = img[:, :, 0]
    if ch not in _CHANNELS_TO_ENCODING:
        raise ValueError(f"{actual} image with {ch} channels is not supported")
    return np.ascontiguousarray(img), _CHANNELS_TO_ENCODING[ch]


def compressed_fields(
    image: np.ndarray, kind: str = "jpeg", quality: int = 95, encoding: str | None = None
) -> dict:
    """Field values ``format, data`` of a ``sensor_msgs/CompressedImage`` for an (H, W) or
    (H, W, 3) uint8 array (BGR channel order, as OpenCV writes it) compressed with
    ``cv2.imencode``; ``format`` in image_transport's form ``"<encoding>; jpeg compressed
    bgr8"``.

    Raises:
        ValueError: ``kind`` not jpeg/png or an array OpenCV cannot encode.
    """
    import cv2

    if kind not in COMPRESSED_FORMATS:
        raise ValueError(f"kind must be one of {COMPRESSED_FORMATS}, got {kind!r}")
    img = np.ascontiguousarray(image, dtype=np.uint8)
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if kind == "jpeg" else []
    ok, data = cv2.imencode(".jpg" if kind == "jpeg" else ".png", img, params)
    if not ok:
        raise ValueError(f"cv2.imencode failed for an array of shape {img.shape}")
    packed = "mono8" if img.ndim == 2 else "bgr8"
    return dict(format=f"{encoding or packed}; {kind} compressed {packed}", data=data.reshape(-1))


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
    return dict(
        height=img.shape[0],
        width=img.shape[1],
        encoding=enc,
        is_bigendian=0,
        step=img.shape[1] * ch,
        data=img.reshape(-1),
    )


def to_gray(image: np.ndarray, encoding: str = "rgb8") -> np.ndarray:
    """(H, W) uint8 grayscale from mono8 / rgb8 / bgr8 / rgba8 / bgra8 arrays (``encoding``
    tells RGB from BGR order for 3 and 4 channels; (H, W) and (H, W, 1) are taken as they are).

    Raises:
        ValueError: an array that is not (H, W), (H, W, 1), (H, W, 3) or (H, W, 4).
    """
    img = np.asarray(image)
    if img.ndim == 2:
        return np.ascontiguousarray(img, dtype=np.uint8)
    if img.ndim == 3 and img.shape[2] == 1:
        return np.ascontiguousarray(img[:, :, 0], dtype=np.uint8)
    enc = encoding.lower()
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"expected an (H, W), (H, W, 3) or (H, W, 4) image, got {img.shape}")
    import cv2  # (as image_from_compressed: the message codecs import without OpenCV)

    code = {
        ("bgr", 3): cv2.COLOR_BGR2GRAY,
        ("bgr", 4): cv2.COLOR_BGRA2GRAY,
        ("rgb", 3): cv2.COLOR_RGB2GRAY,
        ("rgb", 4): cv2.COLOR_RGBA2GRAY,
    }
    kind = "bgr" if enc.startswith("bgr") else "rgb"
    return cv2.cvtColor(np.ascontiguousarray(img, dtype=np.uint8), code[(kind, img.shape[2])])
