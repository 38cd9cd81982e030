"""What the front ends take of a numpy image: its smallest size (:data:`MIN_IMAGE_SIDE`,
:func:`check_image_size`) and the grayscale image they detect in (:func:`to_gray`). The ROS
image messages are decoded into such arrays in :mod:`rs_localizer.ros.image_codec`."""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_IMAGE_SIDE", "check_image_size", "to_gray"]


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
    import cv2  # (imported on use: the module imports without OpenCV)

    code = {
        ("bgr", 3): cv2.COLOR_BGR2GRAY,
        ("bgr", 4): cv2.COLOR_BGRA2GRAY,
        ("rgb", 3): cv2.COLOR_RGB2GRAY,
        ("rgb", 4): cv2.COLOR_RGBA2GRAY,
    }
    kind = "bgr" if enc.startswith("bgr") else "rgb"
    return cv2.cvtColor(np.ascontiguousarray(img, dtype=np.uint8), code[(kind, img.shape[2])])
