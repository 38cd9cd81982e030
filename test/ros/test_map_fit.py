"""A map that cannot fit the place (mirrored: z -> -z) gives no pose, and the user is told
the map is the likely cause: ``frames_failed_with_matches``, ``map_fit_doubtful`` (the node's
diagnostics keys) and the warning ``rs-localizer replay`` prints; the right map raises no
doubt."""

from __future__ import annotations

import yaml

from rs_localizer.ros.bags.replay import replay


def _mirrored(src, dst):
    m = yaml.safe_load(src.read_text())
    for marker in m["markers"]:
        marker["corners"] = [[x, y, -z] for x, y, z in marker["corners"]]
    dst.write_text(yaml.safe_dump(m))
    return dst


def test_a_mirrored_marker_map_is_named(sample_images_bag, tmp_path):
    mirrored = _mirrored(sample_images_bag / "markers.yaml", tmp_path / "mirrored.yaml")
    params = {"frontend": "aruco", "frontend_map": str(mirrored)}
    res = replay(sample_images_bag, params=params, progress=None)
    assert res.solved == 0 and len(res.rows) >= 10
    assert res.counts["frames_failed_with_matches"] >= 10
    assert res.counts["map_fit_doubtful"] == 1
    text = [n for n in res.notes if "does the map fit this place?" in n]
    assert len(text) == 1 and "mirrored" in text[0] and "another room" in text[0], res.notes
    right = {"frontend": "aruco", "frontend_map": str(sample_images_bag / "markers.yaml")}
    res = replay(sample_images_bag, params=right, progress=None)
    assert res.solved == len(res.rows) and not res.counts.get("map_fit_doubtful")
    assert not any("does the map fit" in n for n in res.notes)
