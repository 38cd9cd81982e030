"""The repository's files the tests read: sample bags and parameter files."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_BAG = ROOT / "data" / "sample"
KEYPOINTS_BAG = ROOT / "test" / "data" / "keypoints"
CONFIG = ROOT / "config" / "rs_localizer.yaml"
IMAGES_CONFIG = ROOT / "config" / "rs_localizer_images.yaml"
SAMPLE_IMAGES_BAG = ROOT / "data" / "sample_images"
