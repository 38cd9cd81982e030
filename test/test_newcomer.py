"""tools/newcomer.py (``make newcomer``): it finds the docs' shell commands, runs the quick
ones, and every figure it checks is quoted by its page next to a command the page shows.
Cheap: nothing is run here but the page parsing (``make newcomer`` runs the commands)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("newcomer", ROOT / "tools" / "newcomer.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["newcomer"] = mod  # (its dataclasses look their module up)
    spec.loader.exec_module(mod)
    return mod


def test_commands_are_found_and_classified():
    nc = _tool()
    readme = nc.shell_commands("README.md")
    assert "make demo" in readme and "make test" in readme
    node = next(c for c in readme if c.startswith(".venv/bin/rs_localizer_node"))
    play = readme[readme.index(node) + 1]
    assert play == ".venv/bin/rs-localizer play data/sample --lockstep"
    assert nc.why_skipped(node) == "" and nc.why_skipped(play) == ""
    assert nc.why_skipped("make demo") and nc.why_skipped("rs-localizer replay BAG --json")
    assert nc.why_skipped("rs-localizer map-features --images photos/ -o map.npz")
    assert nc.why_skipped(".venv/bin/rs-localizer export-image /tmp/x docs/debug_image.png")
    for page in nc.PAGES:  # every page parses and every command gets a verdict
        for c in nc.shell_commands(page):
            assert isinstance(nc.why_skipped(c), str), c
    assert "-o map.npz" in " ".join(nc.shell_commands("docs/feature_maps.md"))  # (joined \\)


def test_every_checked_figure_is_quoted_next_to_its_command():
    nc = _tool()
    assert nc.FIGURES
    for fig in nc.FIGURES:
        text = (ROOT / fig.page).read_text()
        cmds = nc.shell_commands(fig.page) + nc.INLINE_COMMANDS.get(fig.page, [])
        assert any(fig.command in c and not nc.why_skipped(c) for c in cmds), fig
        quoted = f"{fig.value:g}"
        assert quoted in text or f"{fig.value}" in text, (fig.page, quoted)
