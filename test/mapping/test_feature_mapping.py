"""Feature maps from photos: renders of textured_room taken on a slow walk (global shutter)
reconstructed by pycolmap, aligned on the scene's markers, checked against the renderer's
ground truth, then rolling-shutter frames localized against the map."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rs_localizer.frontends.features import FeatureFrontend, make_detector
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.maps.features import FeatureMap
from rs_localizer.sim.feature_map import photo_walk
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import NoiseModel, Renderer, camera_preset
from rs_localizer.sim.render.scene import load_scene

N_PHOTOS = 24


@pytest.fixture(scope="module")
def colmap_map(tmp_path_factory):
    pytest.importorskip("pycolmap", reason="pycolmap (extra 'mapping') is not installed")
    from rs_localizer.mapping.colmap import (
        align_feature_map,
        align_to_markers,
        feature_map_from_colmap,
        reconstruct,
    )

    root = tmp_path_factory.mktemp("colmap")
    photos = root / "photos"
    photos.mkdir()
    scene = load_scene("textured_room")
    camera = camera_preset("vga", line_delay=0.0)
    renderer = Renderer(scene, camera)
    poses = photo_walk(N_PHOTOS)
    for k, (R, p) in enumerate(poses):
        cv2.imwrite(str(photos / f"photo_{k:03d}.png"), renderer.render_pose(R, p)[:, :, ::-1])
    model = reconstruct(photos, camera, root / "work", progress=None, matching="exhaustive")
    fm = feature_map_from_colmap(model, min_track=3)
    alignment = align_to_markers(model, photos, "textured_room")
    return dict(
        root=root,
        photos=photos,
        model=model,
        raw=fm,
        map=align_feature_map(fm, alignment),
        alignment=alignment,
        scene=scene,
        camera=camera,
        renderer=renderer,
        poses=poses,
    )


@pytest.mark.slow
def test_reconstructed_map_matches_ground_truth(colmap_map, tmp_path):
    """Median 3D point error after the marker alignment, against the renderer's ray cast of
    each point's first observation (pycolmap's track, COLMAP pixel - 0.5)."""
    import pycolmap

    from rs_localizer.mapping.colmap import align_to_markers

    fm, raw, al = colmap_map["map"], colmap_map["raw"], colmap_map["alignment"]
    rec = pycolmap.Reconstruction(str(colmap_map["model"]))
    assert rec.num_reg_images() >= 0.8 * N_PHOTOS
    assert len(fm) > 2000 and len(np.unique(fm.landmark_ids)) == len(fm)
    assert fm.metric is True and raw.metric is False
    assert (fm.track_length >= 3).all() and np.isfinite(fm.reprojection_error).all()
    first = np.empty(len(fm), np.int64)  # image of each point's first observation
    uv = np.empty((len(fm), 2))  # its pixel (OpenCV convention)
    for k, pid in enumerate(fm.landmark_ids):
        pt = rec.points3D[int(pid)]
        assert len(pt.track.elements) == fm.track_length[k]
        el = pt.track.elements[0]
        first[k] = el.image_id
        uv[k] = np.asarray(rec.images[el.image_id].points2D[el.point2D_idx].xy) - 0.5
    truth = np.full((len(fm), 3), np.nan)
    for iid in np.unique(first):
        R, p = colmap_map["poses"][int(rec.images[int(iid)].name[6:9])]
        sel = first == iid
        truth[sel] = colmap_map["renderer"].cast(uv[sel], pose=(R, p))[0]
    err = np.linalg.norm(fm.points - truth, axis=1)
    assert np.nanmedian(err) < 0.01, np.nanmedian(err)
    # the alignment: all ten markers, a residual of the order of the point error
    assert len(al.markers) >= 6 and al.residual_rms < 0.02
    np.testing.assert_allclose(al.apply(raw.points), fm.points)
    # refined on the marker detections, it turns the map less than the similarity from the
    # triangulated corners alone does, against the best-fit similarity of the model's points
    # to their ground truth (an independent fit: Umeyama on the points)
    near = np.isfinite(err) & (err < 3 * np.nanmedian(err))
    Rt, _ = cv2.estimateAffine3D(raw.points[near], truth[near], force_rotation=True)
    best = np.asarray(Rt)[:, :3]
    corners_only = align_to_markers(
        colmap_map["model"], colmap_map["photos"], "textured_room", refine=False
    )
    refined, triangulated = rotation_angle_deg(al.R, best), rotation_angle_deg(corners_only.R, best)
    assert refined < 0.04 and refined < triangulated, (refined, triangulated)
    assert len(al.reprojection_errors) >= 4 * len(al.markers)
    assert np.median(al.reprojection_errors) < 0.5 and len(corners_only.reprojection_errors) == 0
    # quality survives the file; filtering on it
    back = FeatureMap.load(fm.save(tmp_path / "map.npz"))
    np.testing.assert_array_equal(back.track_length, fm.track_length)
    np.testing.assert_allclose(back.reprojection_error, fm.reprojection_error)
    assert back.metric is True
    long = back.subset(back.track_length >= 5)
    assert 0 < len(long) < len(back) and (long.track_length >= 5).all()


def _localize(feature_map, camera, scene, times):
    from rs_localizer.estimation.estimate import estimate_rs_pose

    renderer = Renderer(scene, camera, noise=NoiseModel())
    motion = make_motion("shake", scene, duration=2.0)
    fe = FeatureFrontend(feature_map)
    out = []
    for i, t in enumerate(times):
        f = renderer.render(motion, t, rng=i)
        uv, X, _ = fe.process(f.image, camera)
        row = []
        for solver in ("r6p_1lin", "p3p"):
            est = estimate_rs_pose(uv, X, camera, solver)
            assert est.success, (solver, t, est.failure)
            row += [
                rotation_angle_deg(est.pose.orientation, f.orientation),
                np.linalg.norm(est.pose.position - f.position),
            ]
        out.append(row)
    return np.median(np.array(out), axis=0)


@pytest.mark.slow
def test_rolling_shutter_frames_localize_against_the_map(colmap_map):
    """RS frames (hand-held shake, 30 ms readout) against the reconstruction: close to the
    ground truth (within 0.1 deg and 5 mm: the map's alignment on the marker detections) and
    to the same frames against the renderer-built map; the RS solver beats the global-shutter
    P3P in rotation on the same matches."""
    from rs_localizer.sim.feature_map import build_feature_map

    scene = colmap_map["scene"]
    camera = camera_preset("vga")
    times = np.linspace(0.2, 1.8, 4)
    rot, pos, rot_p3p, _ = _localize(colmap_map["map"], camera, scene, times)
    assert rot < 0.1 and pos < 0.005, (rot, pos)
    assert rot_p3p > 3 * rot
    motion = make_motion("shake", scene, duration=2.0)
    ref = build_feature_map(
        scene, colmap_map["camera"], (motion, np.linspace(0.0, 2.0, 6)), kind="sift"
    )
    ref_rot, ref_pos, _, _ = _localize(ref, camera, scene, times)
    # the map's keypoints, seen from the photos' viewpoints, not the frames', set the floor
    # (docs/feature_maps.md): a few times the error against the renderer-built map
    assert rot < 8 * ref_rot and pos < 6 * ref_pos, (rot, ref_rot, pos, ref_pos)


def test_colmap_descriptors_converted_to_opencv_normalisation():
    """RootSIFT (uint8, as COLMAP stores it) of OpenCV SIFT descriptors converts back to
    OpenCV's L2 normalisation."""
    from rs_localizer.mapping.colmap import opencv_sift_from_colmap

    img = load_scene("textured_room")
    cam = camera_preset("vga", line_delay=0.0)
    gray = Renderer(img, cam).render_pose(*photo_walk(3)[1], mono=True)
    _, d = make_detector("sift", 500).detectAndCompute(gray, None)
    root = np.sqrt(d / d.sum(axis=1, keepdims=True))
    colmap = np.clip(np.round(512 * root), 0, 255).astype(np.uint8)
    back = opencv_sift_from_colmap(colmap)
    want = 512 * d / np.linalg.norm(d, axis=1, keepdims=True)
    assert back.dtype == np.float32 and back.shape == d.shape
    # uint8 rounding of the square root: a few units on a 512 scale
    assert np.median(np.linalg.norm(back - want, axis=1)) < 8.0
    np.testing.assert_allclose(np.linalg.norm(back, axis=1), 512, rtol=1e-5)


def test_feature_map_without_quality_still_loads(tmp_path):
    """Maps written before the quality fields load with them unset."""
    p = tmp_path / "old.npz"
    np.savez(
        p,
        points=np.zeros((2, 3)),
        descriptors=np.zeros((2, 32), np.uint8),
        landmark_ids=np.arange(2),
        kind=np.array("orb"),
    )
    fm = FeatureMap.load(p)
    assert fm.track_length is None and fm.reprojection_error is None and fm.metric is None
    np.savez(
        p,
        points=np.zeros((2, 3)),
        descriptors=np.zeros((2, 32), np.uint8),
        landmark_ids=np.arange(2),
        kind=np.array("orb"),
        track_length=np.arange(3),
    )
    with pytest.raises(ValueError, match="quality"):
        FeatureMap.load(p)


@pytest.mark.slow
def test_bad_inputs(colmap_map, tmp_path):
    import pycolmap

    from rs_localizer.mapping.colmap import (
        align_to_markers,
        feature_map_from_colmap,
        read_model,
        reconstruct,
    )
    from rs_localizer.maps import load_marker_map, write_marker_map

    model, photos = colmap_map["model"], colmap_map["photos"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="not a COLMAP sparse model"):
        read_model(tmp_path / "empty")
    with pytest.raises(FileNotFoundError):
        read_model(tmp_path / "nowhere")
    other = tmp_path / "other.db"
    pycolmap.Database.open(str(other)).close()
    with pytest.raises(ValueError, match="not this model's"):
        feature_map_from_colmap(model, other)
    with pytest.raises(ValueError, match="no 3D point"):
        feature_map_from_colmap(model, min_track=10_000)
    small = camera_preset("vga", line_delay=0.0)
    small = type(small)(K=small.K / 2 + np.diag([0, 0, 0.5]), width=320, height=240)
    with pytest.raises(ValueError, match="320x240"):
        reconstruct(photos, small, tmp_path / "w1", progress=None)
    assert not (tmp_path / "w1").exists()
    blank = tmp_path / "blank"
    blank.mkdir()
    for k in range(4):
        cv2.imwrite(str(blank / f"b{k}.png"), np.full((480, 640), 128, np.uint8))
    with pytest.raises(ValueError, match="registered 0 of 4"):
        reconstruct(blank, colmap_map["camera"], tmp_path / "w2", progress=None)
    dictionary, corners = load_marker_map("textured_room")
    two = write_marker_map(tmp_path / "two.yaml", dictionary, {k: corners[k] for k in (0, 1)})
    with pytest.raises(ValueError, match="found 2"):
        align_to_markers(model, photos, two)
    moved = dict(corners)
    moved[0], moved[2] = corners[2], corners[0]  # two markers swapped in the map
    bent = write_marker_map(tmp_path / "moved.yaml", dictionary, moved)
    with pytest.raises(ValueError, match="residual"):
        align_to_markers(model, photos, bent)


@pytest.mark.slow
def test_map_features_command(colmap_map, tmp_path, capsys):
    """The command writes the aligned map; refuses to overwrite; bad input: exit 2, no file."""
    from rs_localizer.cli import main

    model, photos = str(colmap_map["model"]), str(colmap_map["photos"])
    out = tmp_path / "map.npz"
    args = ["map-features", "--colmap", model, "--images", photos, "-o", str(out)]
    assert main([*args, "--align-markers", "textured_room"]) == 0
    printed = capsys.readouterr().out
    assert "aligned on markers" in printed and "mm RMS" in printed
    fm = FeatureMap.load(out)
    np.testing.assert_allclose(fm.points, colmap_map["map"].points, atol=1e-9)
    before = out.read_bytes()
    assert main(args) == 2 and "--overwrite" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert main([*args, "--overwrite"]) == 0
    assert "no metric scale" in capsys.readouterr().out and FeatureMap.load(out).metric is False
    bad = tmp_path / "bad.npz"
    assert main(["map-features", "--colmap", photos, "-o", str(bad)]) == 2
    assert "not a COLMAP sparse model" in capsys.readouterr().err
    camera = tmp_path / "camera.yaml"
    camera.write_text(
        "image_width: 320\nimage_height: 240\n"
        "camera_matrix: {rows: 3, cols: 3, data: [260, 0, 160, 0, 260, 120, 0, 0, 1]}\n"
    )
    assert main(["map-features", "--images", photos, "--camera", str(camera), "-o", str(bad)]) == 2
    assert "320x240" in capsys.readouterr().err
    assert main([*args[:-2], "-o", str(bad), "--align-markers", str(tmp_path / "none.yaml")]) == 2
    assert not bad.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "camera.yaml",
        "map.npz",
    ]


def test_map_features_without_pycolmap_says_how_to_install(monkeypatch, tmp_path, capsys):
    import sys

    from rs_localizer.cli import main

    monkeypatch.setitem(sys.modules, "pycolmap", None)
    out = tmp_path / "map.npz"
    assert main(["map-features", "--colmap", str(tmp_path), "-o", str(out)]) == 2
    assert "pip install 'rs_localizer[mapping]'" in capsys.readouterr().err
    assert not out.exists()


def test_flann_matcher_finds_the_same_landmarks_as_brute_force():
    """Approximate (FLANN) matching of an image against a map made of its own features: each
    feature finds its own landmark, as with brute force; ORB maps refuse FLANN."""
    gray = Renderer(load_scene("textured_room"), camera_preset("vga", line_delay=0.0)).render_pose(
        *photo_walk(3)[1], mono=True
    )
    kps, des = make_detector("sift", 1500).detectAndCompute(gray, None)
    uv = np.array([k.pt for k in kps])
    fm = FeatureMap(np.c_[uv, np.zeros(len(uv))], des, np.arange(len(uv)), "sift")
    found = {}
    for matcher in ("bf", "flann"):
        px, X, ids = FeatureFrontend(fm, matcher=matcher, n_features=1500).process(gray, None)
        np.testing.assert_allclose(X[:, :2], px, atol=1e-3)  # matched to its own feature
        found[matcher] = set(ids.tolist())
    assert len(found["flann"]) > 0.9 * len(found["bf"]) > 0.5 * len(uv)
    with pytest.raises(ValueError, match="flann"):
        orb = FeatureMap(fm.points, np.zeros((len(uv), 32), np.uint8), fm.landmark_ids, "orb")
        FeatureFrontend(orb, matcher="flann")
