"""``rs-localizer lifecycle`` against the real managed node (``rs_localizer_lifecycle_node``
as a subprocess, over DDS), and ``play`` naming a managed node that is not active as the cause
of no answer."""

from __future__ import annotations

import sys
import time

import pytest

pytest.importorskip("rclpy")

pytestmark = pytest.mark.slow  # (a node process started and taken through its transitions)

NS = "/lcc"
NODE = f"{NS}/rs_localizer"
REMAP = {
    "/camera/correspondences": f"{NS}/correspondences",
    "/camera/camera_info": f"{NS}/camera_info",
}


def test_lifecycle_command_and_play_naming_an_inactive_node(
    tmp_path, ros_context, sample_bag, capsys
):
    from helpers.paths import CONFIG

    from rs_localizer.cli import main as cli
    from rs_localizer.ros.bags.play import play
    from rs_localizer.ros.process import NodeProcess, ros_env, write_params_yaml

    overlay = write_params_yaml(
        tmp_path / "p.yaml",
        {"warmup": False},
        reliable_topics=[f"{NS}/correspondences", f"{NS}/camera_info"],
    )
    node = NodeProcess(
        [CONFIG, overlay],
        namespace=NS,
        env=ros_env(),
        executable="rs_localizer_lifecycle_node",
        log=tmp_path / "lc.log",
    )

    def lifecycle(*argv):
        t0 = time.monotonic()
        rc = cli(["lifecycle", *argv])
        out = capsys.readouterr().out.strip()
        print(f"lifecycle {' '.join(argv)}: {time.monotonic() - t0:.2f} s", file=sys.stderr)
        return rc, out

    def play_to_nobody(wait_subscribers):
        """The sample bag in lock-step, giving up after 2 unanswered frames: (result, notes)."""
        notes = []
        res = play(
            sample_bag,
            lockstep=True,
            topics=["/camera/correspondences", "/camera/camera_info"],
            remap=REMAP,
            context=ros_context,
            wait_subscribers=wait_subscribers,
            timeout=0.2,
            retries=0,
            give_up=2,
            log=notes.append,
        )
        return res, notes

    try:
        assert node.wait_ready(60, marker="unconfigured"), node.log
        assert lifecycle(NODE, "get") == (0, "unconfigured")
        # (the graph may still list a managed node another test of this run stopped, as
        # "(no answer)": this one is listed with its state)
        rc, listed = lifecycle("list")
        assert rc == 0 and f"{NODE}: unconfigured" in listed.splitlines(), listed

        # nothing takes the frames: play names the node and the commands, not a remap
        res, notes = play_to_nobody(3.0)
        assert res.answered == 0 and res.gave_up, notes
        assert f"the managed node {NODE} is unconfigured" in res.gave_up
        assert f"rs-localizer lifecycle {NODE} configure" in res.gave_up
        assert "--remap" not in res.gave_up
        assert any(n.startswith("waiting: the managed node") for n in notes), notes

        assert lifecycle(NODE, "configure") == (0, "configure: inactive"), node.log
        rc, out = lifecycle(NODE, "configure")  # (not valid from inactive)
        assert rc == 1 and out.startswith(f"configure refused: {NODE} is inactive"), out
        assert lifecycle(NODE, "get") == (0, "inactive")
        res, notes = play_to_nobody(1.0)
        assert f"the managed node {NODE} is inactive" in res.gave_up, res.gave_up
        assert f"rs-localizer lifecycle {NODE} activate" in res.gave_up

        assert lifecycle(NODE, "activate") == (0, "activate: active"), node.log
        assert lifecycle(NODE, "deactivate") == (0, "deactivate: inactive")
        assert lifecycle(NODE, "cleanup") == (0, "cleanup: unconfigured")
        assert lifecycle(NODE, "shutdown") == (0, "shutdown: finalized")
        # no such managed node: one line, exit code 2
        assert cli(["lifecycle", "/nobody/rs_localizer", "get", "--timeout", "1"]) == 2
        assert "no service /nobody/rs_localizer/get_state" in capsys.readouterr().err
    finally:
        node.stop()
