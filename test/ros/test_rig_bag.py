"""Rig bags without ROS: ``make-bag --rig`` writes several unsynchronized cameras, their ground
truth and the node's rig parameters; ``replay`` runs them through the rig mode against the
truth; a camera without mounting is refused naming it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.rig_bags import cut_image, recording_of, rewrite_bag
from helpers.ros import LineLog

pytest.importorskip("rosbags")


def test_make_bag_rig_and_replay(tmp_path, capsys):
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_io import bag_topics
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.ros.param_files import read_params_file
    from rs_localizer.sim.trajectory import default_rig

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "3", "--frames", "12", "--points", "120",
                 "--quiet"]) == 0  # fmt: skip
    topics = bag_topics(bag)
    for n in ("front", "left", "right"):
        assert topics[f"/rig/{n}/correspondences"] == "sensor_msgs/msg/PointCloud2"
        assert topics[f"/rig/{n}/camera_info"] == "sensor_msgs/msg/CameraInfo"
    # the node's parameters: each camera's mounting (its optical frame in base_link) and timing
    p = read_params_file(bag / "rig_params.yaml")
    for c in default_rig(3):
        m = p[f"rig.{c.name}.mounting"]
        assert np.allclose(m[:3], c.p_rig_cam)
        assert p[f"rig.{c.name}.line_delay"] == pytest.approx(c.camera.line_delay)
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["frames_total"] == s["solved"] == s["frames"] == 12 and s["failures"] == {}
    assert s["rot_deg"]["median"] < 0.05 and s["pos_m"]["median"] < 0.005
    # (twist: the fused twist, better than each rig frame's own)
    assert s["angvel"]["median"] < s["own_twist"]["angvel"]["median"]
    assert s["counts"]["left"] == dict(received=12, solved=12, failed=0, skipped=0, pending=0,
                                       points_dropped=0, capped_clouds=0)  # fmt: skip
    # a parameter override: the left camera's mounting 3 deg off -> its points are outliers
    m = list(p["rig.left.mounting"])
    from rs_localizer.geometry import rotvec_to_matrix
    from rs_localizer.ros.conversions import matrix_from_quaternion, quaternion_from_matrix

    R = matrix_from_quaternion(m[3:]) @ rotvec_to_matrix(np.radians([0.0, 3.0, 0.0]))
    res = replay(
        bag, params={"rig.left.mounting": m[:3] + list(quaternion_from_matrix(R))}, progress=None
    )
    assert res.outputs[-1].disagreeing == ("left",)


def test_replay_names_a_camera_that_disagrees_with_the_angle_it_is_off(tmp_path, capsys):
    """A rig bag replayed with the left camera's mounting 5 deg off (a parameter file): the
    cameras' consensus outvotes it, and ``replay`` names it with how far off it is, its
    rotation posed alone against the rig's pose through its mounting: the 5 deg of the
    perturbation (within 0.3 deg); the rig's poses stay within 0.05 deg of the truth. With the
    bag's own mountings no camera is named."""
    from rs_localizer.cli import main
    from rs_localizer.geometry import rotvec_to_matrix
    from rs_localizer.ros.conversions import matrix_from_quaternion, quaternion_from_matrix
    from rs_localizer.ros.param_files import read_params_file

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "3", "--frames", "10", "--points", "120",
                 "--quiet"]) == 0  # fmt: skip
    m = list(read_params_file(bag / "rig_params.yaml")["rig.left.mounting"])
    R = matrix_from_quaternion(m[3:]) @ rotvec_to_matrix(np.radians([0.0, 0.0, 5.0]))
    off = m[:3] + [float(x) for x in quaternion_from_matrix(R)]
    params = tmp_path / "off.yaml"
    params.write_text(
        f"/**/rs_localizer:\n  ros__parameters:\n    rig:\n      left:\n        mounting: {off}\n"
    )
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "--json", "--params-file", str(params)]) == 0
    out = capsys.readouterr()
    s = json.loads(out.out)
    assert s["solved"] == s["frames_total"] == 10 and s["rot_deg"]["median"] < 0.05, s
    assert set(s["disagreeing"]) == {"left"}, s["disagreeing"]
    d = s["disagreeing"]["left"]
    assert d["rig_frames"] >= 8 and abs(d["median_deg"] - 5.0) < 0.3, d
    assert "camera left disagrees with the others in" in out.err, out.err
    assert f"(median {d['median_deg']:.2f} deg off" in out.err
    assert main(["replay", str(bag), "--quiet", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["disagreeing"] == {}


def test_replay_names_a_camera_whose_frames_never_join_the_others(tmp_path, capsys):
    """A rig bag replayed with the left camera's clock 20 ms off (``rig.left.time_offset``
    -0.02 s, its frames put 20 ms early on the rig's clock): its frames are refused, not
    published, and ``replay`` warns as the node's diagnostics do (``frames_apart``), with its
    apparent offsets from the other cameras and the parameter that fixes a constant one; with
    the bag's own timing no camera is named. With its clock 20 ms late its frames join the
    others' next rig frames, stamped where the ground truth has no pose: the report says how
    many posed rig frames its errors leave out."""
    from rs_localizer.cli import main

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "3", "--frames", "20", "--points", "120",
                 "--quiet"]) == 0  # fmt: skip
    capsys.readouterr()
    args = ["replay", str(bag), "--quiet", "--json"]
    assert main([*args, "-p", "rig.left.time_offset:=-0.02"]) == 0
    out = capsys.readouterr()
    s = json.loads(out.out)
    assert s["counts"]["left"]["solved"] == 0 and s["solved"] == 20, s["counts"]
    assert s["rot_deg"]["max"] < 0.35 and s["pos_m"]["max"] < 0.02, s
    line = [x for x in out.err.splitlines() if "never join" in x]
    assert len(line) == 1 and line[0].startswith("warning: camera left: its frames never join")
    assert "ms from front" in line[0] and "set rig.left.time_offset" in line[0], line
    assert main(args) == 0
    assert "never join" not in capsys.readouterr().err
    # left's frames 20 ms late: they join the next rig frames of the others, at stamps the
    # ground truth has none of; the report says how many posed rig frames it leaves out
    late = [*args, "-p", "rig.left.time_offset:=0.02"]
    assert main(late) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["solved"] > s["frames"], s
    assert main([a for a in late if a != "--json"]) == 0
    text = capsys.readouterr().out
    n = s["solved"] - s["frames"]
    assert f"  {n} posed rig frames have no ground truth at their stamp" in text, text


def test_replay_reads_each_cameras_clouds_as_the_rig_node_and_counts_its_rows(tmp_path, capsys):
    """A rig bag of two cameras, the left one's clouds each with 3 rows holding a NaN: the
    replay drops those rows before the rig, counted ``points_dropped`` (3 per left cloud);
    with ``max_points`` below the clouds' size every cloud reaches the rig capped to it,
    counted ``capped_clouds`` per camera (and printed beside the camera's frames), every rig
    frame still posed; without ``max_points`` no cloud is capped and the rig gets every
    finite row of each cloud."""
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.3, num_points=120, seed=3)
    rows = {}  # (camera, stamp ns) -> the finite rows of its cloud
    for f in frames:
        if f.name == "left":
            f.uv = f.uv.copy()
            f.uv[[0, 5, 9], 1] = np.nan
        rows[(f.name, f.stamp_ns)] = len(f.uv) - 3 * (f.name == "left")
    bag = write_rig_bag(tmp_path / "rig", frames, cams, traj)
    n = {c: sum(f.name == c for f in frames) for c in ("front", "left")}
    cap = min(rows.values()) - 10
    assert cap >= 20  # (enough for a pose; well below every cloud)

    full = replay(bag, progress=None)
    for c in ("front", "left"):
        assert full.camera_counts[c]["received"] == n[c]
        assert full.camera_counts[c]["capped_clouds"] == 0
    assert full.camera_counts["front"]["points_dropped"] == 0
    assert full.camera_counts["left"]["points_dropped"] == 3 * n["left"]
    for o in full.outputs:
        for c, f in o.frames.items():
            assert len(f.points2d) == rows[(c, f.stamp_ns)]
            assert np.isfinite(f.points2d).all()

    capped = replay(bag, params={"max_points": cap}, progress=None)
    for c in ("front", "left"):
        assert capped.camera_counts[c]["capped_clouds"] == n[c]
    assert capped.camera_counts["left"]["points_dropped"] == 3 * n["left"]
    assert capped.solved == len(capped.outputs) == full.solved == len(full.outputs)
    assert all(len(f.points2d) == cap for o in capped.outputs for f in o.frames.values())

    params = tmp_path / "cap.yaml"
    params.write_text(f"/**/rs_localizer:\n  ros__parameters:\n    max_points: {cap}\n")
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "--params-file", str(params)]) == 0
    out = capsys.readouterr().out
    assert f"left: received {n['left']}, " in out
    assert f"points_dropped {3 * n['left']}, capped_clouds {n['left']}" in out


def test_replay_refuses_a_camera_without_mounting(tmp_path, capsys):
    from rs_localizer.cli import main

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "2", "--frames", "2", "--points", "60",
                 "--quiet"]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "-p", "rig.cameras:=[front, left, back]"]) == 2
    err = capsys.readouterr().err
    assert "invalid parameters: " in err and "rig camera 'back' has no mounting" in err, err


def test_replay_of_a_rig_bag_refuses_a_single_cameras_options_and_names_its_parameters(
    tmp_path, capsys
):
    """A single camera's replay options have no use on a rig bag: each is refused naming what
    the rig takes instead (rather than ignored); a single camera's parameters set in a
    parameter file or with -p (e.g. one shared with camera nodes) are named in a warning,
    the front end too (a rig bag is replayed from its clouds), and the rig frames are posed
    as without them."""
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.replay import replay

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "2", "--frames", "4", "--points", "80",
                 "--quiet"]) == 0  # fmt: skip
    for option, says in (
        (["--solver", "p3p"], "--solver does not apply to a rig bag: the rig estimator"),
        (["--image-topic", "/cam/image_raw"], "<namespace>/<camera>/image_raw"),
        (["--imu-topic", "/imu"], "the rig's gyro is <namespace>/imu"),
        (["--source", "image"], "--source does not apply to a rig bag"),
    ):
        capsys.readouterr()
        assert main(["replay", str(bag), "--quiet", *option]) == 2
        assert says in capsys.readouterr().err, option
    for given in ({"source": "image"}, {"image_topic": "/cam/image_raw"}, {"imu_topic": "/imu"}):
        with pytest.raises(ValueError, match=f"{next(iter(given))}: not for a rig bag"):
            replay(bag, progress=None, **given)  # (the library's replay too)
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)
    args = ["-p", "solver:=p3p", "-p", "camera.fx:=500.0", "-p", "camera_frame:=cam"]
    assert main(["replay", str(bag), "--quiet", "--json", *args]) == 0
    out = capsys.readouterr()
    warnings = [x for x in out.err.splitlines() if x.startswith("warning: ")]
    assert warnings == [
        "warning: a single camera's parameters set but not used in the rig mode: solver (the "
        "rig estimator solves every camera's points at once, gr6p_1lin); camera.fx (each rig "
        "camera's intrinsics are those of its camera_info); camera_frame (each rig camera's "
        "pose on the rig is rig.<camera>.mounting, in base_frame)",
    ], warnings
    assert json.loads(out.out)["rot_deg"] == plain["rot_deg"]
    # a front end needs the cameras' images, which a make-bag rig bag does not have
    assert main(["replay", str(bag), "--quiet", "-p", "frontend:=aruco"]) == 2
    assert "the rig bag has no camera images (/rig/front/image_raw" in capsys.readouterr().err


def test_replay_of_a_rendered_rig_bag_runs_each_cameras_front_end_on_its_images(tmp_path, capsys):
    """With a front end, a rig bag's images are replayed as the rig node takes them: each
    through its camera's front end (the bag's correspondences were made by the same front end
    on the same images, so the poses are those of the clouds' replay), an image another size
    than its camera_info's skipped for that reason and counted for its camera, the rig frame
    posed without it."""
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.replay import replay

    bag = tmp_path / "rig"
    assert main(["render-bag", str(bag), "--rig", "2", "--frames", "4", "--supersample", "1",
                 "--quiet"]) == 0  # fmt: skip
    params = {"frontend": "aruco", "frontend_map": str(bag / "markers.yaml")}
    clouds, images = replay(bag, progress=None), replay(bag, params=params, progress=None)
    assert images.solved == clouds.solved == 4 and images.camera_counts == clouds.camera_counts
    assert [o.cameras for o in images.outputs] == [o.cameras for o in clouds.outputs]
    for a, b in zip(images.outputs, clouds.outputs, strict=True):
        # (each camera frame's rows, stamp and tag: its frame id)
        assert {n: (len(f.points2d), f.stamp_ns, f.tag) for n, f in a.frames.items()} == {
            n: (len(f.points2d), f.stamp_ns, f.tag) for n, f in b.frames.items()
        }
        assert np.abs(a.estimate.model.C - b.estimate.model.C).max() < 1e-5  # (float32 clouds)
        assert a.tags == b.tags
    # the back camera's second image cut to 320 px wide: skipped, the rig frame posed alone
    cut_bag = rewrite_bag(bag, tmp_path / "cut", cut_image("back", 1))
    res = replay(cut_bag, params=params, progress=None)
    assert res.camera_counts["back"]["skipped.image_size_mismatch"] == 1
    assert res.camera_counts["back"]["received"] == 4 and res.solved == 4
    assert sum("back" not in o.cameras for o in res.outputs) == 1


def test_a_rig_names_the_single_cameras_parameters_it_does_not_use():
    """Only a single camera's parameters set to another value than their default are named
    (a list compared element-wise, an int as the float default); every parameter the rig
    refuses to change as unused has its reason."""
    from rs_localizer.ros.config import (
        RIG_UNUSED_PARAMETERS,
        rig_change_refused,
        rig_unused,
        rig_unused_text,
    )
    from rs_localizer.ros.params import PARAMETERS

    defaults = {n: p.default for n, p in PARAMETERS.items()}
    assert rig_unused(defaults) == () and rig_unused_text(()) is None
    # a rig of one camera at the identity mounting is solved with ``solver``: used, and a
    # change of it taken at run time
    assert rig_unused({**defaults, "solver": "p3p"}) == ("solver",)
    assert rig_unused({**defaults, "solver": "p3p"}, single=True) == ()
    assert rig_change_refused(["solver"], single=True) is None
    assert rig_change_refused(["solver"]).startswith("solver is not used in the rig mode")
    assert rig_unused({**defaults, "camera.d": [0, 0, 0, 0, 0], "camera.fx": 0}) == ()
    changed = {**defaults, "camera_to_base.rotation": [0.0, 0.0, 0.0, 1.0], "solver": "p3p",
               "republish_correspondences": True, "max_points": 10}  # fmt: skip
    assert rig_unused(changed) == ("solver", "camera_to_base.rotation")
    text = rig_unused_text(rig_unused(changed))
    assert text.count("(") == 2 and "max_points" not in text
    for name in PARAMETERS:
        if any(name.startswith(names) for names in RIG_UNUSED_PARAMETERS):
            why = rig_change_refused([name])
            assert why.startswith(f"{name} is not used in the rig mode: ") and why.count(":") == 1


def test_a_recording_of_a_rigs_cameras_is_replayed_with_the_rig_nodes_parameters(tmp_path, capsys):
    """A recording of a rig's cameras (no sequence.json, no ground truth, each camera's
    topics under the recording's namespace, here ``/<camera>/...``) is a rig bag when the
    parameters name ``rig.cameras``: replayed and calibrated as the simulated bag it was
    made from; the bag's namespace is found from the cameras' camera_info topics."""
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_frames import is_rig_bag
    from rs_localizer.ros.bags.bag_io import iter_messages, rig_namespace
    from rs_localizer.ros.bags.replay import replay

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "2", "--frames", "8", "--points", "80",
                 "--quiet"]) == 0  # fmt: skip
    rec, params = recording_of(bag, tmp_path / "recording", tmp_path / "rig.yaml")
    assert not is_rig_bag(rec) and is_rig_bag(rec, [params])
    assert rig_namespace(rec, ["front", "left"]) == "" and rig_namespace(bag) == "/rig"
    assert list(iter_messages(rec, {"/ground_truth/pose"})) == []  # (none of those topics)
    a, b = replay(bag, progress=None), replay(rec, params_files=[params], progress=None)
    assert b.solved == a.solved == 8 and b.camera_counts == a.camera_counts
    assert a.summary["frames"] == 8 and b.summary["frames"] == 0  # (no ground truth)
    for x, y in zip(a.outputs, b.outputs, strict=True):
        assert np.array_equal(x.estimate.model.R, y.estimate.model.R)
    capsys.readouterr()
    assert main(["replay", str(rec), "--params-file", str(params), "--quiet"]) == 0
    assert "solved 8/8 rig frames of 2 cameras" in capsys.readouterr().out
    assert main(["calibrate-rig", str(rec), "--params-file", str(params), "--min-inliers", "8",
                 "-o", str(tmp_path / "calibrated.yaml")]) == 0  # fmt: skip


def test_a_recording_of_keypoints_is_replayed_with_the_landmarks(tmp_path, capsys):
    """A recording whose cameras send keypoints (u, v, id; no correspondences) replayed with
    ``landmarks_file``: each row takes its landmark's point, and the rig frames are the ones
    of the correspondences the keypoints were made from, bit for bit (the table holds the
    clouds' own points); ids not in the table are counted per camera, as the node counts
    them; calibrate-rig reads the same frames."""
    from rosbags.rosbag2 import Writer

    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_frames import read_rig_frames
    from rs_localizer.ros.bags.bag_io import (
        RosbagsMessages,
        iter_messages,
        storage_plugin,
        typestore,
    )
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.ros.conversions import stamp_to_ns
    from rs_localizer.ros.pointcloud import read_correspondences

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "2", "--frames", "8", "--points", "80",
                 "--quiet"]) == 0  # fmt: skip
    ts, clouds = typestore(), []
    for topic, mt, t, raw in iter_messages(bag):
        if topic.endswith("/correspondences"):
            clouds.append((topic, t, ts.deserialize_cdr(raw, mt)))
    xyz = [read_correspondences(m).xyz.astype(np.float64) for _, _, m in clouds]
    points, index = np.unique(np.concatenate(xyz), axis=0, return_inverse=True)
    ids = 500 + np.arange(len(points))
    lines = [
        ",".join([str(i), *map(repr, map(float, q))]) for i, q in zip(ids, points, strict=True)
    ]
    table = tmp_path / "landmarks.csv"
    table.write_text("id,x,y,z\n" + "\n".join(lines) + "\n")
    rec, params = recording_of(bag, tmp_path / "recording", tmp_path / "rig.yaml")
    keyed = tmp_path / "keypoints"
    make = RosbagsMessages()
    with Writer(keyed, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns, start, unknown = {}, 0, 0
        for topic, mt, t, raw in iter_messages(rec):
            if topic.endswith("/correspondences"):  # (as keypoints, one of an unknown id more)
                m = ts.deserialize_cdr(raw, mt)
                c = read_correspondences(m)
                rows = ids[index.ravel()[start : start + len(c.uv)]]
                start += len(c.uv)
                uv, rows, unknown = np.vstack([c.uv, [[5.0, 5.0]]]), np.r_[rows, 3], unknown + 1
                m = make.keypoints(uv, rows, stamp_to_ns(m.header.stamp), m.header.frame_id)
                topic, raw = (
                    topic.replace("/correspondences", "/keypoints"),
                    ts.serialize_cdr(m, mt),
                )
            if topic not in conns:
                conns[topic] = w.add_connection(topic, mt, typestore=ts)
            w.write(conns[topic], t, raw)
    a = replay(rec, params_files=[params], progress=None)
    b = replay(keyed, params_files=[params], params={"landmarks_file": str(table)}, progress=None)
    assert a.solved == b.solved == 8
    for x, y in zip(a.outputs, b.outputs, strict=True):
        assert np.array_equal(x.estimate.model.R, y.estimate.model.R)
        assert np.array_equal(x.estimate.model.C, y.estimate.model.C)
    unread = sum(b.camera_counts[n].get("unknown_landmark_ids", 0) for n in b.cameras)
    assert unread == unknown == 16
    frames = read_rig_frames(keyed, [params], {"landmarks_file": str(table)}).frames
    assert len(frames) == 16 and all(len(f.points2d) > 0 for f in frames)


@pytest.mark.parametrize("solver", [None, "p3p"])
def test_a_cameras_bag_replayed_as_a_rig_of_one_is_the_cameras_replay(sample_bag, solver):
    """A camera alone is a rig of one: the sample bag (one camera) replayed through the rig
    mode with ``rig.cameras: [camera]`` at the identity mounting and the camera's RS timing
    gives the camera's replay, every row's pose and twist errors bit for bit (the rig's row is
    stamped at its reference time, the camera's at its header stamp; both publish at the
    reference time); with the parameter ``solver`` too, which the rig of one is solved with
    (and does not name as unused)."""
    from rs_localizer.ros.bags.replay import replay

    timing = {"rs.line_delay": 3e-05, "rs.direction": "top_to_bottom",
              "rs.reference_row": 359.5, "rs.stamp_row": 0.0}  # fmt: skip
    rig = {"rig.cameras": ["camera"], "rig.camera.mounting": [0.0] * 6 + [1.0], **timing}
    chosen = {} if solver is None else {"solver": solver}
    cam = replay(sample_bag, params=chosen)
    one = replay(sample_bag, params={**rig, **chosen}, progress=None)
    assert one.solver == cam.config.solver == (solver or "r6p_1lin")
    assert one.solved == len(cam.rows) == len(one.rows) == 30 and not one.notes
    for a, b in zip(cam.rows, one.rows, strict=True):
        assert a["out_stamp_ns"] == b["out_stamp_ns"] and a["stamp_ns"] < b["stamp_ns"]
        assert {k: v for k, v in a.items() if k not in ("stamp_ns", "time_ms")} == {
            k: v for k, v in b.items() if k not in ("stamp_ns", "time_ms")
        }


def test_make_bag_rig_with_a_gyro_and_replay_it(tmp_path, capsys):
    """``make-bag --rig 2 --imu-rate 400`` writes the rig's gyro on ``/rig/imu`` with
    ``imu.enabled`` and ``imu.rotation`` in the node's parameters; ``replay`` solves every rig
    frame with it (the gyro line of its output: all used); its errors against the truth stay
    within 1.5x those of the replay without the gyro (12 frames)."""
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_io import bag_topics
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.ros.param_files import read_params_file

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "2", "--frames", "12", "--points", "100",
                 "--imu-rate", "400", "--quiet"]) == 0  # fmt: skip
    assert bag_topics(bag)["/rig/imu"] == "sensor_msgs/msg/Imu"
    p = read_params_file(bag / "rig_params.yaml")
    assert p["imu.enabled"] is True and np.allclose(p["imu.rotation"], [0, 0, 0, 1])
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet"]) == 0
    assert "gyro: 12 rig frames used it, 0 contradicted by the image" in capsys.readouterr().out
    with_gyro = replay(bag, progress=None)
    without = replay(bag, params={"imu.enabled": False}, progress=None)
    assert all(o.estimate.gyro_used for o in with_gyro.outputs)
    assert not any(o.estimate.gyro_used for o in without.outputs)
    assert with_gyro.solved == without.solved == 12
    assert with_gyro.counts["frames_with_gyro"] == 12 and without.counts == {}
    a, b = with_gyro.summary, without.summary
    for k in ("rot_deg", "pos_m", "angvel"):  # (angvel: the fused twist's)
        assert a[k]["median"] < 1.5 * b[k]["median"], k


def test_a_rig_bags_replay_counts_the_imu_messages_it_rejects_as_the_rig_node(tmp_path):
    """A ``make-bag --rig 2 --imu-rate 400`` bag copied with 3 of its IMU messages saying they
    carry no angular velocity (``angular_velocity_covariance[0] = -1``) and one message sent
    twice (the same stamp again): the replay counts them as the rig node does,
    ``imu_rejected.no_angular_velocity`` 3 and ``imu_rejected.stamp_not_increasing`` 1 (the
    gyro buffer's reason), ``imu_rejected`` 4; the clean bag counts none."""
    import dataclasses
    import shutil

    from rosbags.rosbag2 import Reader, Writer

    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_io import storage_plugin, typestore
    from rs_localizer.ros.bags.replay import replay

    bag, bad = tmp_path / "rig", tmp_path / "bad"
    assert main(["make-bag", str(bag), "--rig", "2", "--frames", "6", "--points", "60",
                 "--imu-rate", "400", "--quiet"]) == 0  # fmt: skip
    ts = typestore()
    with Reader(bag) as r, Writer(bad, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns = {
            c.id: w.add_connection(c.topic, c.msgtype, typestore=ts, serialization_format="cdr")
            for c in r.connections
        }
        k = 0
        for c, t, raw in r.messages():
            w.write(conns[c.id], t, raw)
            if c.topic != "/rig/imu":
                continue
            k += 1
            if k in (10, 20, 30):  # (written again without its angular velocity)
                m = ts.deserialize_cdr(raw, c.msgtype)
                cov = np.array(m.angular_velocity_covariance, float)
                cov[0] = -1.0
                m = dataclasses.replace(m, angular_velocity_covariance=cov)
                w.write(conns[c.id], t, bytes(ts.serialize_cdr(m, c.msgtype)))
            elif k == 40:  # (the same message again)
                w.write(conns[c.id], t, raw)
    for f in bag.iterdir():
        if f.suffix in (".json", ".yaml", ".csv") and f.name != "metadata.yaml":
            shutil.copy(f, bad / f.name)
    clean, got = replay(bag, progress=None), replay(bad, progress=None)
    assert not any(key.startswith("imu_rejected") for key in clean.counts), clean.counts
    c = got.counts
    assert c["imu_rejected.no_angular_velocity"] == 3, c
    assert c["imu_rejected.stamp_not_increasing"] == 1 and c["imu_rejected"] == 4, c
    assert got.solved == clean.solved


def test_replay_of_a_rig_warns_when_its_video_contradicts_the_cameras_timing(tmp_path, capsys):
    """A 60-frame rig bag of three cameras replayed with their line delays: no timing warning;
    with every camera's line delay doubled (parameters), most rig frames are refused (the
    cameras disagree), and the twists of those posed do not predict the video: ``replay``
    says so, naming the cameras' timing parameters."""
    from rs_localizer.cli import main
    from rs_localizer.ros.param_files import read_params_file

    bag = tmp_path / "rig"
    assert main(["make-bag", str(bag), "--rig", "3", "--frames", "60", "--points", "60",
                 "--quiet"]) == 0  # fmt: skip
    p = read_params_file(bag / "rig_params.yaml")
    assert main(["replay", str(bag), "--quiet"]) == 0
    assert "does not predict the video" not in capsys.readouterr().err
    doubled = [f"-p=rig.{n}.line_delay:={2 * p[f'rig.{n}.line_delay']!r}" for n in p["rig.cameras"]]
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", *doubled]) == 0
    err = capsys.readouterr().err
    assert "warning: the rig frames' rolling-shutter motion does not predict the video" in err
    assert "rig.<camera>" in err


def test_each_cloud_of_a_rig_bag_gets_the_camera_info_of_its_stamp(tmp_path):
    """The frames calibrate-rig and play --lockstep read take the camera model of the newest
    camera_info stamped at or before each cloud, as the rig node does, not the one received
    last: the left camera's camera_info changes (fx 2 % up) at its 5th frame's stamp but is
    received before its 2nd frame. The front camera's first camera_info is missing: its
    first frame, received before any, has no camera model (the node counts it
    ``skipped.no_camera_info``) and joins no rig frame."""
    from dataclasses import replace

    from rs_localizer.ros.bags.bag_frames import read_rig_frames
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.ros.bags.play import rig_frame_grouping
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.3, num_points=80, seed=4)
    clean = write_rig_bag(tmp_path / "clean", frames, cams, traj)
    stamps = {c.name: [f.stamp_ns for f in frames if f.name == c.name] for c in cams}
    change = stamps["left"][4]
    fx = cams[1].camera.K[0, 0]

    def edit(topic, msg, t):
        s = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if topic == "/rig/left/camera_info":
            if s < change:
                return [(t, msg)]
            k, q = msg.k.copy(), msg.p.copy()
            k[0], q[0] = 1.02 * k[0], 1.02 * q[0]
            msg = replace(msg, k=k, p=q)
            # (received at once after the first one: before the clouds stamped before it)
            return [(stamps["left"][0] + 1_500_000, msg)] if s == change else [(t, msg)]
        if topic == "/rig/front/camera_info" and s == stamps["front"][0]:
            return []
        return [(t, msg)]

    bag = rewrite_bag(clean, tmp_path / "changed", edit)
    read = read_rig_frames(bag)
    left = [f for f in read.frames if f.camera_name == "left"]
    assert [f.stamp_ns for f in left] == stamps["left"]
    for f in left:
        want = fx * 1.02 if f.stamp_ns >= change else fx
        assert f.camera.K[0, 0] == pytest.approx(want, rel=1e-9), f.stamp_ns
    front = [f for f in read.frames if f.camera_name == "front"]
    assert front[0].camera is None and all(f.camera is not None for f in front[1:])
    # the grouping play --lockstep waits on is the replay's (the node's reading)
    res = replay(bag, progress=None)
    assert res.camera_counts["front"]["skipped"] == 1  # (no camera model)
    assert rig_frame_grouping(bag)[1] == res.camera_counts["rig"]["rig_frames"]


def test_an_unread_cloud_is_counted_and_grouped_as_the_rig_node_takes_it(tmp_path, capsys):
    """The left camera's clouds 3..8 without their ``x`` field and its cloud 10 with a stamp no
    ROS time holds: the one reader yields each as an unread frame (``bad_input``; the stamp's
    ``bad_stamp``, as the single camera's), so that replay counts them as the rig node does
    (received, ``skipped.bad_input``, handed to the rig, which does not wait for the camera
    at their times; received, ``failed.bad_stamp``, never seen by the rig), calibrate-rig's
    reader leaves them out of its frames and counts them ``bad_input``, ``bad_stamp``
    (printed, in the JSON), and the grouping ``play --lockstep`` waits on is the rig mode's
    with them: the rig frames each of those clouds completes."""
    from helpers.rig_bags import BAD_STAMP, NO_X, bag_with_unread_clouds

    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_frames import read_rig_frames, rig_parameter_values
    from rs_localizer.ros.bags.play import rig_frame_grouping
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.ros.camera_input import DroppedFrame, to_rig
    from rs_localizer.ros.config import build_config
    from rs_localizer.tracking.video import Localizer

    b = bag_with_unread_clouds(tmp_path)
    n = {c: len(s) for c, s in b.stamps.items()}
    bad = len(NO_X) + 1

    read = read_rig_frames(b.bag)
    unread = [f for f in read.items if isinstance(f, DroppedFrame)]
    assert [(f.camera_name, f.stamp_ns) for f in unread if f.stamp_ns is not None] == sorted(
        b.no_x, key=lambda x: x[1]
    )
    assert [f.camera_name for f in unread if f.stamp_ns is None] == ["left"]
    assert [f.reason for f in unread] == ["bad_input"] * len(NO_X) + ["bad_stamp"]
    assert len(read.frames) == len(b.frames) - bad
    assert not any(isinstance(f, DroppedFrame) for f in read.frames)
    assert read.counts["left"]["bad_input"] == len(NO_X) and read.counts["left"]["bad_stamp"] == 1
    assert read.counts["front"]["bad_input"] == 0 and "bad_stamp" not in read.counts["front"]

    res = replay(b.bag, progress=None)
    left = res.camera_counts["left"]
    assert left["received"] == n["left"] and left["skipped.bad_input"] == len(NO_X), left
    assert left["failed.bad_stamp"] == 1, left
    assert left["received"] == left["solved"] + left["failed"] + left["skipped"] + left["pending"]
    assert left["skipped"] == len(NO_X) and "skipped.bad_input" not in res.camera_counts["front"]
    assert left["failed"] == 1 and "failed.bad_stamp" not in res.camera_counts["front"]
    front = res.camera_counts["front"]
    assert front["received"] == front["solved"] == n["front"]
    assert res.solved == len(res.outputs) == res.camera_counts["rig"]["rig_frames"] == n["front"]
    missing = [o for o in res.outputs if "left" not in o.cameras]
    assert len(missing) == bad  # (the stamp the rig cannot read: its rig frame without left)

    # the grouping: the rig mode's, each unread cloud with a stamp handed to it as the node does
    ends, formed = rig_frame_grouping(b.bag)
    values, cam_values = rig_parameter_values(b.bag)
    rig = Localizer(build_config(values, cam_values).settings)
    truth = {}
    for f in read.items:
        k = len(to_rig(rig, f))
        if k:
            truth[(f.camera_name, f.stamp_ns)] = k
    assert ends == truth and formed == rig.counts["rig_frames"] == n["front"]
    assert len(b.no_x & set(ends)) == len(NO_X) - 1  # (each but the first completes one)
    assert ("left", b.stamps["left"][BAD_STAMP]) not in ends

    capsys.readouterr()
    assert main(["calibrate-rig", str(b.bag), "--json", "-o", str(tmp_path / "m.yaml")]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["cameras"]["left"]["bad_input"] == len(NO_X)
    assert json.loads(out.out)["cameras"]["left"]["bad_stamp"] == 1
    line = f"left: points_dropped 0, capped_clouds 0, capped_points 0, bad_input {len(NO_X)}, "
    assert line + "bad_stamp 1 (" in out.err, out.err
    assert "front: points_dropped" not in out.err
    capsys.readouterr()
    assert main(["replay", str(b.bag), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert f", failed.bad_stamp 1, skipped.bad_input {len(NO_X)}" in printed, printed


def test_lockstep_grouping_is_the_rig_s_with_a_slow_camera(tmp_path):
    """A camera at 1 fps beside one at 30 fps (``rig.stop_after`` 0.5 s, shorter than its frame
    interval): the rig does not take it as stopped between its frames, and the
    frames ``play --lockstep`` waits after are those whose arrival completes a rig frame in
    the rig mode solving them (a :class:`Localizer` fed as the node feeds it)."""
    from helpers.rig_bags import rewrite_bag

    from rs_localizer.ros.bags.bag_frames import read_rig_frames, rig_parameter_values
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.ros.bags.play import rig_frame_grouping
    from rs_localizer.ros.camera_input import to_rig
    from rs_localizer.ros.config import build_config
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.video import Localizer

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=3.2, num_points=40, seed=3)
    clean = write_rig_bag(tmp_path / "clean", frames, cams, traj)
    left = [f.stamp_ns for f in frames if f.name == "left"]
    keep = set(left[::30])  # (1 fps)

    def edit(topic, msg, t):
        if topic != "/rig/left/correspondences":
            return [(t, msg)]
        s = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        return [(t, msg)] if s in keep else []

    bag = rewrite_bag(clean, tmp_path / "slow", edit)
    ends, formed = rig_frame_grouping(bag)
    values, cam_values = rig_parameter_values(bag)
    assert float(values["rig.stop_after"]) < 1.0
    rig = Localizer(build_config(values, cam_values).settings)
    truth, with_left = {}, 0
    for f in read_rig_frames(bag).items:
        outs = to_rig(rig, f)
        with_left += sum("left" in o.cameras for o in outs)
        if outs:
            truth[(f.camera_name, f.stamp_ns)] = len(outs)
    assert ends == truth and formed == rig.counts["rig_frames"]
    # (stopped once at most: before its second frame the rig does not know its rate)
    assert rig.counts["left.stopped"] <= 1 and with_left == len(keep)
    # (each slow frame's arrival completes the rig frames the fast camera moved past)
    assert sum(1 for (n, s) in ends if n == "left") >= len(keep) - 2


def test_a_rig_bag_is_replayed_and_reported_as_a_camera_bag_is(tmp_path, capsys):
    """``replay`` of a rig bag reports what a camera's replay does, a rig frame for a frame:
    the JSON has every key of a camera's (and the rig's own: counts, each rig frame's own
    twist, the cameras that disagree), ``--csv`` has a camera's columns with one row per rig
    frame whose pose errors are those of its pose against the bag's ground truth, and
    ``--out`` holds the rig node's outputs: a pose and own twist per posed rig frame and, with
    tracking, each fused twist on ``twist`` and ``odom`` (every rig frame's, the fused poses of
    the library's replay), or without tracking its own twist there."""
    import csv

    from rs_localizer.cli import main
    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros.bags.bag_io import iter_messages, load_ground_truth, typestore
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.ros.bags.replay_out import CSV_COLUMNS
    from rs_localizer.ros.conversions import matrix_from_quaternion

    bag, cam = tmp_path / "rig", tmp_path / "cam"
    for out, more in ((bag, ["--rig", "2"]), (cam, [])):
        assert main(["make-bag", str(out), "--frames", "10", "--points", "100", "--quiet",
                     *more]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["replay", str(cam), "--quiet", "--json"]) == 0
    camera_keys = set(json.loads(capsys.readouterr().out))
    out, table = tmp_path / "out", tmp_path / "rig.csv"
    assert main(["replay", str(bag), "--quiet", "--json", "--csv", str(table), "--out",
                 str(out)]) == 0  # fmt: skip
    s = json.loads(capsys.readouterr().out)
    assert camera_keys <= set(s), camera_keys - set(s)
    assert {"own_twist", "counts", "disagreeing"} <= set(s)
    assert s["frames_total"] == s["solved"] == 10 and s["solver"] == "gr6p_1lin"
    assert s["csv"] == str(table) and s["out_bag"] == str(out)
    with open(table) as f:
        rows = list(csv.DictReader(f))
        assert f.seek(0) == 0 and f.readline().strip().split(",") == CSV_COLUMNS
    assert len(rows) == 10 and all(r["success"] == "True" for r in rows)
    gt = load_ground_truth(bag)
    for r in rows:
        t = gt.nearest(int(r["stamp_ns"]))
        R = matrix_from_quaternion([float(r[f"q{a}"]) for a in "xyzw"])
        assert float(r["err_rot_deg"]) == pytest.approx(
            rotation_angle_deg(R, gt.orientation[t]), abs=1e-5
        )
        p = np.array([float(r[f"p{a}"]) for a in "xyz"])
        assert float(r["err_pos_m"]) == pytest.approx(np.linalg.norm(p - gt.position[t]), abs=1e-7)
    res = replay(bag, progress=None)
    ts = typestore()
    got: dict = {}
    for topic, mt, _, raw in iter_messages(out):
        got.setdefault(topic.rsplit("/", 1)[-1], []).append(ts.deserialize_cdr(raw, mt))
    assert {k: len(v) for k, v in got.items()} == {
        "pose": 10, "twist_single_frame": 10, "pose_with_covariance": 10, "twist": 10, "odom": 10
    }  # fmt: skip
    fused = [f for o in res.outputs for f in o.fused] + res.flushed
    fused = {f.pose.stamp_ns: f.pose.angular_velocity for f in fused}
    for m in got["twist"]:
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        w = [m.twist.angular.x, m.twist.angular.y, m.twist.angular.z]
        assert np.allclose(w, fused[stamp], atol=1e-9) and m.header.frame_id == "base_link"
    # without tracking: twist is each rig frame's own twist
    assert main(["replay", str(bag), "--quiet", "--no-tracking", "--out", str(out),
                 "--overwrite"]) == 0  # fmt: skip
    twists = [ts.deserialize_cdr(raw, mt)
              for _, mt, _, raw in iter_messages(out, {"/rs_localizer/twist"})]  # fmt: skip
    assert len(twists) == 10
    no_track = replay(bag, params={"tracking.enabled": False}, progress=None)
    own = {o.stamp_ns: o.estimate.pose.angular_velocity for o in no_track.outputs}
    for m in twists:
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        assert np.allclose([m.twist.angular.x, m.twist.angular.y, m.twist.angular.z],
                           own[stamp], atol=1e-9)  # fmt: skip


def test_replay_of_a_rendered_rig_bag_writes_each_cameras_debug_outputs(tmp_path, capsys):
    """``replay --out --debug-outputs`` of a rendered rig bag (2 cameras, 3 frames each)
    writes the rig node's visualization topics: for each camera one
    ``/rs_localizer/<camera>/debug_image`` per posed rig frame, of the camera's size (its
    camera_info), stamped like its frame, in its frame id, drawn on the camera's own image of
    that stamp (it correlates with it, not with the other camera's); its ``markers``, whose
    frustum starts at the camera's centre (the ground-truth rig pose at the camera's
    reference line through its mounting) and whose inliers are points of its frame's cloud;
    and the rig's ``path``, after each posed rig frame the poses on ``pose`` so far. With one
    camera frame's image taken out of the bag, that frame's debug image is drawn on a canvas
    (it no longer correlates with the image) and every other frame's on its image still."""
    from rs_localizer.cli import main
    from rs_localizer.ros.bags.bag_io import iter_messages, load_ground_truth, typestore
    from rs_localizer.ros.conversions import stamp_to_ns
    from rs_localizer.ros.image_codec import decode_image
    from rs_localizer.ros.param_files import read_params_file

    bag, out = tmp_path / "rig", tmp_path / "out"
    assert main(["render-bag", str(bag), "--rig", "2", "--frames", "3", "--supersample", "1",
                 "--no-noise", "--quiet"]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "--json", "--out", str(out),
                 "--debug-outputs"]) == 0  # fmt: skip
    s = json.loads(capsys.readouterr().out)
    assert s["solved"] == s["frames_total"] == 3 and s["out_bag"] == str(out)
    ts = typestore()
    cams = ("front", "back")
    size, frame_id, images, clouds = {}, {}, {}, {}
    for topic, mt, _, raw in iter_messages(bag):
        n, leaf = (topic.split("/") + ["", ""])[2:4]
        if n not in cams:
            continue
        m = ts.deserialize_cdr(raw, mt)
        stamp = stamp_to_ns(m.header.stamp)
        if leaf == "camera_info":
            size[n] = (m.width, m.height)
        elif leaf == "image_raw":
            images[(n, stamp)] = decode_image(m)[0]
            frame_id[n] = m.header.frame_id
        elif leaf == "correspondences":
            xyz = np.frombuffer(bytes(m.data), np.float32).reshape(m.width, -1)
            offs = {f.name: f.offset // 4 for f in m.fields}
            clouds[(n, stamp)] = xyz[:, [offs["x"], offs["y"], offs["z"]]].astype(float)
    got: dict = {}
    for topic, mt, t, raw in iter_messages(out):
        got.setdefault(topic, []).append((t, ts.deserialize_cdr(raw, mt)))
    poses = got["/rs_localizer/pose"]
    assert len(poses) == 3
    # the rig's path: the poses published so far
    paths = got["/rs_localizer/path"]
    assert [t for t, _ in paths] == [t for t, _ in poses]
    for k, (_, p) in enumerate(paths):
        assert p.header.frame_id == "map" and len(p.poses) == k + 1
        for q, (_, pose) in zip(p.poses, poses[: k + 1], strict=True):
            assert q.pose.position == pose.pose.position and q.header.stamp == pose.header.stamp
    gt = load_ground_truth(bag)
    params = read_params_file(bag / "rig_params.yaml")
    gray = {k: v.astype(float).mean(axis=2) for k, v in images.items()}
    for n in cams:
        drawn = got[f"/rs_localizer/{n}/debug_image"]
        # one per posed rig frame, stamped like the camera's frames (every one posed here)
        assert [t for t, _ in drawn] == [t for t, _ in poses]
        stamps = [stamp_to_ns(m.header.stamp) for _, m in drawn]
        assert stamps == sorted(s for c, s in images if c == n)
        other = [s for c, s in images if c != n]
        for (_, m), stamp, o in zip(drawn, stamps, other, strict=True):
            assert (m.width, m.height) == size[n] and m.encoding == "bgr8"
            assert m.header.frame_id == frame_id[n]
            img = np.frombuffer(bytes(m.data), np.uint8).reshape(m.height, m.width, 3)
            below = slice(60, None)  # (under the text banner)
            seen = img[below].astype(float).mean(axis=2).ravel()
            mine = np.corrcoef(seen, gray[(n, stamp)][below].ravel())[0, 1]
            twin = cams[cams.index(n) - 1]
            theirs = np.corrcoef(seen, gray[(twin, o)][below].ravel())[0, 1]
            assert mine > 0.8 and theirs < 0.5, (mine, theirs)
        markers = got[f"/rs_localizer/{n}/markers"]
        assert [t for t, _ in markers] == [t for t, _ in poses]
        mount = np.asarray(params[f"rig.{n}.mounting"][:3])
        for (_, m), stamp in zip(markers, stamps, strict=True):
            by = {x.ns: x for x in m.markers}
            ref = stamp_to_ns(by["frustum"].header.stamp)
            g = gt.nearest(ref, tol_ns=100_000)
            centre = gt.position[g] + gt.orientation[g] @ mount
            apex = by["frustum"].points[0]
            assert (
                np.linalg.norm([apex.x - centre[0], apex.y - centre[1], apex.z - centre[2]]) < 0.005
            )
            pts = np.array([[p.x, p.y, p.z] for p in by["inliers"].points])
            cloud = clouds[(n, stamp)]
            assert len(pts) >= 0.9 * len(cloud)
            assert np.abs(pts[:, None, :] - cloud[None]).max(axis=2).min(axis=1).max() < 1e-6

    # the front camera's second image taken out: that frame's debug image on a canvas only
    gone = sorted(s for c, s in images if c == "front")[1]

    def edit(topic, msg, t):
        drop = topic == "/rig/front/image_raw" and stamp_to_ns(msg.header.stamp) == gone
        return [] if drop else [(t, msg)]

    cut, out2 = rewrite_bag(bag, tmp_path / "cut", edit), tmp_path / "out2"
    assert main(["replay", str(cut), "--quiet", "--out", str(out2), "--debug-outputs"]) == 0
    for n in cams:
        for _, mt, _, raw in iter_messages(out2, {f"/rs_localizer/{n}/debug_image"}):
            m = ts.deserialize_cdr(raw, mt)
            stamp = stamp_to_ns(m.header.stamp)
            img = np.frombuffer(bytes(m.data), np.uint8).reshape(m.height, m.width, 3)
            seen = img[60:].astype(float).mean(axis=2).ravel()
            r = np.corrcoef(seen, gray[(n, stamp)][60:].ravel())[0, 1]
            assert (r < 0.5) if (n, stamp) == ("front", gone) else (r > 0.8), (n, stamp, r)


def test_a_rig_camera_s_camera_infos_after_a_time_reset_are_forgotten_as_the_node_forgets_them(
    tmp_path,
):
    """A rig bag whose video plays at T0 + 10 s, then again from T0 (a time reset of the rig,
    ``time_reset_threshold`` 5 s), then at T0 + 3.2 s, each camera with its true camera_info at
    T0 and a wrong one (focal 30 % longer) stamped T0 + 3 s, received first: replay notes each
    frame's stamp on the rig's clock as the rig node does, so each camera forgets the
    camera_info of the old timeline's T0 + 3 s at its first frame after the reset, and the
    frames at T0 + 3.2 s take the true camera."""
    from dataclasses import replace

    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.2, num_points=120, seed=23)
    clean = write_rig_bag(tmp_path / "clean", frames, cams, traj)
    t0 = min(f.stamp_ns for f in frames)
    first_info: dict = {}

    def stamped(msg, ns):
        stamp = replace(msg.header.stamp, sec=ns // 10**9, nanosec=ns % 10**9)
        return replace(msg, header=replace(msg.header, stamp=stamp))

    def edit(topic, msg, t):
        s = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        if topic.endswith("/camera_info"):
            if topic in first_info:
                return []
            first_info[topic] = s
            k, p = msg.k.copy(), msg.p.copy()
            k[0], k[4], p[0], p[5] = 1.3 * k[0], 1.3 * k[4], 1.3 * p[0], 1.3 * p[5]
            wrong = stamped(replace(msg, k=k, p=p), t0 + 3 * 10**9)
            return [(t - 2, wrong), (t - 1, msg)]
        if topic.endswith("/correspondences"):
            shifts = (10 * 10**9, 0, int(3.2e9))  # (log order: +10 s, then 0, then +3.2 s)
            return [(t + i * 10**9, stamped(msg, s + dt)) for i, dt in enumerate(shifts)]
        return []  # (no ground truth: its stamps are the first video's)

    bag = rewrite_bag(clean, tmp_path / "reset", edit)
    res = replay(bag, params={"time_reset_threshold": 5.0}, progress=None)
    assert res.solved > 0
    late = [o for o in res.outputs if o.stamp_ns > t0 + 3 * 10**9 and o.stamp_ns < t0 + 5 * 10**9]
    assert {n for o in late for n in o.frames} == {c.name for c in cams}
    true_k = {c.name: c.camera.K for c in cams}
    for o in late:
        for n, f in o.frames.items():
            np.testing.assert_array_equal(f.camera.K, true_k[n])


def test_a_rig_camera_s_frame_whose_step_raises_fails_and_the_replay_goes_on(tmp_path, monkeypatch):
    """The left camera's 3rd frame's step raises (the rig's frame step, ``Localizer.add``):
    as the rig node takes it, the frame is counted ``failed.internal_error`` (received =
    solved + failed + skipped + pending), logged with the exception, and the replay goes
    on: every rig frame is posed, the left camera's later frames in them."""
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.video import Localizer

    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.3, num_points=120, seed=3)
    bag = write_rig_bag(tmp_path / "rig", frames, cams, traj)
    left = sorted(f.stamp_ns for f in frames if f.name == "left")
    add = Localizer.add

    def failing(self, frame, *args, **kwargs):
        if frame.camera_name == "left" and frame.stamp_ns == left[2]:
            raise RuntimeError("injected fault")
        return add(self, frame, *args, **kwargs)

    monkeypatch.setattr(Localizer, "add", failing)
    log = LineLog()
    res = replay(bag, progress=None, log=log)
    c = res.camera_counts["left"]
    assert c["failed.internal_error"] == c["failed"] == 1 and c["received"] == len(left)
    assert c["received"] == c["solved"] + c["failed"] + c["skipped"] + c["pending"]
    assert log.warnings() == [
        "rig camera 'left': frame failed (internal_error): RuntimeError: injected fault"
    ]
    assert res.solved == len(res.rows) > 0
    later = {f.stamp_ns for o in res.outputs for n, f in o.frames.items() if n == "left"}
    assert set(left[3:]) <= later and left[2] not in later


def test_a_rig_cameras_name_with_spaces_reads_its_parameters_as_the_rig_node_names_it():
    """``rig.cameras: [" front", ...]`` (a quoted name with spaces) names the camera ``front``,
    as the rig node's parameters do: its ``rig.front.*`` values are read, and the rig's
    configuration is that of the names without spaces."""
    from rs_localizer.ros.bags.bag_frames import rig_bag_config, rig_parameter_values

    params = {
        "rig.front.line_delay": 2e-5,
        "rig.front.mounting": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        "rig.left.mounting": [0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
    }
    spaced = {**params, "rig.cameras": [" front", "left "]}
    values, cams = rig_parameter_values(None, params=spaced)
    assert values["rig.cameras"] == ["front", "left"]
    assert list(cams) == ["front", "left"]
    assert cams["front"]["line_delay"] == 2e-5
    assert cams["left"]["mounting"] == [0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    got = rig_bag_config(None, params=spaced)[2].cameras
    plain = rig_bag_config(None, params={**params, "rig.cameras": ["front", "left"]})[2].cameras
    assert [(c.name, c.line_delay, tuple(c.mount.c)) for c in got] == [
        (c.name, c.line_delay, tuple(c.mount.c)) for c in plain
    ]
    assert got[0].line_delay == 2e-5 and got[1].mount.c[0] == -0.1
