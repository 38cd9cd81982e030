"""Installed data files: ``repo_file`` finds config/data in ``<prefix>/share/rs_localizer`` (the
ament index, a pip venv) when not run from the source tree."""

import sys
from pathlib import Path

from rs_localizer.ros import process


def test_repo_file_finds_the_ament_share(tmp_path, monkeypatch):
    prefix = tmp_path / "install" / "rs_localizer"
    cfg = prefix / "share" / "rs_localizer" / "config" / "only_installed.yaml"
    cfg.parent.mkdir(parents=True)
    cfg.write_text("x: 1\n")
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"/nonexistent:{prefix}")
    assert prefix / "share" / "rs_localizer" in process.share_dirs()
    assert process.repo_file("config", "only_installed.yaml") == cfg
    assert process.repo_file("config", "nowhere.yaml") is None
    # the source tree's own files still come first (next to the package)
    assert (
        process.repo_file("config", "rs_localizer.yaml")
        == Path(process.__file__).resolve().parents[2] / "config" / "rs_localizer.yaml"
    )


def test_share_dirs_of_a_venv_install():
    dirs = process.share_dirs()
    assert Path(sys.prefix) / "share" / "rs_localizer" in dirs
