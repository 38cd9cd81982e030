"""sensor_msgs/CompressedImage decoding (rs_localizer.frontends.image.image_from_compressed):
PNG is lossless (the decoded array must equal the original), JPEG is checked against an
independent decoder (Pillow), and bad payloads raise ValueError."""

import io
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from rs_localizer.frontends.image import compressed_fields, image_from_compressed

PIL = pytest.importorskip("PIL.Image")


def _img(shape, seed=0):
    rng = np.random.default_rng(seed)
    # smooth content + noise: realistic for JPEG, exact for PNG
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    base = 128 + 60 * np.sin(xx / 9.0) * np.cos(yy / 13.0)
    if len(shape) == 3:
        base = base[:, :, None] + np.arange(shape[2]) * 20.0
    return np.clip(base + rng.normal(0, 4, shape), 0, 255).astype(np.uint8)


def _msg(fmt, data):
    return SimpleNamespace(format=fmt, data=np.asarray(data, np.uint8).reshape(-1))


@pytest.mark.parametrize("shape, enc", [((48, 64), "mono8"), ((48, 64, 3), "bgr8")])
def test_png_roundtrip_is_exact(shape, enc):
    img = _img(shape)
    f = compressed_fields(img, "png")
    assert f["format"] == f"{enc}; png compressed {enc}"
    out, got_enc = image_from_compressed(SimpleNamespace(**f))
    assert got_enc == enc and out.dtype == np.uint8
    np.testing.assert_array_equal(out, img)


def test_png_with_alpha_written_by_pillow():
    rgba = _img((30, 40, 4), seed=3)
    buf = io.BytesIO()
    PIL.fromarray(rgba, "RGBA").save(buf, format="PNG")
    out, enc = image_from_compressed(_msg("png", np.frombuffer(buf.getvalue(), np.uint8)))
    assert enc == "bgra8"
    np.testing.assert_array_equal(out, rgba[:, :, [2, 1, 0, 3]])


@pytest.mark.parametrize("shape", [(60, 80), (60, 80, 3)])
@pytest.mark.parametrize("fmt", ["jpeg", "rgb8; jpeg compressed bgr8", "JPG", ""])
def test_jpeg_matches_pillow(shape, fmt):
    img = _img(shape, seed=1)
    f = compressed_fields(img, "jpeg", quality=90)
    out, enc = image_from_compressed(_msg(fmt, f["data"]))
    ref = np.asarray(PIL.open(io.BytesIO(bytes(f["data"]))))
    if ref.ndim == 3:
        ref = ref[:, :, ::-1]  # Pillow gives RGB, we give OpenCV's BGR
    assert enc == ("mono8" if len(shape) == 2 else "bgr8")
    assert out.shape == img.shape
    # two IDCT implementations: a gray level or two apart at most
    assert np.abs(out.astype(int) - ref.astype(int)).max() <= 3
    assert np.abs(out.astype(float) - img).mean() < 4.0  # and close to the original


def test_jpeg_written_by_pillow():
    rgb = _img((50, 70, 3), seed=2)
    buf = io.BytesIO()
    PIL.fromarray(rgb, "RGB").save(buf, format="JPEG", quality=95)
    out, enc = image_from_compressed(_msg("jpeg", np.frombuffer(buf.getvalue(), np.uint8)))
    assert enc == "bgr8"
    assert np.abs(out[:, :, ::-1].astype(float) - rgb).mean() < 4.0


def _bad_payloads():
    img = _img((40, 50))
    jpg = compressed_fields(img, "jpeg")["data"]
    png = compressed_fields(img, "png")["data"]
    flipped = png.copy()
    flipped[len(png) // 2] ^= 0xFF
    png16 = cv2.imencode(".png", img.astype(np.uint16) * 200)[1].reshape(-1)
    return {
        "empty": ("jpeg", np.zeros(0, np.uint8)),
        "garbage": ("jpeg", np.arange(200, dtype=np.uint8)),
        "truncated_jpeg": ("jpeg", jpg[: len(jpg) // 2]),
        "truncated_png": ("png", png[: len(png) // 2]),
        "corrupt_png": ("png", flipped),
        "png_said_jpeg": ("jpeg", png),
        "png16": ("png", png16),
        "compressed_depth": ("16UC1; compressedDepth png", png),
        "h264": ("h264", jpg),
    }


@pytest.mark.parametrize("name", list(_bad_payloads()))
def test_bad_payloads_raise(name):
    fmt, data = _bad_payloads()[name]
    with pytest.raises(ValueError):
        image_from_compressed(_msg(fmt, data))


def test_compressed_fields_rejects_unknown_kind():
    with pytest.raises(ValueError):
        compressed_fields(np.zeros((4, 4), np.uint8), "webp")
