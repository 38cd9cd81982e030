"""The held-out check of a rig's mountings (benchmarks.held_out): on a synthetic rig whose
mountings are known it ranks the true ones above ones 0.5 deg and 5 mm off; on TagSLAM's
test_2 (skipped when the data is absent) calibrate-rig's mountings, calibrated on the other
part of the video, fit the held-out corners as well as TagSLAM's extrinsics."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.held_out import (
    alone_poses,
    held_out,
    relative_disagreement,
    reprojection,
    split,
)
from benchmarks.tagslam_data import FOLDER, RealRig, load_test2, tag_corners
from rs_localizer.camera import CameraModel


def _synthetic_rig(seed=0, frames=40, noise=0.3):
    """Two cameras 0.2 m apart, the second turned 20 deg about the rig's y axis, before a wall
    of 24 tags (0.15 m) 3 m away; 40 rig poses turned by ~5 deg and moved by ~0.2 m; corners
    projected with ``noise`` px Gaussian noise. Returns the rig (reference poses: the true
    ones turned by ~0.5 deg and moved by ~2 cm, a start to fit from) and the true mountings."""
    rng = np.random.default_rng(seed)
    cam = CameraModel(K=np.array([[600.0, 0, 640], [0, 600.0, 512], [0, 0, 1]]), width=1280,
                      height=1024, distortion_model="none")  # fmt: skip
    cams = {"cam0": cam, "cam1": cam}
    R1 = Rotation.from_euler("y", 20, degrees=True).as_matrix().T  # (rig -> cam1)
    mounts = {"cam0": (np.eye(3), np.zeros(3)), "cam1": (R1, -R1 @ np.array([0.2, 0.0, 0.0]))}
    side = 0.15
    tags = {}
    grid = [(x, y) for x in np.linspace(-1.5, 2.5, 6) for y in (-0.8, 0, 0.8, 1.2)]
    for i, (x, y) in enumerate(grid):
        Rt = Rotation.from_euler("xy", rng.normal(0, 10, 2), degrees=True).as_matrix()
        tags[i] = (Rt, np.array([x, y, 3.0]), side)
    out, reference, ids = [], {}, {}
    for f in range(frames):
        stamp = 0.1 * f
        R = Rotation.from_rotvec(np.deg2rad(5) * rng.normal(size=3) / np.sqrt(3)).as_matrix()
        C = rng.normal(0, 0.2, 3)
        views, tag_ids = {}, {}
        for n, (Rm, cm) in mounts.items():
            uv, X, seen = [], [], []
            for i, (Rt, p, w) in tags.items():
                Xi = tag_corners(w) @ Rt.T + p
                x = cams[n].project((Xi @ R.T + C) @ Rm.T + cm)
                if np.isfinite(x).all() and (x >= 0).all() and (x < [1280, 1024]).all():
                    uv.append(x + rng.normal(0, noise, x.shape))
                    X.append(Xi)
                    seen.append(i)
            if len(seen) >= 2:
                views[n] = (np.concatenate(uv), np.concatenate(X))
                tag_ids[n] = np.array(seen)
        out.append((stamp, views))
        ids[stamp] = tag_ids
        reference[stamp] = (Rotation.from_rotvec(np.deg2rad(0.5) * rng.normal(size=3) / np.sqrt(3))
                            .as_matrix() @ R, C + rng.normal(0, 0.02, 3))  # fmt: skip
    rig = RealRig(cams, mounts, out, reference, "synthetic", tags=tags, tag_ids=ids, anchors=[0])
    return rig, mounts


def _perturbed(mounts, deg, mm, seed=1):
    rng = np.random.default_rng(seed)
    R, c = mounts["cam1"]
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(np.deg2rad(deg) * axis / np.linalg.norm(axis)).as_matrix()
    step = rng.normal(size=3)
    return {**mounts, "cam1": (turn @ R, c + 1e-3 * mm * step / np.linalg.norm(step))}


def test_split_alternates_runs_of_consecutive_rig_frames():
    rig, _ = _synthetic_rig(frames=20)
    a, b = split(rig, 4)  # (runs of 5: frames 0-4 and 10-14, then 5-9 and 15-19)
    assert [s for s, _ in a] == [rig.frames[i][0] for i in [*range(5), *range(10, 15)]]
    assert [s for s, _ in b] == [rig.frames[i][0] for i in [*range(5, 10), *range(15, 20)]]


@pytest.mark.parametrize(("deg", "mm"), [(0.5, 5.0), (0.5, 0.0), (0.0, 5.0)])
def test_the_true_mountings_fit_better_than_perturbed_ones(deg, mm):
    # held-out reprojection with the mountings fixed: the true mountings leave the corners'
    # noise (0.3 px per axis: 0.35 px median distance), a perturbed mounting more (measured:
    # 0.5 deg and 5 mm 2.27 px median; 0.5 deg 2.66; 5 mm 0.54)
    rig, truth = _synthetic_rig()
    frames = [(s, v) for s, v in rig.frames if len(v) == 2]
    assert len(frames) >= 30
    good = reprojection(rig, frames, truth)["error"]
    bad = reprojection(rig, frames, _perturbed(truth, deg, mm))["error"]
    assert np.isfinite(good).all() and np.isfinite(bad).all()
    assert abs(np.median(good) - 0.3 * np.sqrt(2 * np.log(2))) < 0.03
    assert np.median(bad) > 1.3 * np.median(good)
    assert np.sqrt(np.mean(bad**2)) > np.sqrt(np.mean(good**2))


def test_cameras_posed_alone_agree_with_the_true_mountings():
    # the relative pose of the two cameras posed alone, frame by frame: its median is the
    # true mounting's within its noise (measured 0.014 deg, 0.8 mm), 0.49 deg and 4.0 mm from
    # the perturbed one's
    rig, truth = _synthetic_rig()
    poses = alone_poses(rig, rig.frames)
    out = relative_disagreement(
        poses, {"true": truth, "perturbed": _perturbed(truth, 0.5, 5.0)}, [("cam0", "cam1")]
    )
    t, p = out[("cam0", "cam1", "true")], out[("cam0", "cam1", "perturbed")]
    assert t["frames"] >= 30
    assert t["bias_deg"] < 0.05 and t["bias_mm"] < 1.5
    assert abs(p["bias_deg"] - 0.5) < 0.1 and abs(p["bias_mm"] - 5.0) < 2.0
    assert p["median_deg"] > t["median_deg"] and p["median_mm"] > t["median_mm"]


@pytest.mark.skipif(not FOLDER.is_dir(), reason=f"{FOLDER} absent")
def test_calibrate_rig_fits_held_out_corners_as_well_as_tagslams_on_test_2():
    # test_2 on TagSLAM's map, calibrate-rig on alternate runs of the video scored on the
    # others (measured, 333 rig frames, 14912 corners: median 0.303 px against TagSLAM's
    # 0.290, p90 0.619 against 0.648, RMS 0.41 and 0.42; the cameras posed alone: the median
    # relative pose 0.034 deg, 0.8 mm from calibrate-rig's, 0.024 deg, 0.5 mm from TagSLAM's)
    rig = load_test2(FOLDER)
    out = held_out(rig, {"TagSLAM's": rig.mounts}, whole=False)
    ours, theirs = out["scores"]["calibrate-rig"], out["scores"]["TagSLAM's"]
    assert out["frames"] > 300 and ours.corners[-1] == theirs.corners[-1] > 10000
    assert ours.median[-1] < theirs.median[-1] + 0.03
    assert ours.p90[-1] < theirs.p90[-1] + 0.01
    assert ours.rms[-1] < theirs.rms[-1] + 0.02
    a = out["alone"][("cam0", "cam1", "calibrate-rig")]
    assert a["frames"] > 250 and a["bias_deg"] < 0.1 and a["bias_mm"] < 2.0
