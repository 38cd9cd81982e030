"""The ROS image codec (rs_localizer.ros.image_codec): ``sensor_msgs/Image`` and
``CompressedImage`` through the one decoder, ``decode_image``. Raw images must give back the
array they were written from (row padding honoured); PNG is lossless (the decoded array must
equal the original), JPEG is checked against an independent decoder (Pillow); bad payloads,
unsupported encodings, images of another size than the camera and images smaller than the
front ends take are refused under the node's reasons. The single-camera node's pipeline and
the rig node decode a message through it to the same array, and refuse one for the same
reason."""

import io
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from rs_localizer.camera import CameraModel
from rs_localizer.frontends.image import MIN_IMAGE_SIDE
from rs_localizer.ros.image_codec import (
    ENCODINGS,
    ImageRejected,
    compressed_fields,
    decode_image,
    image_fields,
)

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
    out, got_enc = decode_image(SimpleNamespace(**f))
    assert got_enc == enc and out.dtype == np.uint8
    np.testing.assert_array_equal(out, img)


def test_png_with_alpha_written_by_pillow():
    rgba = _img((30, 40, 4), seed=3)
    buf = io.BytesIO()
    PIL.fromarray(rgba, "RGBA").save(buf, format="PNG")
    out, enc = decode_image(_msg("png", np.frombuffer(buf.getvalue(), np.uint8)))
    assert enc == "bgra8"
    np.testing.assert_array_equal(out, rgba[:, :, [2, 1, 0, 3]])


@pytest.mark.parametrize("shape", [(60, 80), (60, 80, 3)])
@pytest.mark.parametrize("fmt", ["jpeg", "rgb8; jpeg compressed bgr8", "JPG", ""])
def test_jpeg_matches_pillow(shape, fmt):
    img = _img(shape, seed=1)
    f = compressed_fields(img, "jpeg", quality=90)
    out, enc = decode_image(_msg(fmt, f["data"]))
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
    out, enc = decode_image(_msg("jpeg", np.frombuffer(buf.getvalue(), np.uint8)))
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
    with pytest.raises(ImageRejected) as e:
        decode_image(_msg(fmt, data))
    assert e.value.reason == "bad_image"


def test_compressed_fields_rejects_unknown_kind():
    with pytest.raises(ValueError):
        compressed_fields(np.zeros((4, 4), np.uint8), "webp")


# ------------------------------------------------------------------------------ raw images
def test_image_message_roundtrip():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (6, 5, 3), dtype=np.uint8)
    out, enc = decode_image(SimpleNamespace(**image_fields(rgb)), min_side=0)
    np.testing.assert_array_equal(out, rgb)
    assert enc == "rgb8"
    # padded rows (step > width * channels), mono8
    mono = rng.integers(0, 255, (4, 3), dtype=np.uint8)
    padded = np.zeros((4, 8), np.uint8)
    padded[:, :3] = mono
    msg = SimpleNamespace(
        height=4, width=3, encoding="mono8", is_bigendian=0, step=8, data=padded.tobytes()
    )
    np.testing.assert_array_equal(decode_image(msg, min_side=0)[0], mono)
    for bad in (
        SimpleNamespace(height=4, width=3, encoding="16UC1", step=6, data=b""),
        SimpleNamespace(height=4, width=3, encoding="rgb8", step=9, data=b"12"),
    ):
        with pytest.raises(ImageRejected) as e:
            decode_image(bad, min_side=0)
        assert e.value.reason == "bad_image"


@pytest.mark.parametrize("enc", sorted(ENCODINGS))
def test_every_encoding_gives_back_its_pixels(enc):
    ch = ENCODINGS[enc]
    rng = np.random.default_rng(len(enc))
    img = rng.integers(0, 256, (20, 24) if ch == 1 else (20, 24, ch), dtype=np.uint8)
    out, got = decode_image(SimpleNamespace(**image_fields(img, enc.upper())))
    np.testing.assert_array_equal(out, img)
    assert got == ("mono8" if enc == "8uc1" else enc)


def test_sizes_refused_under_the_node_reasons():
    """Empty, below ``MIN_IMAGE_SIDE`` (raw: before decoding), another size than the camera:
    ``bad_image``, ``bad_image``, ``image_size_mismatch``; ``min_side=0`` takes any non-empty
    size; a camera of unknown size (0) checks nothing."""
    k = MIN_IMAGE_SIDE
    cam = _camera(40, 30)
    tiny = SimpleNamespace(**image_fields(np.zeros((k - 1, 40), np.uint8)))
    for camera in (None, cam):
        with pytest.raises(ImageRejected) as e:
            decode_image(tiny, camera)
        assert e.value.reason == "bad_image" and f"{k}x{k}" in str(e.value)
    assert decode_image(tiny, min_side=0)[0].shape == (k - 1, 40)
    empty = SimpleNamespace(height=0, width=40, encoding="mono8", step=40, data=b"")
    with pytest.raises(ImageRejected, match="empty image"):
        decode_image(empty, min_side=0)
    other = SimpleNamespace(**image_fields(np.zeros((30, 41), np.uint8)))
    with pytest.raises(ImageRejected) as e:
        decode_image(other, cam)
    assert e.value.reason == "image_size_mismatch" and "41x30" in str(e.value)
    assert decode_image(other, SimpleNamespace(width=0, height=0))[0].shape == (30, 41)


def _camera(w: int, h: int) -> CameraModel:
    return CameraModel(
        K=np.array([[400.0, 0, w / 2], [0, 400.0, h / 2], [0, 0, 1]]), width=w, height=h
    )


# ------------------------------------------------------------------ rclpy messages (the node's)
def _rclpy_image(img: np.ndarray, encoding: str = "rgb8"):
    sensor_msgs = pytest.importorskip("sensor_msgs.msg")
    m = sensor_msgs.Image()
    m.height, m.width = int(img.shape[0]), int(img.shape[1])
    m.encoding = encoding
    img = np.ascontiguousarray(img)
    m.step = int(img.strides[0])
    m.data = img.tobytes()
    return m


def _rclpy_compressed(fmt: str, data: bytes):
    sensor_msgs = pytest.importorskip("sensor_msgs.msg")
    c = sensor_msgs.CompressedImage()
    c.format = fmt
    c.data = data
    return c


def _reason(msg, camera):
    with pytest.raises(ImageRejected) as e:
        decode_image(msg, camera)
    return e.value.reason


def test_rclpy_messages_decoded_and_checked():
    """rclpy's Image (data an ``array.array``) of the camera's size decodes to its pixels, a
    compressed JPEG decodes (bgr8); another size, an unknown encoding, a truncated raw image or
    a payload that is no image are refused under the node's reasons, the size before decoding
    (its camera unknown: not checked)."""
    cam = _camera(640, 480)
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
    out, enc = decode_image(_rclpy_image(img), cam)
    assert enc == "rgb8" and np.array_equal(out, img)
    small = _rclpy_image(img[:240, :320])
    assert _reason(small, cam) == "image_size_mismatch"
    assert decode_image(small, None)[0].shape == (240, 320, 3)
    assert _reason(_rclpy_image(img, "yuv422"), cam) == "bad_image"
    cut = _rclpy_image(img)
    cut.data = bytes(cut.data)[:1000]
    assert _reason(cut, cam) == "bad_image"
    c = _rclpy_compressed("jpeg", cv2.imencode(".jpg", img)[1].tobytes())
    out, enc = decode_image(c, cam)
    assert enc == "bgr8" and out.shape == (480, 640, 3)
    c.data = b"not an image"
    assert _reason(c, cam) == "bad_image"
    c.data = cv2.imencode(".jpg", img[:240, :320])[1].tobytes()
    assert _reason(c, cam) == "image_size_mismatch"


def test_raw_pixels_are_viewed_not_copied():
    """An unpadded raw image decodes to a view of the message's buffer (rclpy's
    ``array.array``, ``bytes``, a uint8 array): the same pixels, no per-frame copy of the
    0.9 MB of a 640x480 RGB frame; padded rows are copied out; ``data`` as a list of ints
    still decodes."""
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (20, 24, 3), dtype=np.uint8)
    m = _rclpy_image(img)
    out, _ = decode_image(m)
    assert np.array_equal(out, img) and np.shares_memory(out, np.frombuffer(m.data, np.uint8))
    data = np.ascontiguousarray(img).reshape(-1)
    for d in (data, data.tobytes(), memoryview(data)):
        msg = SimpleNamespace(height=20, width=24, encoding="rgb8", step=72, data=d)
        out, _ = decode_image(msg)
        assert np.array_equal(out, img)
        assert isinstance(d, bytes) or np.shares_memory(out, data)
    listed = SimpleNamespace(height=20, width=24, encoding="rgb8", step=72, data=data.tolist())
    assert np.array_equal(decode_image(listed)[0], img)
    padded = np.zeros((20, 80), np.uint8)
    padded[:, :72] = data.reshape(20, 72)
    msg = SimpleNamespace(height=20, width=24, encoding="rgb8", step=80, data=padded.reshape(-1))
    out, _ = decode_image(msg)
    assert np.array_equal(out, img) and out.flags.c_contiguous
    assert not np.shares_memory(out, padded)


def test_an_image_smaller_than_the_front_ends_take_is_a_bad_image():
    """An image below ``MIN_IMAGE_SIDE`` px a side (raw or compressed, the camera's size
    unknown or not) is ``bad_image`` naming the minimum, never given to a front end; one of
    exactly that side decodes."""
    k = MIN_IMAGE_SIDE
    tiny = np.full((k - 1, 40, 3), 128, np.uint8)
    for cam in (None, _camera(640, 480)):
        with pytest.raises(ImageRejected) as e:
            decode_image(_rclpy_image(tiny), cam)
        assert e.value.reason == "bad_image" and f"{k}x{k}" in str(e.value)
    c = _rclpy_compressed("png", cv2.imencode(".png", tiny)[1].tobytes())
    assert _reason(c, None) == "bad_image"
    ok = np.full((k, k, 3), 128, np.uint8)
    assert decode_image(_rclpy_image(ok), None)[0].shape == (k, k, 3)


# ------------------------------------------------------- the camera node and the rig node alike
def _camera_node_decode(msgs, maps, cfg, msg, cam):
    """The single-camera node's pipeline (no DDS) on ``msg`` after a camera_info of ``cam``:
    ``("image", array, encoding)`` as handed to the front end, or ``("drop", reason,
    detail)``."""
    from helpers.camera_node import CameraNode

    pipe = CameraNode(cfg, maps=maps)
    assert pipe.add_camera_info(msgs.camera_info(cam, 0, "cam")) is not None
    res = pipe.process(msg, "image")
    if res.image is None:
        return "drop", res.failure, res.detail
    assert res.failure in (None, "frontend_too_few_points"), (res.failure, res.detail)
    return "image", res.image[0], res.image[1]


def _rig_node_decode(msg, cam):
    """The rig node's image step (``LocalizerMode.take_frame`` of an image) on ``msg`` with the
    camera's model ``cam``: what it hands to the rig (``process_image`` or ``drop``), in the
    same form."""
    from rs_localizer.camera import FrameTime
    from rs_localizer.ros.camera_input import CameraCounts, CameraInput
    from rs_localizer.ros.core import QueuedFrame
    from rs_localizer.ros.mode import LocalizerMode

    got, logged = [], []

    class Rig:
        def process_image(self, name, stamp, img, camera, enc, tag=None):
            got.append(("image", img, enc))
            return []

        def drop(self, name, stamp, camera, reason):
            got.append(("drop", reason))
            return []

        def took_time_reset(self, name, stamp_ns=None):  # (no time reset: its stamp noted after)
            return None

        def last_search(self, name):  # (no search timed)
            return None

        def frame_time(self, name, stamp, camera):  # (its time the stamp)
            return FrameTime(stamp, int(stamp))

    log = SimpleNamespace(warning=lambda key, text: logged.append(text))
    camera_input = CameraInput(log, lambda key, n: None, name="c", rig=True)
    camera_input.history.add(0, (), None, cam)  # (the camera model of every stamp)
    warn = lambda key, text, count=0: log.warning(key, text)  # noqa: E731 (the node's warn)
    mode = LocalizerMode.__new__(LocalizerMode)  # (a rig's, not configured)
    node = SimpleNamespace(warn=warn, inputs={"c": camera_input}, camera_viz={},
                           frontend_kind="aruco", republish=False)  # fmt: skip
    mode.node, mode.alone = node, False
    mode.rig, mode._images, mode._counts = Rig(), {}, CameraCounts()
    mode._warn_no_info = lambda name, what: None
    stamp = camera_input.check(msg, "image")
    camera = camera_input.camera_of(stamp)
    # (the rig camera's frame step, the mode's take_frame: its entry checks, then the rig)
    taken = mode.take_frame(QueuedFrame("c", "image", msg, 0.0, stamp), camera)
    assert taken.outs == [] and taken.failure is None
    (out,) = got
    if out[0] == "drop":
        (text,) = logged
        detail = text.split(f"({out[1]}): ", 1)[1]
        return "drop", out[1], detail
    return out


def test_the_camera_node_and_the_rig_node_decode_alike():
    """One message through the single-camera node's pipeline and through the rig node's image
    step: raw 640x480 rgb8, bgr8, rgba8, mono8 give back the array written (the front end's
    input, encoding as sent); a JPEG CompressedImage gives OpenCV's own decoding of the payload
    (close to the original), a PNG the original; both paths hand the front end identical arrays.
    16-bit mono16, another size than the camera_info and an image below ``MIN_IMAGE_SIDE``
    (raw and compressed, with a camera_info of its own size) are refused by both under the same
    reason and message."""
    pytest.importorskip("rclpy")
    from rs_localizer.ros import config as C
    from rs_localizer.ros import params as P
    from rs_localizer.ros.bags.bag_io import COMPRESSED_IMAGE, RosbagsMessages

    msgs = RosbagsMessages()
    cfg = C.build_config(
        {**P.default_values(), "camera_info_wait": 0.0, "frontend": "aruco",
         "frontend_map": "apriltag_board", "tracking.enabled": False}
    )  # fmt: skip
    maps = C.load_maps(cfg.camera, owner=object())
    rng = np.random.default_rng(7)
    vga, k = _camera(640, 480), MIN_IMAGE_SIDE
    rgb = _img((480, 640, 3), seed=4)
    gray = _img((480, 640), seed=5)
    rgba = rng.integers(0, 256, (480, 640, 4), dtype=np.uint8)

    def raw(img, enc, stamp):
        return msgs.T["sensor_msgs/msg/Image"](
            header=msgs.header(stamp, "cam"), **image_fields(img, enc)
        )

    def compressed(img, kind, stamp):
        f = compressed_fields(img, kind, quality=90)
        return msgs.T[COMPRESSED_IMAGE](header=msgs.header(stamp, "cam"), **f)

    mono16 = msgs.T["sensor_msgs/msg/Image"](
        header=msgs.header(7, "cam"), height=480, width=640, encoding="mono16", is_bigendian=0,
        step=1280, data=rng.integers(0, 4096, (480, 640), np.uint16).view(np.uint8).ravel(),
    )  # fmt: skip
    jpeg = compressed(rgb, "jpeg", 5)
    jpeg_gray = compressed(gray, "jpeg", 6)
    decoded = {
        "rgb8": (raw(rgb, "rgb8", 1), vga, rgb, "rgb8"),
        "bgr8": (raw(rgb, "bgr8", 2), vga, rgb, "bgr8"),
        "rgba8": (raw(rgba, "rgba8", 3), vga, rgba, "rgba8"),
        "mono8": (raw(gray, "mono8", 4), vga, gray, "mono8"),
        "jpeg": (jpeg, vga, cv2.imdecode(np.asarray(jpeg.data), cv2.IMREAD_UNCHANGED), "bgr8"),
        "jpeg mono": (
            jpeg_gray,
            vga,
            cv2.imdecode(np.asarray(jpeg_gray.data), cv2.IMREAD_UNCHANGED),
            "mono8",
        ),
        "png": (compressed(rgb[:, :, ::-1], "png", 8), vga, rgb[:, :, ::-1], "bgr8"),
    }
    for name, (msg, cam, want, enc) in decoded.items():
        a, b = _camera_node_decode(msgs, maps, cfg, msg, cam), _rig_node_decode(msg, cam)
        assert a[0] == b[0] == "image", (name, a, b)
        assert a[2] == b[2] == enc, name
        assert a[1].dtype == b[1].dtype == np.uint8, name
        np.testing.assert_array_equal(a[1], b[1], err_msg=name)
        np.testing.assert_array_equal(a[1], want, err_msg=name)
    for name, src in (("jpeg", rgb), ("jpeg mono", gray)):  # (the array sent up to JPEG loss,
        # in the channel order it was compressed in: compressed_fields takes OpenCV's BGR)
        assert np.abs(decoded[name][2].astype(float) - src).mean() < 4.0, name

    thin = rgb[: k - 1]
    refused = {
        "mono16": (mono16, vga, "bad_image", "unsupported image encoding 'mono16'"),
        "other size": (raw(rgb[:240, :320], "rgb8", 9), vga, "image_size_mismatch", "320x240"),
        "too small": (raw(thin, "rgb8", 10), _camera(640, k - 1), "bad_image", f"{k}x{k}"),
        "too small jpeg": (
            compressed(thin, "jpeg", 11),
            _camera(640, k - 1),
            "bad_image",
            f"{k}x{k}",
        ),
    }
    for name, (msg, cam, reason, says) in refused.items():
        a, b = _camera_node_decode(msgs, maps, cfg, msg, cam), _rig_node_decode(msg, cam)
        assert a == b, (name, a, b)
        assert a[:2] == ("drop", reason) and says in a[2], (name, a)
