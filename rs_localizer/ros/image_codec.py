"""The ROS image messages <-> numpy, without cv_bridge (rclpy and rosbags messages alike):
``sensor_msgs/Image`` (8-bit encodings, :data:`ENCODINGS`) and ``sensor_msgs/CompressedImage``
(JPEG, PNG, decoded with OpenCV) read by the one decoder, :func:`decode_image`, which also
checks the image's size against the camera and the front ends' smallest image
(:data:`~rs_localizer.frontends.image.MIN_IMAGE_SIDE`) under the node's documented reasons
(:class:`ImageRejected`); and the field values of the messages written
(:func:`image_fields`, :func:`compressed_fields`: bags, render-bag, the debug image).

The camera node's pipeline, the rig node, replay, the bag readers and the command-line tools
decode through :func:`decode_image`. Nothing here imports rclpy or a message package: the
message is read by its fields."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..frontends.image import MIN_IMAGE_SIDE, check_image_size

__all__ = [
    "COMPRESSED_FORMATS",
    "ENCODINGS",
    "ImageRejected",
    "compressed_fields",
    "decode_image",
    "image_fields",
]

#: supported ``sensor_msgs/Image`` encodings -> channels (8-bit)
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

#: payload formats of a ``CompressedImage`` :func:`decode_image` decodes (the ``format`` field
#: names one of them)
COMPRESSED_FORMATS = ("jpeg", "png")
_CHANNELS_TO_ENCODING = {1: "mono8", 3: "bgr8", 4: "bgra8"}


class ImageRejected(ValueError):
    """An image message :func:`decode_image` refuses; ``reason`` is the node's counter:
    ``bad_image`` (does not decode, unsupported, empty or smaller than the front ends take) or
    ``image_size_mismatch`` (another size than the camera model's); the message says why."""

    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason


def decode_image(
    msg: Any, camera: Any = None, *, min_side: int = MIN_IMAGE_SIDE
) -> tuple[np.ndarray, str]:
    """The pixels of a ``sensor_msgs/Image`` or ``CompressedImage`` (told apart by the
    ``encoding`` field, which only ``Image`` has), checked before a front end sees them.

    Returns ``(array, encoding)``: (H, W) ``mono8``, or (H, W, C) uint8 with the encoding
    lower-cased (``rgb8``, ``bgr8``, ``rgba8``...; a compressed colour payload is ``bgr8`` or
    ``bgra8``, OpenCV's channel order): pass it on to the front end's
    ``process(..., encoding=...)``. A raw image honours ``step`` (row padding).

    Args:
        msg: an ``Image`` (fields ``height, width, encoding, step, data``) or a
            ``CompressedImage`` (``format, data``; ``format`` is ``jpeg``/``png``, image_transport's
            ``"rgb8; jpeg compressed bgr8"`` or empty: taken from the payload).
        camera: the camera model of the frame (``width``, ``height`` in px; None or a size of 0:
            not checked). A raw image of another size is refused before it is decoded.
        min_side: px, the smallest width and height taken (default: the front ends' smallest
            image; 0: any size but an empty image, e.g. to export an image).

    Raises:
        ImageRejected: ``bad_image``: an unsupported encoding (16-bit, Bayer, ...), truncated
            data, an empty image, a compressed format other than JPEG/PNG (``compressedDepth``,
            ``h264``), a payload that is not what the format says, does not decode or is not
            8-bit, a side below ``min_side``; ``image_size_mismatch``: another size than
            ``camera``'s.
    """
    if not hasattr(msg, "encoding"):
        img, enc = _bad_image(_decode_compressed, msg)
        h, w = img.shape[:2]
    else:
        h, w = int(msg.height), int(msg.width)
        if h * w == 0:
            raise ImageRejected("bad_image", f"empty image ({w}x{h})")
        _check_side(h, w, min_side)  # (before decoding: no copy of an image refused anyway)
        _check_camera(h, w, camera)
        img, enc = _bad_image(_decode_raw, msg)
    _check_camera(h, w, camera)
    _check_side(h, w, min_side)
    return img, enc


def _bad_image(decode, msg) -> tuple[np.ndarray, str]:
    try:
        return decode(msg)
    except ValueError as e:
        raise ImageRejected("bad_image", str(e)) from None


def _check_side(h: int, w: int, min_side: int) -> None:
    if min_side > 0:
        try:
            check_image_size((h, w), min_side)
        except ValueError as e:
            raise ImageRejected("bad_image", str(e)) from None


def _check_camera(h: int, w: int, camera: Any) -> None:
    if camera is None or camera.width <= 0 or camera.height <= 0:
        return
    if (w, h) != (camera.width, camera.height):
        raise ImageRejected(
            "image_size_mismatch",
            f"image is {w}x{h}, the camera model {camera.width}x{camera.height}",
        )


def _bytes_view(data: Any) -> np.ndarray:
    """A message's ``data`` as a flat uint8 array, without a copy where it can be a view:
    rclpy's ``array.array('B')``, ``bytes``, ``memoryview`` and a rosbags uint8 array are
    viewed, the decoded image then sharing the message's memory (a 640x480 RGB frame is
    0.9 MB, copied per frame otherwise); a list of ints is converted."""
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except TypeError:  # (no buffer: a sequence of ints)
        return np.frombuffer(bytes(data), dtype=np.uint8)


def _decode_raw(msg: Any) -> tuple[np.ndarray, str]:
    """An 8-bit ``sensor_msgs/Image``: ``(array, encoding)`` (``8uc1`` is ``mono8``).

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
    buf = _bytes_view(msg.data)
    if step < w * ch or len(buf) < step * h:
        raise ValueError(
            f"image data too short: {len(buf)} bytes for {h} rows of step {step} "
            f"({w} x {ch} bytes needed per row)"
        )
    img = buf[: step * h].reshape(h, step)[:, : w * ch]
    img = img.reshape(h, w) if ch == 1 else img.reshape(h, w, ch)
    return np.ascontiguousarray(img), ("mono8" if ch == 1 and enc == "8uc1" else enc)


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
    """``jpeg``/``png`` from a payload's first bytes (its signature); None: neither."""
    if len(buf) >= 3 and buf[0] == 0xFF and buf[1] == 0xD8 and buf[2] == 0xFF:
        return "jpeg"
    if len(buf) >= 8 and bytes(buf[:8]) == b"\x89PNG\r\n\x1a\n":
        return "png"
    return None


def _decode_compressed(msg: Any) -> tuple[np.ndarray, str]:
    """A ``sensor_msgs/CompressedImage`` (JPEG or PNG, 8-bit) with ``cv2.imdecode``:
    ``(array, encoding)``, (H, W) ``mono8`` for a gray payload, (H, W, 3) ``bgr8`` or
    (H, W, 4) ``bgra8`` otherwise.

    Raises:
        ValueError: a format other than JPEG/PNG, a payload that is not what the format says,
            does not decode (truncated, corrupt, empty) or is not 8-bit (16-bit PNG).
    """
    import cv2

    kind = _compressed_kind(str(msg.format))
    if kind is None:
        raise ValueError(
            f"unsupported compressed image format {msg.format!r}; supported: "
            f"{', '.join(COMPRESSED_FORMATS)}"
        )
    buf = _bytes_view(msg.data)
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
    """Field values of a ``sensor_msgs/Image`` for an (H, W), (H, W, 3) or (H, W, 4) uint8
    array: ``height, width, encoding, is_bigendian, step, data`` (no row padding; data as a
    uint8 array; ``encoding`` default ``mono8``, ``rgb8`` or ``rgba8`` by the channels).

    Raises:
        ValueError: an array of another shape.
    """
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
