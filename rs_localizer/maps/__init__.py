"""Map files: what the world looks like to a front end or the node, independent of how it was
made. One module per format, each with its one writer and its one reader (validation beside
it):

=====================  ===================================================  ==================
module                 format                                               writer / reader
=====================  ===================================================  ==================
:mod:`.markers`        ArUco marker maps (YAML: dictionary + the four 3D    ``write_marker_map``
                       corners of each marker; also scene YAMLs)            / ``load_marker_map``
:mod:`.boards`         board YAMLs (checkerboard, ChArUco, tag boards)      - / ``read_board``
:mod:`.features`       feature maps (``.npz``: 3D points + descriptors)     ``FeatureMap.save``
                                                                            / ``FeatureMap.load``
:mod:`.landmarks`      landmark maps (``id,x,y,z`` CSV, metres)             ``save_landmarks_csv``
                                                                            / ``load_landmarks_csv``
:mod:`.scenes`         scene YAMLs (``rs_localizer/scenes/``): where their  - / ``scene_path``
                       quads, markers and checkerboards are
:mod:`.tag_poses`      marker maps from tag poses (``{id, size, pose}``     ``write_tag_map``
                       YAML, WPILib field JSON, apriltag_ros bundles)       / ``read_tag_layout``
:mod:`.files`          atomic writes, the umask mode, regular-file checks
=====================  ===================================================  ==================

The model layer: front ends, mapping, the simulator and the CLI import these modules, never the
reverse. The names below are re-exported so ``rs_localizer.maps.load_marker_map`` and the like
keep working.
"""

from .files import check_regular_file, file_mode, open_regular_file, write_text_atomic
from .landmarks import load_landmarks_csv, save_landmarks_csv
from .markers import (
    MARKER_SQUARE_TOLERANCE,
    check_marker_corners,
    load_marker_map,
    load_marker_readout,
    load_marker_std,
    marker_dictionary,
    write_marker_map,
)
from .scenes import (
    SCENE_DIR,
    checkerboard_corners,
    checkerboard_layout,
    marker_layout,
    scene_names,
    scene_path,
    scene_quad_frames,
)

__all__ = [
    "MARKER_SQUARE_TOLERANCE",
    "SCENE_DIR",
    "check_marker_corners",
    "check_regular_file",
    "checkerboard_corners",
    "checkerboard_layout",
    "file_mode",
    "load_landmarks_csv",
    "load_marker_map",
    "load_marker_readout",
    "load_marker_std",
    "marker_dictionary",
    "marker_layout",
    "open_regular_file",
    "save_landmarks_csv",
    "scene_names",
    "scene_path",
    "scene_quad_frames",
    "write_marker_map",
    "write_text_atomic",
]
