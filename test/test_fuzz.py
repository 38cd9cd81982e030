"""Property-based fuzzing (hypothesis) of everything a hostile publisher controls:
the PointCloud2, CameraInfo and Image decoders and the estimator's input validation.

Properties: no exception escapes other than the documented one, every rejection carries a
documented reason, decoded values equal what was encoded (NumPy structured arrays as the
independent reference), and nothing implausible is returned as a success.

Profiles: ``ci`` (default, a bounded number of examples per test; the whole file takes a few
seconds to ~20 s) and ``long``, selected by ``RS_FUZZ_EXAMPLES`` (examples per test)::

    RS_FUZZ_EXAMPLES=20000 .venv/bin/python -m pytest -q -s test/test_fuzz.py \\
        --hypothesis-show-statistics

The number of examples each test ran is printed at the end of the module (``-s``).
"""

from __future__ import annotations

import itertools
import os
from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from rs_localizer.camera import CameraModel  # noqa: E402
from rs_localizer.estimation import EstimateOptions, RansacOptions, estimate_rs_pose  # noqa: E402
from rs_localizer.estimation.plausibility import depths_at_capture  # noqa: E402
from rs_localizer.geometry import rotation_angle_deg  # noqa: E402
from rs_localizer.ros.image_codec import ENCODINGS, decode_image  # noqa: E402
from rs_localizer.sim.attacks import ATTACKS, attack, corridor_frames  # noqa: E402

_LONG = int(os.environ.get("RS_FUZZ_EXAMPLES", "0") or 0)
_COMMON = dict(
    deadline=None,
    derandomize=not _LONG,
    database=None,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.filter_too_much,
        HealthCheck.data_too_large,
    ],
)
settings.register_profile("ci", max_examples=200, **_COMMON)
settings.register_profile("long", max_examples=max(_LONG, 1), **_COMMON)
_PROFILE = "long" if _LONG else "ci"
#: the estimator is ~100x slower per example than the decoders: fewer of them in CI
_EST_EXAMPLES = _LONG if _LONG else 60

RUNS = Counter()  # test -> examples run


@pytest.fixture(scope="module", autouse=True)
def _report():
    yield
    print(
        f"\nfuzz examples run ({_PROFILE} profile): "
        + ", ".join(f"{k} {v}" for k, v in sorted(RUNS.items()))
        + f"; total {sum(RUNS.values())}"
    )


# ------------------------------------------------------------------------------ PointCloud2
pc = pytest.importorskip("rs_localizer.ros.pointcloud")

_NAMES = ["u", "v", "x", "y", "z", "id", "score", "rgb", "intensity", "", "u"]
_field = st.builds(
    lambda name, off, dt, cnt: SimpleNamespace(name=name, offset=off, datatype=dt, count=cnt),
    st.sampled_from(_NAMES),
    st.integers(-4, 72),
    st.integers(0, 10),
    st.sampled_from([0, 1, 1, 1, 2, 3, 2**31]),
)


@st.composite
def _raw_clouds(draw):
    """Arbitrary layouts: field names, offsets, datatypes, counts, sizes, steps, data."""
    fields = draw(st.lists(_field, max_size=9))
    point_step = draw(st.integers(-1, 80))
    width = draw(st.integers(0, 12))
    height = draw(st.integers(0, 3))
    row_step = draw(st.one_of(st.just(max(point_step, 0) * width), st.integers(-1, 1000)))
    need = max(row_step, 0) * height
    n_data = draw(st.one_of(st.just(need), st.integers(0, need + 64)))
    data = draw(st.binary(min_size=n_data, max_size=n_data))
    return SimpleNamespace(
        fields=fields,
        point_step=point_step,
        width=width,
        height=height,
        row_step=row_step,
        is_bigendian=draw(st.booleans()),
        data=data,
    )


def _check_decoded(out, n, kind):
    assert len(out) == n
    assert out.uv.shape == (n, 2) and out.uv.dtype == np.float64
    if kind == "corr":
        assert out.xyz.shape == (n, 3) and out.xyz.dtype == np.float64
    else:
        assert out.ids.shape == (n,)


@settings(settings.get_profile(_PROFILE))
@given(_raw_clouds(), st.sampled_from(["corr", "kp"]))
def test_fuzz_pointcloud_layouts(msg, kind):
    """Any layout: a decoded cloud of width * height points, or a CloudError with a documented
    reason; never another exception."""
    RUNS["pointcloud_layouts"] += 1
    read = pc.read_correspondences if kind == "corr" else pc.read_keypoints
    try:
        out = read(msg)
    except pc.CloudError as e:
        assert e.reason in pc.CLOUD_REASONS, e.reason
        return
    _check_decoded(out, msg.width * msg.height, kind)
    # what was read came from distinct bytes inside the record (a v at u's offset is an error)
    sizes = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}
    read = [f for f in msg.fields if f.name in ("u", "v", "x", "y", "z", "id", "score")]
    spans = sorted((f.offset, f.offset + sizes[f.datatype] * max(f.count, 1)) for f in read)
    assert all(a >= 0 and b <= msg.point_step for a, b in spans)
    assert all(b1 <= a2 for (_, b1), (a2, _) in itertools.pairwise(spans)), spans


_FLOAT = {pc.FLOAT32: "f4", pc.FLOAT64: "f8"}
_INDEX = {pc.UINT32: "u4", pc.INT32: "i4", pc.UINT16: "u2", pc.UINT8: "u1"}
_ANY = {**_FLOAT, **_INDEX, pc.INT8: "i1", pc.INT16: "i2"}


@st.composite
def _valid_clouds(draw):
    """Valid correspondence clouds: u, v, x, y, z (+ id, score, + extra fields of any type,
    unknown types included) at random non-overlapping offsets, padding, endianness, organized
    or not. Returns (message, expected structured array, which optional fields)."""
    names = list("uvxyz")
    types = {k: draw(st.sampled_from(list(_FLOAT))) for k in names}
    if draw(st.booleans()):
        names.append("id")
        types["id"] = draw(st.sampled_from(list(_INDEX)))
    if draw(st.booleans()):
        names.append("score")
        types["score"] = draw(st.sampled_from(list(_FLOAT)))
    extra = draw(st.lists(st.sampled_from(list(_ANY) + [0, 9, 42]), max_size=3))
    order = draw(st.permutations(names + [f"extra{i}" for i in range(len(extra))]))
    for i, dt in enumerate(extra):
        types[f"extra{i}"] = dt
    big = draw(st.booleans())
    offsets, off = {}, 0
    for nm in order:
        off += draw(st.integers(0, 3))
        offsets[nm] = off
        off += np.dtype(_ANY.get(types[nm], "u1")).itemsize
    point_step = off + draw(st.integers(0, 5))
    width, height = draw(st.integers(1, 8)), draw(st.integers(1, 3))
    pad = draw(st.integers(0, 7))
    e = ">" if big else "<"
    known = [nm for nm in order if types[nm] in _ANY]
    dt = np.dtype(
        {
            "names": known,
            "formats": [e + _ANY[types[nm]] for nm in known],
            "offsets": [offsets[nm] for nm in known],
            "itemsize": point_step,
        }
    )
    n = width * height
    arr = np.zeros(n, dt)
    vals = st.floats(allow_nan=True, allow_infinity=True, width=32)
    for nm in known:
        kind = dt.fields[nm][0].kind
        if kind == "f":
            arr[nm] = draw(st.lists(vals, min_size=n, max_size=n))
        else:
            info = np.iinfo(dt.fields[nm][0])
            arr[nm] = draw(
                st.lists(st.integers(int(info.min), int(info.max)), min_size=n, max_size=n)
            )
    rows = arr.tobytes()
    data = b"".join(
        rows[r * width * point_step : (r + 1) * width * point_step] + b"\xab" * pad
        for r in range(height)
    )
    fields = [
        SimpleNamespace(name=nm, offset=offsets[nm], datatype=types[nm], count=1) for nm in order
    ]
    msg = SimpleNamespace(
        fields=fields,
        point_step=point_step,
        width=width,
        height=height,
        row_step=width * point_step + pad,
        is_bigendian=big,
        data=data,
    )
    return msg, arr


@settings(settings.get_profile(_PROFILE))
@given(_valid_clouds())
def test_fuzz_pointcloud_values(case):
    """Valid layouts decode to exactly the encoded values (NumPy is the reference); fields the
    reader does not use, of whatever type, are ignored."""
    RUNS["pointcloud_values"] += 1
    msg, arr = case
    c = pc.read_correspondences(msg)
    np.testing.assert_array_equal(c.uv, np.stack([arr["u"], arr["v"]], 1).astype(float))
    np.testing.assert_array_equal(c.xyz, np.stack([arr[k] for k in "xyz"], 1).astype(float))
    if "id" in arr.dtype.names:
        np.testing.assert_array_equal(c.ids, arr["id"].astype(np.int64))
        k = pc.read_keypoints(msg)
        np.testing.assert_array_equal(k.ids, arr["id"].astype(np.int64))
    else:
        assert c.ids is None
    if "score" in arr.dtype.names:
        np.testing.assert_array_equal(c.scores, arr["score"].astype(float))


# ------------------------------------------------------------------------------ CameraInfo
cv = pytest.importorskip("rs_localizer.ros.conversions")

_num = st.one_of(st.floats(-3000, 3000), st.sampled_from([0.0, -1.0, np.nan, np.inf, 1e300]))


@st.composite
def _camera_infos(draw):
    fx, fy = draw(st.one_of(st.floats(50, 3000), _num)), draw(st.one_of(st.floats(50, 3000), _num))
    w, h = draw(st.sampled_from([0, 1, 64, 640, 1280])), draw(st.sampled_from([0, 1, 48, 480, 720]))
    cx, cy = draw(st.one_of(st.just(w / 2), _num)), draw(st.one_of(st.just(h / 2), _num))
    k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    if draw(st.integers(0, 9)) == 0:
        k[draw(st.integers(0, 8))] = draw(_num)
    n_d = draw(st.sampled_from([0, 1, 2, 3, 4, 5, 6, 8, 9, 12, 14]))
    d = draw(
        st.lists(
            st.one_of(st.just(0.0), st.floats(-0.5, 0.5), st.sampled_from([np.nan, np.inf])),
            min_size=n_d,
            max_size=n_d,
        )
    )
    model = draw(
        st.sampled_from(
            ["plumb_bob", "rational_polynomial", "equidistant", "none", "", "fisheye_magic"]
        )
    )
    roi = SimpleNamespace(
        x_offset=draw(st.integers(0, 1400)),
        y_offset=draw(st.integers(0, 800)),
        width=draw(st.integers(0, 1400)),
        height=draw(st.integers(0, 800)),
    )
    if draw(st.booleans()):
        roi.x_offset = roi.y_offset = roi.width = roi.height = 0
    return SimpleNamespace(
        k=k,
        d=d,
        distortion_model=model,
        width=w,
        height=h,
        binning_x=draw(st.integers(0, 4)),
        binning_y=draw(st.integers(0, 4)),
        roi=roi,
    )


@settings(settings.get_profile(_PROFILE))
@given(_camera_infos())
def test_fuzz_camera_info(info):
    """Any CameraInfo: a camera model whose K, size and distortion follow from the message
    (REP 104 ROI and binning, computed here independently), or a CameraInfoError with a
    documented reason."""
    RUNS["camera_info"] += 1
    try:
        cam = cv.camera_model_from_camera_info(info, line_delay=3e-5)
    except cv.CameraInfoError as e:
        assert e.reason in cv.CAMERA_INFO_REASONS, e.reason
        return
    K = np.reshape(info.k, (3, 3)).astype(float)
    w, h = info.width, info.height
    r = info.roi
    assert np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0
    if (r.x_offset, r.y_offset, r.width, r.height) != (0, 0, 0, 0):
        assert r.width > 0 and r.height > 0
        assert r.x_offset + r.width <= w and r.y_offset + r.height <= h
        if (r.width, r.height) != (w, h):
            K[0, 2] -= r.x_offset
            K[1, 2] -= r.y_offset
            w, h = r.width, r.height
    bx, by = max(info.binning_x, 1), max(info.binning_y, 1)
    K[0] /= bx
    K[1] /= by
    w, h = w // bx, h // by
    assert (cam.width, cam.height) == (w, h) and w > 0 and h > 0
    np.testing.assert_array_equal(cam.K, K)
    assert np.isfinite(cam.D).all()
    nz = np.flatnonzero(info.d)
    if len(nz):  # the non-zero coefficients are kept in place, nothing is padded in
        assert len(cam.D) >= nz[-1] + 1
        np.testing.assert_array_equal(cam.D[: nz[-1] + 1], np.asarray(info.d)[: nz[-1] + 1])
        assert len(cam.D) <= len(info.d)


# ------------------------------------------------------------------------------ Image
@st.composite
def _images(draw):
    enc = draw(st.sampled_from(sorted(ENCODINGS) + ["MONO8", "rgb16", "bayer_rggb8", "", "32FC1"]))
    h, w = draw(st.integers(0, 6)), draw(st.integers(0, 6))
    ch = ENCODINGS.get(enc.lower(), 1)
    step = draw(st.one_of(st.just(w * ch), st.integers(0, 40)))
    n = draw(st.one_of(st.just(step * h), st.integers(0, step * h + 8)))
    return SimpleNamespace(
        encoding=enc, height=h, width=w, step=step, data=draw(st.binary(min_size=n, max_size=n))
    )


@settings(settings.get_profile(_PROFILE))
@given(_images())
def test_fuzz_image_decoder(msg):
    """Any Image: the pixels of each row (honouring ``step``), or a ValueError (the node's
    ``bad_image``)."""
    RUNS["image"] += 1
    try:
        img, _enc = decode_image(msg, min_side=0)
    except ValueError:
        return
    ch = ENCODINGS[msg.encoding.lower()]
    assert img.shape[:2] == (msg.height, msg.width) and img.dtype == np.uint8
    assert (img.ndim == 2) == (ch == 1)
    buf = np.frombuffer(msg.data, np.uint8)
    for r in range(msg.height):
        np.testing.assert_array_equal(
            img[r].reshape(-1), buf[r * msg.step : r * msg.step + msg.width * ch]
        )


# ------------------------------------------------------------------------------ estimator
CAM = CameraModel(
    K=np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]]),
    width=640,
    height=480,
    line_delay=5e-5,
    D=[0.05, -0.02, 0.0, 0.0, 0.0],
)
OPTS = EstimateOptions(ransac=RansacOptions(max_iterations=60, min_iterations=10))
#: every failure reason estimate_rs_pose documents
REASONS = {
    "too_few_points",
    "ambiguous_tag",
    "no_hypothesis",
    "too_few_inliers",
    "degenerate_geometry",
    "implausible_motion",
    "cheirality",
    "inconsistent_fit",
}


def _check_estimate(e, u, X, opts=OPTS):
    """Nothing implausible as a success: finite rotation, bounded velocities, enough inliers,
    every inlier in front of the camera at its capture time and within the threshold."""
    assert np.isfinite(e.model.R).all() and np.isfinite(e.pose.position).all()
    if not e.success:
        assert e.failure in REASONS, e.failure
        assert e.num_inliers == 0
        return
    assert e.failure is None
    assert e.num_inliers >= opts.ransac.min_inliers
    np.testing.assert_allclose(e.model.R @ e.model.R.T, np.eye(3), atol=1e-9)
    assert np.linalg.norm(e.pose.angular_velocity) <= opts.plausibility.max_angular_velocity * (
        1 + 1e-9
    )
    assert np.linalg.norm(e.pose.linear_velocity) <= opts.plausibility.max_linear_velocity * (
        1 + 1e-9
    )
    inl = e.inliers
    _, r, _ = CAM.normalize(u[inl])
    z = depths_at_capture(e.model.R, e.model.C, e.model.w, e.model.t, X[inl], r - CAM.r0)
    assert (z > 0).all()
    assert e.rmse_px <= opts.ransac.threshold_px


_val = st.one_of(st.floats(-2000, 2000), st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e30]))


@st.composite
def _arrays(draw):
    n = draw(st.integers(0, 40))
    u = np.array(
        draw(st.lists(st.tuples(_val, _val), min_size=n, max_size=n)), dtype=float
    ).reshape(n, 2)
    X = np.array(
        draw(st.lists(st.tuples(_val, _val, _val), min_size=n, max_size=n)), dtype=float
    ).reshape(n, 3)
    if draw(st.integers(0, 9)) == 0:  # a wrong shape
        X = X[:, :2] if draw(st.booleans()) else X[: max(n - 1, 0)]
    return u, X


@settings(settings.get_profile(_PROFILE), max_examples=_EST_EXAMPLES)
@given(_arrays(), st.sampled_from(["r6p_1lin", "p3p", "r9p"]))
def test_fuzz_estimator_arbitrary_input(arrays, solver):
    """Arbitrary values (NaN, inf, huge, duplicates): a ValueError for wrong shapes only,
    otherwise a result that is a documented failure or a plausible pose."""
    RUNS["estimator_arbitrary"] += 1
    u, X = arrays
    if u.shape[0] != X.shape[0] or X.shape[1:] != (3,):
        with pytest.raises(ValueError):
            estimate_rs_pose(u, X, CAM, solver, OPTS)
        return
    _check_estimate(estimate_rs_pose(u, X, CAM, solver, OPTS), u, X)


def _scene(seed):
    rng = np.random.default_rng(seed)
    R = np.eye(3)
    C = np.array([0.0, 0.0, 6.0])
    P = np.concatenate([rng.uniform(-2, 2, (60, 2)), rng.uniform(-1, 1, (60, 1))], axis=1)
    Pc = P @ R.T + C
    uv = CAM.distort(Pc[:, :2] / Pc[:, 2:])
    return uv, P, R, C


_corruptions = st.lists(
    st.sampled_from(
        [
            "v=u",
            "u=v",
            "reflect",
            "duplicate",
            "shuffle_3d",
            "collinear_px",
            "scale_3d",
            "nan_rows",
            "behind",
            "one_point",
        ]
    ),
    min_size=1,
    max_size=3,
)


@settings(settings.get_profile(_PROFILE), max_examples=_EST_EXAMPLES)
@given(st.integers(0, 2**16), _corruptions, st.floats(0.0, 1.0))
def test_fuzz_estimator_corrupted_frames(seed, corruptions, frac):
    """A valid static frame (60 points, 6 m away) with hostile edits applied to a fraction of
    its rows: never an implausible success; untouched frames solve to the truth."""
    RUNS["estimator_corrupted"] += 1
    u, X, R, C = _scene(seed)
    rng = np.random.default_rng(seed)
    m = rng.random(len(u)) < frac
    for c in corruptions:
        if c == "v=u":
            u[m, 1] = u[m, 0]
        elif c == "u=v":
            u[:, 0] = u[:, 1]
        elif c == "reflect":
            centre = -R.T @ C
            X[m] = 2 * centre - X[m]
        elif c == "duplicate":
            u[m], X[m] = u[0], X[0]
        elif c == "shuffle_3d":
            X[m] = X[m][rng.permutation(int(m.sum()))]
        elif c == "collinear_px":
            u[m, 1] = 0.3 * u[m, 0] + 10
        elif c == "scale_3d":
            X[m] *= 1e5
        elif c == "nan_rows":
            u[m, 0] = np.nan
        elif c == "behind":
            X[m, 2] = -C[2] - 5.0
        elif c == "one_point":
            u[:], X[:] = u[0], X[0]
    e = estimate_rs_pose(u, X, CAM, "r6p_1lin", OPTS)
    _check_estimate(e, u, X)
    ok = np.isfinite(u).all(1)
    if ok.sum() >= 3:  # every pixel within 1 px of one image line: no pose, whatever the 3D
        p = u[ok] - u[ok].mean(0)
        if np.linalg.svd(p, compute_uv=False)[-1] / np.sqrt(ok.sum()) < 1.0:
            assert not e.success
    if not m.any() and "u=v" not in corruptions and "one_point" not in corruptions:
        assert e.success and rotation_angle_deg(e.model.R, R) < 0.5


@settings(settings.get_profile(_PROFILE), max_examples=_EST_EXAMPLES)
@given(st.integers(0, 2**16), st.sampled_from(ATTACKS), st.sampled_from(["r6p_1lin", "p3p"]))
def test_fuzz_estimator_partial_fit_garbage(seed, kind, solver):
    """A corridor frame (walls, floor, ceiling, clutter; 300 points) whose every row is
    mirrored or reflected (:func:`~rs_localizer.sim.attacks.attack`): one
    wall fits from behind; never a success."""
    RUNS["estimator_partial_fit_garbage"] += 1
    f = attack(corridor_frames(1, seed)[0], kind)
    e = estimate_rs_pose(f.points_px, f.points3d, f.camera, solver, f.options)
    assert not e.success, (e.inliers.sum(), e.pose.position, f.position)
    assert e.failure in REASONS
