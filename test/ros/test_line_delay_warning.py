"""The node warns once when it runs an image front end with the default line delay (the
user has most likely not set the camera's), and not when the line delay or the readout time
is set."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rclpy")

MARKERS = Path(__file__).resolve().parents[2] / "data" / "sample_images" / "markers.yaml"


@pytest.mark.parametrize(
    "timing, warns",
    [({}, True), ({"rs.line_delay": 6.25e-05}, False), ({"rs.readout_time": 0.03}, False)],
)
def test_default_line_delay_on_images_warns_once(ros_context, capfd, timing, warns):
    from rclpy.parameter import Parameter

    from rs_localizer.ros.node import RSLocalizerNode

    params = {
        "warmup": False,
        "publish_tf": False,
        "frontend": "aruco",
        "frontend_map": str(MARKERS),
        **timing,
    }
    node = RSLocalizerNode(
        "ld_warning",
        context=ros_context,
        namespace="/ldw",
        parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
    )
    try:
        # a parameter change rebuilds the configuration: still one warning at most
        node.set_parameters([Parameter("ransac.threshold_px", value=3.0)])
    finally:
        node.destroy_node()
    err = capfd.readouterr().err
    assert err.count("is the default 30 us/line") == (1 if warns else 0), err
