"""docs/video.md "A video of images in ten lines": the block runs as written on the committed
sample bag and gives every frame a pose within 0.1 deg and 1 cm of the bag's ground truth."""

import re
from pathlib import Path

import numpy as np

from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.ros.bags.bag_io import load_ground_truth

ROOT = Path(__file__).resolve().parents[2]


def _example() -> str:
    text = (ROOT / "docs" / "video.md").read_text()
    section = text.split("## A video of images in ten lines", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_documented_image_video_example_localizes_the_sample_bag(monkeypatch):
    monkeypatch.chdir(ROOT)  # (the block names the bag relative to the repository)
    scope: dict = {}
    exec(compile(_example(), "docs/video.md", "exec"), scope)
    poses = scope["poses"]
    gt = load_ground_truth(ROOT / "data" / "sample_images")
    assert len(poses) == 20 and set(poses) <= set(gt.orientation)
    for stamp, pose in poses.items():
        assert rotation_angle_deg(pose.orientation, gt.orientation[stamp]) < 0.1
        assert np.linalg.norm(pose.position - gt.position[stamp]) < 0.01
