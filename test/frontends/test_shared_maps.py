"""frontends.shared.MapCache: one load per map file, one front end per camera."""

import os

import numpy as np
import pytest

from rs_localizer.frontends.shared import MapCache
from rs_localizer.maps import load_landmarks_csv


def test_marker_map_loaded_once_and_frontends_are_separate(tmp_path):
    from rs_localizer.frontends.aruco import ArucoFrontend
    from rs_localizer.maps import load_marker_map

    cache = MapCache()
    a = cache.frontend("aruco", "aruco_room")
    b = cache.frontend("aruco", "aruco_room")
    assert isinstance(a, ArucoFrontend) and a is not b
    assert cache.loads == 1
    ref_dict, ref = load_marker_map("aruco_room")
    assert a.dictionary == ref_dict and set(a.marker_corners) == set(ref)
    for k in ref:
        np.testing.assert_array_equal(a.marker_corners[k], ref[k])


def test_feature_map_shared_by_two_frontends(tmp_path):
    from rs_localizer.frontends.features import FeatureFrontend
    from rs_localizer.maps.features import FeatureMap

    rng = np.random.default_rng(0)
    fm = FeatureMap(
        rng.normal(size=(50, 3)),
        rng.integers(0, 256, (50, 32), dtype=np.uint8),
        np.arange(50, dtype=np.int64),
        "orb",
    )
    path = fm.save(tmp_path / "map.npz")
    cache = MapCache()
    a, b = cache.frontend("features", path), cache.frontend("features", str(path))
    assert isinstance(a, FeatureFrontend) and a is not b and a.map is b.map
    assert cache.loads == 1
    np.testing.assert_array_equal(a.map.descriptors, fm.descriptors)
    np.testing.assert_array_equal(a.map.points, fm.points)


def test_landmarks_reloaded_when_the_file_changes(tmp_path):
    p = tmp_path / "lm.csv"
    p.write_text("id,x,y,z\n5,1,2,3\n2,4,5,6\n")
    cache = MapCache()
    ids, pts = cache.landmarks(p)
    ids2, _ = cache.landmarks(str(p))
    assert ids is ids2 and cache.loads == 1
    np.testing.assert_array_equal(ids, [2, 5])
    np.testing.assert_array_equal(pts, [[4, 5, 6], [1, 2, 3]])
    p.write_text("id,x,y,z\n7,0,0,1\n")
    os.utime(p, ns=(p.stat().st_atime_ns, p.stat().st_mtime_ns + 10**9))
    ids3, _ = cache.landmarks(p)
    assert cache.loads == 2
    np.testing.assert_array_equal(ids3, load_landmarks_csv(p)[0])


def test_errors_are_not_cached(tmp_path):
    cache = MapCache()
    with pytest.raises(FileNotFoundError):
        cache.frontend("aruco", tmp_path / "missing.yaml")
    with pytest.raises(ValueError):
        cache.frontend("nope", "aruco_room")
    assert cache.loads == 0


def test_owners_hold_and_release():
    cache = MapCache()
    a, b = object(), object()
    cache.frontend("aruco", "aruco_room", owner=a)
    cache.frontend("aruco", "aruco_room", owner=b)
    assert cache.loads == 1 and len(cache) == 1
    cache.release(a)
    assert len(cache) == 1  # b still holds it
    cache.frontend("aruco", "aruco_room", owner=a)
    assert cache.loads == 1
    cache.release(a)
    cache.release(b)
    assert len(cache) == 0  # nobody holds it: gone
    cache.frontend("aruco", "aruco_room", owner=a)
    assert cache.loads == 2  # loaded again


def test_a_new_map_replaces_the_owners_old_one(tmp_path):
    p1, p2 = tmp_path / "a.csv", tmp_path / "b.csv"
    p1.write_text("1,0,0,1\n")
    p2.write_text("2,0,0,1\n")
    cache, owner = MapCache(), object()
    cache.landmarks(p1, owner=owner)
    cache.frontend("aruco", "aruco_room", owner=owner)
    assert len(cache) == 2
    cache.landmarks(p2, owner=owner)  # p1 no longer held by anyone
    assert len(cache) == 2 and cache.landmarks(p2)[0][0] == 2
    cache.release(owner)
    assert len(cache) == 1  # p2 stays: pinned by the owner-less call above


def test_one_table_of_front_ends():
    """make_frontend and the node's shared maps read the same table of front ends."""
    from rs_localizer.frontends import FRONTENDS, make_frontend
    from rs_localizer.frontends.registry import FRONTEND_KINDS

    assert FRONTENDS == tuple(FRONTEND_KINDS) == ("aruco", "features", "board")
    with pytest.raises(ValueError, match="unknown front end 'nope'"):
        make_frontend("nope", "aruco_room")
    a = make_frontend("aruco", "aruco_room")
    b = MapCache().frontend("aruco", "aruco_room")
    assert type(a) is type(b) and a.marker_corners.keys() == b.marker_corners.keys()


def test_node_and_library_score_markers_by_the_stated_std(tmp_path):
    """A map with stated marker std (as map-markers writes): the node's front end (shared maps)
    and make_frontend both carry them, and the scores follow marker_scores."""
    from rs_localizer.frontends import make_frontend
    from rs_localizer.frontends.aruco import marker_scores
    from rs_localizer.maps.markers import load_marker_map, write_marker_map

    dictionary, corners = load_marker_map("aruco_room")
    ids = sorted(corners)[:3]
    std = {ids[0]: 0.001, ids[1]: 0.005, ids[2]: 0.05}
    path = write_marker_map(
        tmp_path / "m.yaml",
        dictionary,
        {i: corners[i] for i in ids},
        marker_fields={i: {"std_position": [s, s / 2, s / 3]} for i, s in std.items()},
    )
    for fe in (make_frontend("aruco", path), MapCache().frontend("aruco", path)):
        assert fe.marker_std == pytest.approx(std)
    expected = marker_scores(np.array([std[i] for i in ids]))
    assert expected[0] > expected[1] > expected[2]


def test_load_maps_loads_what_a_camera_names_and_reuses_its_front_end(tmp_path):
    from rs_localizer.frontends.aruco import ArucoFrontend
    from rs_localizer.maps import save_landmarks_csv

    ids = np.array([7, 3, 5])
    pts = np.arange(9.0).reshape(3, 3)
    save_landmarks_csv(tmp_path / "lm.csv", ids, pts)
    cache, owner = MapCache(), object()
    m = cache.load_maps(str(tmp_path / "lm.csv"), "aruco", "aruco_room", {}, owner=owner)
    np.testing.assert_array_equal(m.landmarks[0], [3, 5, 7])  # sorted by id, rows with them
    np.testing.assert_array_equal(m.landmarks[1], pts[[1, 2, 0]])
    assert isinstance(m.frontend, ArucoFrontend) and (m.frontend_kind, m.frontend_map) == (
        "aruco",
        "aruco_room",
    )
    again = cache.load_maps("", "aruco", "aruco_room", {}, owner=owner, current=m)
    assert again.frontend is m.frontend and again.landmarks is None
    other = cache.load_maps("", "aruco", "aruco_room", {"windowed": True}, owner=owner)
    assert other.frontend is not m.frontend and cache.loads == 2  # (the map itself: shared)
    assert cache.load_maps().frontend is None
    cache.release(owner)
    assert len(cache) == 0


def test_load_maps_names_the_parameter_of_a_map_that_does_not_load(tmp_path):
    cache = MapCache()
    with pytest.raises(ValueError, match=r"cannot load landmarks_file .*missing\.csv"):
        cache.load_maps(str(tmp_path / "missing.csv"))
    (tmp_path / "bad.npz").write_text("not a feature map")
    with pytest.raises(ValueError, match=r"cannot load frontend_map .*bad\.npz' \(features\)"):
        cache.load_maps("", "features", str(tmp_path / "bad.npz"))
    os.mkfifo(tmp_path / "fifo.yaml")  # (refused without opening it: no blocking)
    with pytest.raises(ValueError, match=r"cannot load frontend_map .*fifo\.yaml' \(board\)"):
        cache.load_maps("", "board", str(tmp_path / "fifo.yaml"))


def test_front_end_options_from_the_node_parameters():
    from rs_localizer.frontends.marker_detection import DetectorOptions
    from rs_localizer.frontends.registry import FRONTENDS, frontend_kind, frontend_options
    from rs_localizer.ros.params import default_values

    v = default_values()
    assert frontend_options("none", v) == {} and frontend_options("board", v) == {}
    f = frontend_options(
        "features", {**v, "features.matcher": " FLANN ", "features.max_features": 500}
    )
    assert f["matcher"] == "flann" and f["n_features"] == 500 and f["tracking"] is True
    assert frontend_options("features", v)["matcher"] is None  # auto: by the map's descriptors
    a = frontend_options("aruco", {**v, "aruco.windowed": True, "aruco.quad_decimate": 2.0})
    assert a["windowed"] is True and a["detector_options"] == DetectorOptions(quad_decimate=2.0)
    with pytest.raises(ValueError, match=r"unknown features\.matcher 'x'"):
        frontend_options("features", {**v, "features.matcher": "x"})
    with pytest.raises(ValueError, match=r"aruco\.detector options: "):
        frontend_options("aruco", {**v, "aruco.detector": "x"})
    with pytest.raises(ValueError, match="unknown front end"):
        frontend_options("nope", v)
    assert all(frontend_kind(k).map_file for k in FRONTENDS)
