"""Custom ArUco dictionaries from OpenCV's dictionary YAML, in the detector, marker maps and the
ArUco front end: OpenCV's tutorial photo ``gboriginal.png`` (35 markers of the custom
``tutorial_dict.yml``) against OpenCV's own gold corners (skips when
``shared/data/real_markers`` is absent); ``--marker-sizes`` by id range."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import yaml
from helpers.paths import ROOT

from rs_localizer.cli.args import parse_marker_sizes
from rs_localizer.cv_compat import get_dictionary, read_dictionary
from rs_localizer.frontends.aruco import ArucoFrontend
from rs_localizer.frontends.marker_detection import make_marker_detector
from rs_localizer.maps import load_marker_map, write_marker_map

TUTORIAL = next(
    (
        p
        for p in (
            ROOT / ".." / "shared" / "data" / "real_markers" / "opencv_aruco_tutorial",
            ROOT / ".." / ".." / "shared" / "data" / "real_markers" / "opencv_aruco_tutorial",
        )
        if p.is_dir()
    ),
    None,
)
needs_real = pytest.mark.skipif(TUTORIAL is None, reason="shared/data/real_markers is absent")


@needs_real
def test_dictionary_file_is_opencvs():
    """The file read here holds the same codes as OpenCV's own ``readDictionary``."""
    path = TUTORIAL / "tutorial_dict.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    # a dictionary to read into: OpenCV >= 4.7 constructs an empty one; 4.6 (Debian 12) has no
    # usable default constructor (reading into it crashes), so a predefined one is overwritten
    make = getattr(cv2.aruco, "Dictionary_get", None)
    ref = make(cv2.aruco.DICT_4X4_50) if make is not None else cv2.aruco.Dictionary()
    assert ref.readDictionary(fs.root())
    d = get_dictionary(str(path))
    assert (d.markerSize, d.maxCorrectionBits) == (ref.markerSize, ref.maxCorrectionBits)
    np.testing.assert_array_equal(d.bytesList, ref.bytesList)


def _grid_corners() -> dict:
    """The tutorial's grid board (5x7 markers of 0.04 m, 0.01 m apart, ids row by row from the
    printed top-left): corners TL, TR, BR, BL of each, x right and y up on the board."""
    out = {}
    for k in range(35):
        r, c = divmod(k, 5)
        x0, y0 = c * 0.05, -r * 0.05
        out[k] = np.array(
            [[x0, y0, 0], [x0 + 0.04, y0, 0], [x0 + 0.04, y0 - 0.04, 0], [x0, y0 - 0.04, 0]]
        )
    return out


@needs_real
def test_custom_dictionary_finds_every_marker_of_the_real_photo(tmp_path):
    """The detector of a dictionary file finds all 35 markers of ``gboriginal.png`` within
    1.5 px of OpenCV's gold corners (integer pixels, upstream tolerance 1 px); a marker map
    naming the file relative to itself loads it, and its front end gives their 140 corners."""
    gold = json.loads((TUTORIAL / "gold_corners.json").read_text())["gboriginal.png"]["markers"]
    gray = cv2.imread(str(TUTORIAL / "gboriginal.png"), cv2.IMREAD_GRAYSCALE)
    det = make_marker_detector(str(TUTORIAL / "tutorial_dict.yml"))
    corners, ids, _ = det.detect(gray)
    assert sorted(ids.tolist()) == sorted(int(k) for k in gold) and len(ids) == 35
    for c, i in zip(corners, ids, strict=True):
        np.testing.assert_allclose(c, np.reshape(gold[str(i)], (4, 2)), atol=1.5)

    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "dict.yml").write_bytes((TUTORIAL / "tutorial_dict.yml").read_bytes())
    path = write_marker_map(tmp_path / "maps" / "board.yaml", "dict.yml", _grid_corners())
    dictionary, _ = load_marker_map(path)
    assert dictionary == str(tmp_path / "maps" / "dict.yml")
    front = ArucoFrontend.from_file(path)
    corr = front.process(gray)
    assert len(corr.points) == 140


def test_bad_dictionary_files_are_refused(tmp_path):
    """A dictionary file with a missing or malformed entry is refused naming it."""
    bad = tmp_path / "bad.yml"
    bad.write_text('%YAML:1.0\nnmarkers: 2\nmarkersize: 4\nmarker_0: "0101"\n')
    with pytest.raises(ValueError, match="marker_0 must be 16 characters"):
        read_dictionary(bad)
    bad.write_text("%YAML:1.0\nmarkersize: 4\n")
    with pytest.raises(ValueError, match="no 'nmarkers'"):
        make_marker_detector(str(bad))
    with pytest.raises(FileNotFoundError):
        get_dictionary(str(tmp_path / "missing.yaml"))


def test_written_dictionary_round_trips(tmp_path):
    """A dictionary written by OpenCV (``writeDictionary``) reads back with the same codes."""
    src = get_dictionary("DICT_5X5_50")
    path = tmp_path / "d.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    src.writeDictionary(fs)
    fs.release()
    d = read_dictionary(path)
    np.testing.assert_array_equal(d.bytesList, src.bytesList)
    assert (d.markerSize, d.maxCorrectionBits) == (src.markerSize, src.maxCorrectionBits)


def test_marker_sizes_by_id_range(tmp_path):
    """``--marker-sizes``: single ids and inclusive ranges, or a YAML file of them; overlaps,
    reversed ranges and sizes <= 0 are refused."""
    sizes = parse_marker_sizes("0-9:0.165, 10-52:0.1,60:0.3")
    assert len(sizes) == 54 and sizes[0] == sizes[9] == 0.165 and sizes[52] == 0.1
    assert sizes[60] == 0.3 and 53 not in sizes
    f = tmp_path / "sizes.yaml"
    f.write_text(yaml.safe_dump({"0-9": 0.165, 12: 0.3}))
    assert parse_marker_sizes(str(f)) == {**dict.fromkeys(range(10), 0.165), 12: 0.3}
    for bad, msg in (
        ("0-9:0.1,5:0.2", "given twice"),
        ("9-0:0.1", "bad id range"),
        ("3:0", "> 0"),
        ("3", "expected ID:SIZE"),
    ):
        with pytest.raises(ValueError, match=msg):
            parse_marker_sizes(bad)
