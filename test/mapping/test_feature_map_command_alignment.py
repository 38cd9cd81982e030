"""``map-features --images --align-markers --matching sequential`` (the command as a user runs it,
the reconstruction retried when the alignment refuses it) on photos of the rendered
``textured_room`` taken on a weaving walk: the written map against the renderer's ground truth.

The reconstruction runs on one thread with a fixed seed (repeatable: the same photos give the same
model), so the bounds below hold for this model every run; across seeds the same 24 photos give
alignment rotations 0.038-0.078 deg off the best-fit similarity of the points and marker centres
0.09-0.11 px (median).
"""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
import yaml

from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.maps.features import FeatureMap
from rs_localizer.sim.render.motion import base_rotation
from rs_localizer.sim.render.renderer import Renderer, camera_preset
from rs_localizer.sim.render.scene import load_scene

N_PHOTOS = 24


def _walk(n: int) -> list:
    """(camera -> world rotation, centre m) of ``n`` photos: 1.4 m forward through the room,
    weaving +-0.5 m, looking +-35 deg around."""
    out = []
    for s in np.linspace(0.0, 1.0, n):
        pos = np.array(
            [0.6 + 1.4 * s, 0.5 * np.sin(2 * np.pi * s), 1.45 + 0.05 * np.sin(4 * np.pi * s)]
        )
        yaw = np.deg2rad(35 * np.sin(3 * np.pi * s))
        pitch = np.deg2rad(-12 + 6 * np.cos(2 * np.pi * s))
        out.append((base_rotation(yaw, pitch), pos))
    return out


@pytest.mark.slow
def test_sequential_map_is_aligned_on_the_markers(tmp_path, capsys):
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap (extra 'mapping') is not installed")
    from rs_localizer.cli import main
    from rs_localizer.mapping.colmap import align_to_markers, feature_map_from_colmap

    camera = camera_preset("vga", line_delay=0.0)
    renderer = Renderer(load_scene("textured_room"), camera)
    poses = _walk(N_PHOTOS)
    photos = tmp_path / "photos"
    photos.mkdir()
    for k, (R, p) in enumerate(poses):
        cv2.imwrite(str(photos / f"photo_{k:03d}.png"), renderer.render_pose(R, p)[:, :, ::-1])
    cam_yaml = tmp_path / "camera.yaml"
    cam_yaml.write_text(
        yaml.safe_dump(
            {
                "image_width": camera.width,
                "image_height": camera.height,
                "camera_matrix": {"rows": 3, "cols": 3, "data": camera.K.ravel().tolist()},
                "distortion_model": "plumb_bob",
                "distortion_coefficients": {"rows": 1, "cols": 5, "data": camera.D.tolist()},
            }
        )
    )
    work, out = tmp_path / "work", tmp_path / "map.npz"
    argv = ["map-features", "--images", str(photos), "--camera", str(cam_yaml)]
    argv += ["--align-markers", "textured_room", "--matching", "sequential"]
    assert main([*argv, "--workdir", str(work), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    # the first model (sequential matching, seed 0) aligned: nothing refused
    assert "refused first" not in printed and "kept: sequential matching, seed 0" in printed
    rms_mm = float(re.search(r"residual ([0-9.]+) mm RMS", printed).group(1))
    assert rms_mm < 12.0, printed

    fm = FeatureMap.load(out)
    assert fm.metric is True and len(fm) > 2000
    model = work / "model"
    raw = feature_map_from_colmap(model, min_track=3)
    al = align_to_markers(model, photos, "textured_room")
    np.testing.assert_allclose(al.apply(raw.points), fm.points, atol=1e-9)
    assert len(al.markers) >= 8 and np.median(al.reprojection_errors) < 0.15

    # ground truth of each point: the renderer's ray cast of its first observation
    rec = pycolmap.Reconstruction(str(model))
    first = np.empty(len(fm), np.int64)
    uv = np.empty((len(fm), 2))
    for k, pid in enumerate(fm.landmark_ids):
        el = rec.points3D[int(pid)].track.elements[0]
        first[k] = el.image_id
        uv[k] = np.asarray(rec.images[el.image_id].points2D[el.point2D_idx].xy) - 0.5
    truth = np.full((len(fm), 3), np.nan)
    for iid in np.unique(first):
        sel = first == iid
        truth[sel] = renderer.cast(uv[sel], pose=poses[int(rec.images[int(iid)].name[6:9])])[0]
    err = np.linalg.norm(fm.points - truth, axis=1)
    assert np.nanmedian(err) < 0.006, np.nanmedian(err)
    # the alignment's rotation against the best-fit similarity of the model's points to their
    # truth (an independent fit: Umeyama on the points near their truth)
    near = np.isfinite(err) & (err < 3 * np.nanmedian(err))
    Rt, _ = cv2.estimateAffine3D(raw.points[near], truth[near], force_rotation=True)
    assert rotation_angle_deg(al.R, np.asarray(Rt)[:, :3]) < 0.1
