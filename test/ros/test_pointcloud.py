"""PointCloud2 <-> NumPy without sensor_msgs_py."""

import numpy as np
import pytest

sensor_msgs = pytest.importorskip("sensor_msgs.msg")

from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402

from rs_localizer.ros import pointcloud as pc  # noqa: E402


def _cloud(fields, point_step, data, width, height=1, bigendian=False, row_step=None):
    msg = PointCloud2()
    msg.height, msg.width = height, width
    msg.fields = [PointField(name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields]
    msg.point_step = point_step
    msg.row_step = point_step * width if row_step is None else row_step
    msg.is_bigendian = bigendian
    msg.data = bytes(data)
    return msg


def test_roundtrip_correspondences_float32_with_id_and_score():
    rng = np.random.default_rng(0)
    uv = rng.uniform(0, 1000, (50, 2))
    xyz = rng.normal(0, 10, (50, 3))
    ids = np.arange(50) * 3 + 7
    scores = rng.uniform(0, 1, 50)
    msg = pc.correspondence_cloud(uv, xyz, ids, scores, frame_id="cam", stamp=1_500_000_000_25)
    assert msg.header.frame_id == "cam"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (150, 25)
    assert msg.point_step == 28 and msg.width == 50 and msg.height == 1
    assert len(msg.data) == 28 * 50 and msg.is_dense
    c = pc.read_correspondences(msg)
    np.testing.assert_allclose(c.uv, uv, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(c.xyz, xyz, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(c.ids, ids)
    np.testing.assert_allclose(c.scores, scores, rtol=1e-6)
    assert c.uv.dtype == np.float64 and len(c) == 50
    # the library's one correspondence type: what a front end returns, same fields
    from rs_localizer.correspondences import Correspondences

    assert type(c) is Correspondences and c.points2d is c.uv and c.points is c.xyz
    assert c.ids.dtype == np.int64
    pixels, points, found_ids = c  # unpacks like a front end's result
    np.testing.assert_array_equal(pixels, c.uv)
    np.testing.assert_array_equal(points, c.xyz)
    np.testing.assert_array_equal(found_ids, ids)


def test_roundtrip_float64_exact():
    rng = np.random.default_rng(1)
    uv, xyz = rng.uniform(0, 1000, (20, 2)), rng.normal(0, 10, (20, 3))
    msg = pc.correspondence_cloud(uv, xyz, dtype="f8")
    assert {f.datatype for f in msg.fields} == {pc.FLOAT64}
    c = pc.read_correspondences(msg)
    np.testing.assert_array_equal(c.uv, uv)
    np.testing.assert_array_equal(c.xyz, xyz)
    assert c.ids is None and c.scores is None


def test_mixed_types_padding_and_field_order():
    # x,y,z float64 first, then padding, then u,v float32 (arbitrary order and offsets)
    n = 7
    dt = np.dtype(
        {
            "names": ["x", "y", "z", "v", "u"],
            "formats": ["<f8"] * 3 + ["<f4"] * 2,
            "offsets": [0, 8, 16, 28, 32],
            "itemsize": 40,
        }
    )
    arr = np.zeros(n, dt)
    arr["x"], arr["y"], arr["z"] = np.arange(n), np.arange(n) * 2, np.arange(n) * 3
    arr["u"], arr["v"] = np.arange(n) + 0.5, np.arange(n) + 0.25
    fields = [(nm, o, d, c) for nm, o, d, c in pc.dtype_to_fields(dt)]
    msg = _cloud(fields, 40, arr.tobytes(), n)
    c = pc.read_correspondences(msg)
    np.testing.assert_array_equal(c.uv[:, 0], np.arange(n) + 0.5)
    np.testing.assert_array_equal(c.uv[:, 1], np.arange(n) + 0.25)
    np.testing.assert_array_equal(c.xyz[:, 2], np.arange(n) * 3)


def test_big_endian():
    n = 5
    dt = np.dtype([(k, ">f4") for k in "uvxyz"])
    arr = np.zeros(n, dt)
    for i, k in enumerate("uvxyz"):
        arr[k] = np.arange(n) * (i + 1) + 0.5
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")]
    c = pc.read_correspondences(_cloud(fields, 20, arr.tobytes(), n, bigendian=True))
    np.testing.assert_array_equal(c.xyz[:, 2], np.arange(n) * 5 + 0.5)
    # the same bytes read as little endian are garbage, not equal
    c2 = pc.read_correspondences(_cloud(fields, 20, arr.tobytes(), n, bigendian=False))
    assert not np.allclose(np.nan_to_num(c2.xyz[:, 2]), np.arange(n) * 5 + 0.5)


def test_organized_cloud_with_row_padding():
    w, h = 3, 2
    dt = np.dtype([(k, "<f4") for k in "uvxyz"])
    arr = np.zeros((h, w), dt)
    arr["u"] = np.arange(6).reshape(h, w)
    pad = 8
    data = b"".join(arr[r].tobytes() + b"\0" * pad for r in range(h))
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")]
    msg = _cloud(fields, 20, data, w, h, row_step=20 * w + pad)
    c = pc.read_correspondences(msg)
    np.testing.assert_array_equal(c.uv[:, 0], np.arange(6))


def test_uint32_id_and_keypoints():
    uv = np.array([[1.0, 2.0], [3.0, 4.0]])
    msg = pc.keypoint_cloud(uv, [4_000_000_000, 5])
    k = pc.read_keypoints(msg)
    np.testing.assert_array_equal(k.ids, [4_000_000_000, 5])
    np.testing.assert_array_equal(k.uv, uv)


@pytest.mark.parametrize("drop", ["u", "z"])
def test_missing_field(drop):
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz") if k != drop]
    msg = _cloud(fields, 20, bytes(20 * 3), 3)
    with pytest.raises(ValueError, match=f"missing field.*'{drop}'") as e:
        pc.read_correspondences(msg)
    assert e.value.reason == "missing_fields"


def test_wrong_field_type():
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")]
    fields[0] = ("u", 0, pc.UINT32, 1)
    with pytest.raises(ValueError, match="'u' has type uint32") as e:
        pc.read_correspondences(_cloud(fields, 20, bytes(60), 3))
    assert e.value.reason == "wrong_field_type"
    fields[0] = ("u", 0, 42, 1)
    with pytest.raises(ValueError, match=r"unknown\(42\)"):
        pc.read_correspondences(_cloud(fields, 20, bytes(60), 3))
    # float id is rejected too
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")] + [("id", 20, 7, 1)]
    with pytest.raises(ValueError, match="'id' has type float32"):
        pc.read_correspondences(_cloud(fields, 24, bytes(72), 3))


def test_truncated_and_bad_layout():
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")]
    with pytest.raises(ValueError, match="truncated PointCloud2: 59 bytes") as e:
        pc.read_correspondences(_cloud(fields, 20, bytes(59), 3))
    assert e.value.reason == "truncated"
    with pytest.raises(ValueError, match="does not fit in point_step"):
        pc.read_correspondences(_cloud(fields, 16, bytes(48), 3))
    with pytest.raises(ValueError, match="row_step"):
        pc.read_correspondences(_cloud(fields, 20, bytes(60), 3, row_step=40))
    with pytest.raises(ValueError, match="point_step must be > 0"):
        pc.read_correspondences(_cloud(fields, 0, b"", 3))
    dup = fields + [("u", 0, pc.FLOAT32, 1)]
    with pytest.raises(ValueError, match="duplicate"):
        pc.read_correspondences(_cloud(dup, 20, bytes(60), 3))


def test_extra_bytes_are_tolerated_and_nan_rows_kept():
    uv = np.array([[1.0, 2.0], [np.nan, 4.0], [5.0, np.inf]])
    msg = pc.correspondence_cloud(uv, np.ones((3, 3)))
    assert not msg.is_dense
    msg.data = bytes(msg.data) + b"\0" * 7
    c = pc.read_correspondences(msg)
    assert np.isnan(c.uv[1, 0]) and np.isinf(c.uv[2, 1])


def test_empty_cloud():
    msg = pc.correspondence_cloud(np.zeros((0, 2)), np.zeros((0, 3)))
    assert msg.width == 0
    c = pc.read_correspondences(msg)
    assert c.uv.shape == (0, 2) and c.xyz.shape == (0, 3)


def test_count_greater_than_one_takes_first():
    dt = np.dtype([("u", "<f4"), ("v", "<f4"), ("x", "<f4", (3,))])
    arr = np.zeros(2, dt)
    arr["x"] = [[1, 2, 3], [4, 5, 6]]
    fields = [("u", 0, 7, 1), ("v", 4, 7, 1), ("x", 8, 7, 3)]
    got = pc.cloud_to_array(_cloud(fields, 20, arr.tobytes(), 2))
    np.testing.assert_array_equal(got["x"], [[1, 2, 3], [4, 5, 6]])


def test_dtype_to_fields_rejects_int64():
    with pytest.raises(ValueError, match="cannot be stored"):
        pc.dtype_to_fields(np.dtype([("a", "<i8")]))


def test_rosbags_messages_are_accepted():
    pytest.importorskip("rosbags")
    from rclpy.serialization import serialize_message
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    rng = np.random.default_rng(3)
    uv, xyz = rng.uniform(0, 100, (9, 2)), rng.uniform(0, 10, (9, 3))
    raw = serialize_message(pc.correspondence_cloud(uv, xyz, ids=np.arange(9)))
    msg = ts.deserialize_cdr(raw, "sensor_msgs/msg/PointCloud2")
    c = pc.read_correspondences(msg)
    np.testing.assert_allclose(c.uv, uv, rtol=1e-6)
    np.testing.assert_array_equal(c.ids, np.arange(9))


# ------------------------------------------------------------------ hostile layouts
def test_overlapping_offsets_are_a_layout_error():
    """A v field at the offset of u (every v == u) was accepted and solved 2000 km off."""
    rng = np.random.default_rng(5)
    arr = pc.correspondence_array(rng.uniform(0, 99, (4, 2)), rng.uniform(0, 9, (4, 3)))
    for name, off in (("v", 0), ("v", 2), ("z", 14), ("x", 4)):
        fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")]
        i = "uvxyz".index(name)
        fields[i] = (name, off, pc.FLOAT32, 1)
        with pytest.raises(ValueError, match="overlap") as e:
            pc.read_correspondences(_cloud(fields, 20, arr.tobytes(), 4))
        assert e.value.reason == "bad_layout"
    # a count > 1 running into the next field
    fields = [("u", 0, pc.FLOAT32, 2)] + [
        (k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz") if k != "u"
    ]
    with pytest.raises(ValueError, match="overlap") as e:
        pc.read_correspondences(_cloud(fields, 20, arr.tobytes(), 4))
    assert e.value.reason == "bad_layout"


def test_huge_count_is_a_layout_error_not_a_memory_error():
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")]
    fields[4] = ("z", 16, pc.FLOAT32, 2**32 - 1)
    with pytest.raises(ValueError, match="does not fit") as e:
        pc.read_correspondences(_cloud(fields, 20, bytes(60), 3))
    assert e.value.reason == "bad_layout"


def test_fields_that_are_not_read_are_ignored():
    """An extra field of unknown datatype rejected the whole cloud; fields the reader does not
    use (unknown type, empty name, overlapping each other or beyond the record) are ignored."""
    rng = np.random.default_rng(6)
    uv, xyz = rng.uniform(0, 99, (5, 2)), rng.uniform(0, 9, (5, 3))
    dt = np.dtype(
        {
            "names": list("uvxyz"),
            "formats": ["<f4"] * 5,
            "offsets": [0, 4, 8, 12, 16],
            "itemsize": 32,
        }
    )
    arr = np.zeros(5, dt)
    for i, k in enumerate("uv"):
        arr[k] = uv[:, i]
    for i, k in enumerate("xyz"):
        arr[k] = xyz[:, i]
    fields = [(k, 4 * i, pc.FLOAT32, 1) for i, k in enumerate("uvxyz")]
    fields += [
        ("rgb", 20, 42, 1),
        ("", 24, pc.UINT8, 1),
        ("a", 20, pc.FLOAT64, 1),
        ("b", 22, pc.UINT16, 1),
        ("c", 30, pc.FLOAT64, 1),
        ("d", 28, 0, 7),
    ]
    c = pc.read_correspondences(_cloud(fields, 32, arr.tobytes(), 5))
    np.testing.assert_allclose(c.uv, uv, rtol=1e-6)
    np.testing.assert_allclose(c.xyz, xyz, rtol=1e-6)
    assert c.ids is None and c.scores is None
    kfields = [
        ("u", 0, pc.FLOAT32, 1),
        ("v", 4, pc.FLOAT32, 1),
        ("id", 8, pc.UINT32, 1),
        ("w", 12, 99, 1),
        ("junk", 100, pc.FLOAT32, 1),
    ]
    k = pc.read_keypoints(_cloud(kfields, 20, bytes(40), 2))
    assert len(k) == 2
