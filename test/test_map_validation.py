"""Map files that load but could never work are refused with a clear error; maps are written
readable by others (the user's umask)."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
import yaml

from rs_localizer.maps import load_marker_map, write_marker_map
from rs_localizer.maps.features import DESCRIPTOR_FORMATS, FeatureMap


def _square(side: float, origin=(0.0, 0.0, 2.0)) -> np.ndarray:
    o = np.asarray(origin, float)
    return o + side * np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)


def _write(tmp_path, data) -> str:
    p = tmp_path / "map.yaml"
    p.write_text(yaml.safe_dump(data))
    return str(p)


def _marker(mid, corners, **extra) -> dict:
    return {"id": mid, "corners": np.asarray(corners).tolist(), **extra}


def test_a_good_marker_map_loads_with_extra_fields(tmp_path):
    path = _write(
        tmp_path,
        {
            "dictionary": "DICT_4X4_50",
            "anchor": 3,
            "marker_size": 0.1,
            "frame_uncertainty": {"position": [0.001, 0.001, 0.001]},
            "markers": [
                _marker(3, _square(0.1), std_position=[0.0, 0.0, 0.0], observations=4),
                _marker(4, _square(0.1, (0.3, 0.0, 2.0)), covariance=np.eye(6).tolist()),
            ],
        },
    )
    dictionary, corners = load_marker_map(path)
    assert dictionary == "DICT_4X4_50" and sorted(corners) == [3, 4]
    np.testing.assert_allclose(corners[4], _square(0.1, (0.3, 0.0, 2.0)))


@pytest.mark.parametrize(
    "markers, match",
    [
        ([], "no markers"),
        ([_marker(1, _square(0.1)), _marker(1, _square(0.1, (1, 0, 2)))], "appears twice"),
        ([_marker(1.5, _square(0.1))], "integer"),
        ([_marker(-1, _square(0.1))], "integer"),
        ([{"id": 2}], "'id' and 'corners'"),
        ([_marker(1, _square(0.1) * np.array([1.0, 2.0, 1.0]))], "not a square"),
        ([_marker(1, np.repeat(_square(0.1)[:1], 4, axis=0))], "degenerate"),
        ([_marker(1, np.full((4, 3), np.nan))], "4 finite"),
        ([_marker(1, _square(0.1)[:3])], "4 finite"),
        ([_marker(1, _square(0.1), size=0.2)], "states 0.2"),
    ],
)
def test_marker_maps_that_cannot_work_are_refused(tmp_path, markers, match):
    with pytest.raises(ValueError, match=match):
        load_marker_map(_write(tmp_path, {"dictionary": "DICT_4X4_50", "markers": markers}))


def test_a_bent_marker_is_refused(tmp_path):
    c = _square(0.1)
    c[2, 2] += 0.02  # one corner 2 cm out of the plane (20 % of the side)
    with pytest.raises(ValueError, match=r"not a square|coplanar"):
        load_marker_map(_write(tmp_path, {"markers": [_marker(1, c)]}))


def test_the_built_in_scenes_still_load():
    for name in ("aruco_room", "textured_room"):
        dictionary, corners = load_marker_map(name)
        assert corners and dictionary.startswith("DICT_")


def _feature_map(kind="orb", n=20, **over) -> dict:
    rng = np.random.default_rng(0)
    dtype, width = DESCRIPTOR_FORMATS.get(kind, DESCRIPTOR_FORMATS["orb"])
    d = dict(
        points=rng.normal(size=(n, 3)),
        descriptors=rng.integers(0, 255, (n, width)).astype(dtype),
        landmark_ids=np.arange(n, dtype=np.int64),
    )
    d.update(over)
    d["kind"] = np.array(kind)
    return d


def test_a_good_feature_map_loads(tmp_path):
    for kind in DESCRIPTOR_FORMATS:
        p = tmp_path / f"{kind}.npz"
        np.savez(p, **_feature_map(kind))
        fm = FeatureMap.load(p)
        assert fm.kind == kind and len(fm) == 20


@pytest.mark.parametrize(
    "over, match",
    [
        ({"descriptors": np.zeros((20, 32), np.float32)}, "descriptors must be"),
        ({"descriptors": np.zeros((20, 64), np.uint8)}, "descriptors must be"),
        ({"kind": "surf"}, "kind"),
        ({"points": np.full((20, 3), np.nan)}, "non-finite"),
        ({"landmark_ids": np.full(20, np.nan)}, "landmark ids"),
        (
            {
                "points": np.zeros((0, 3)),
                "descriptors": np.zeros((0, 32), np.uint8),
                "landmark_ids": np.zeros(0, np.int64),
            },
            "no landmarks",
        ),
    ],
)
def test_feature_maps_that_cannot_work_are_refused(tmp_path, over, match):
    p = tmp_path / "bad.npz"
    np.savez(p, **_feature_map(**over))
    with pytest.raises(ValueError, match=match):
        FeatureMap.load(p)


def _pickled_points(p):
    d = _feature_map()
    d["points"] = np.array([{"x": 1.0}] * 20, dtype=object)
    np.savez(p, **d)  # (np.savez pickles an object array)


def _zip_of_other_arrays(p):
    import zipfile

    with zipfile.ZipFile(p, "w") as z:
        for name in ("points", "descriptors", "landmark_ids", "kind"):
            z.writestr(f"{name}.npy", b"not an array")


@pytest.mark.parametrize(
    "make, why",
    [
        (lambda p: p.write_bytes(np.random.default_rng(3).bytes(4096)), "not a NumPy .npz"),
        (lambda p: p.write_bytes(b""), "not a NumPy .npz"),
        (_zip_of_other_arrays, "'points' is not a NumPy array"),
        (lambda p: np.savez(p, foo=np.zeros(3)), "missing"),
        (lambda p: np.savez(p, **_feature_map(points=np.array(["a"] * 20))), "'points'"),
        (_pickled_points, "Python objects"),
        (lambda p: p.write_bytes(_npy_bytes()), "single NumPy array"),
    ],
)
def test_a_file_that_is_not_a_feature_map_is_named_never_unpickled(tmp_path, make, why):
    p = tmp_path / "corrupt.npz"
    make(p)
    with pytest.raises(ValueError) as e:
        FeatureMap.load(p)
    assert f"{p}: not a feature map" in str(e.value) and why in str(e.value), e.value
    # nothing the user sees (the error and what a traceback shows of its causes) suggests
    # loading the file as a pickle
    err, shown = e.value, []
    while err is not None:
        shown.append(str(err))
        err = err.__cause__ or (None if err.__suppress_context__ else err.__context__)
    assert not any("pickle" in m.lower() for m in shown), shown


def _npy_bytes() -> bytes:
    import io

    b = io.BytesIO()
    np.save(b, np.zeros(3))
    return b.getvalue()


def test_the_node_keeps_its_old_map_when_a_new_one_is_refused(tmp_path):
    """A run-time change to a map that cannot work fails before anything is swapped."""
    from rs_localizer.frontends.shared import SHARED_MAPS

    good = tmp_path / "good.yaml"
    write_marker_map(good, "DICT_4X4_50", {1: _square(0.1)})
    bad = _write(tmp_path, {"dictionary": "DICT_4X4_50", "markers": []})
    owner = object()
    fe = SHARED_MAPS.frontend("aruco", str(good), owner)
    with pytest.raises(ValueError, match="no markers"):
        SHARED_MAPS.frontend("aruco", bad, owner)
    assert fe.marker_corners.keys() == {1}
    SHARED_MAPS.release(owner)


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def test_maps_are_written_readable_by_others(tmp_path, umask_022):
    from rs_localizer.mapping.outputs import write_atomic
    from rs_localizer.maps import file_mode

    assert file_mode() == 0o644
    p = write_atomic(tmp_path / "m.yaml", "markers: []\n")
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    os.umask(0o077)
    q = write_atomic(tmp_path / "private.yaml", "markers: []\n")
    assert stat.S_IMODE(q.stat().st_mode) == 0o600
    assert not list(tmp_path.glob(".*.tmp"))


def test_landmark_maps_that_cannot_work_are_refused(tmp_path):
    from rs_localizer.maps import load_landmarks_csv

    cases = {
        "id,x,y,z\n": "no landmarks",
        "id,x,y,z\n1,0,0,1\n1,0,1,1\n": "duplicate",
        "id,x,y,z\n1,nan,0,1\n": "non-finite",
        "1,0,0\n": "expected",
    }
    for k, (text, match) in enumerate(cases.items()):
        p = tmp_path / f"l{k}.csv"
        p.write_text(text)
        with pytest.raises(ValueError, match=match):
            load_landmarks_csv(p)
    p.write_text("id,x,y,z\n3,0.5,0,2\n")
    ids, pts = load_landmarks_csv(p)
    assert ids.tolist() == [3] and pts.tolist() == [[0.5, 0.0, 2.0]]


def test_marker_and_landmark_maps_are_written_whole_and_readable(tmp_path, umask_022):
    from rs_localizer.maps import load_landmarks_csv, save_landmarks_csv

    p = write_marker_map(tmp_path / "sub" / "m.yaml", "DICT_4X4_50", {7: _square(0.1)})
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    assert load_marker_map(p)[1].keys() == {7}
    q = save_landmarks_csv(tmp_path / "l.csv", [4, 5], np.array([[0, 0, 1.0], [1, 2, 3.0]]))
    assert stat.S_IMODE(q.stat().st_mode) == 0o644
    assert load_landmarks_csv(q)[0].tolist() == [4, 5]
    assert not list(tmp_path.rglob("*.tmp"))


def test_a_missing_map_file_is_named_a_map_file(tmp_path):
    """A missing marker map (the node's ``frontend_map``, the tools' map arguments) is reported
    as a map file, naming the path and what was expected."""
    from rs_localizer.maps import scene_path

    missing = tmp_path / "nosuch.yaml"
    with pytest.raises(FileNotFoundError, match=r"map file .*nosuch\.yaml.* not found"):
        scene_path(missing)


def test_the_marker_map_writer_keeps_map_markers_fields(tmp_path):
    """One writer for every marker map: the anchor, the frame and per-marker fields written
    after the corners (map-markers' map) read back through the one reader and the std reader."""
    from rs_localizer.maps.markers import load_marker_std

    frame = {"kind": "anchor", "anchors": [7]}
    p = write_marker_map(
        tmp_path / "m.yaml",
        "DICT_4X4_50",
        {8: _square(0.1, (0.3, 0.0, 2.0)), 7: _square(0.1)},
        anchor=7,
        frame=frame,
        marker_fields={7: {"std_position": [0.001, 0.002, 0.0], "observations": 3}},
    )
    data = yaml.safe_load(p.read_text())
    assert list(data) == ["dictionary", "anchor", "frame", "markers"] and data["frame"] == frame
    assert [m["id"] for m in data["markers"]] == [7, 8]
    assert list(data["markers"][0]) == ["id", "corners", "std_position", "observations"]
    assert sorted(load_marker_map(p)[1]) == [7, 8] and load_marker_std(p) == {7: 0.002}
    with pytest.raises(FileExistsError):
        write_marker_map(p, "DICT_4X4_50", {7: _square(0.1)}, overwrite=False)


def test_feature_maps_are_written_whole_and_readable(tmp_path, umask_022):
    rng = np.random.default_rng(1)
    fm = FeatureMap(
        rng.normal(size=(5, 3)), rng.integers(0, 256, (5, 32), np.uint8), np.arange(5), "orb"
    )
    p = fm.save(tmp_path / "map")
    assert p == tmp_path / "map.npz" and stat.S_IMODE(p.stat().st_mode) == 0o644
    np.testing.assert_array_equal(FeatureMap.load(p).descriptors, fm.descriptors)
    assert not list(tmp_path.glob(".*.tmp"))
