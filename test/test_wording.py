"""What users read says what and why: no tracker numbers ("issue 12") in the package, its
configuration, launch files and documentation, no development narrative ("this round", "as
before") in the documentation, and no paths to files that do not ship (``shared/paper``).
References to upstream projects written ``owner/repo#N`` (e.g. ``opencv/opencv#25539``) are
allowed. Also: every relative link in README.md and docs/ points to an existing file, and every
``#anchor`` in such a link to a heading of that file.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

TRACKER = re.compile(r"\bissues? \d+", re.IGNORECASE)
UNSHIPPED = re.compile(r"shared/paper")
# development narrative: words about how the code got here, not what it is
NARRATIVE = re.compile(
    r"\bthis round\b|\bas before\b|\bstill to be taken\b|\bother developers\b|"
    r"\bmeasured in issue\b|\bbefore issue\b",
    re.IGNORECASE,
)


def _docs() -> list:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _user_facing() -> list:
    """The package's sources and data files, its configuration, launch files and docs."""
    pkg = ROOT / "rs_localizer"
    files = [*pkg.rglob("*.py"), *pkg.rglob("*.yaml")]
    for d in ("config", "launch"):
        files += [p for p in (ROOT / d).rglob("*") if p.is_file()]
    files += _docs()
    return sorted(p for p in set(files) if "__pycache__" not in p.parts)


def _hits(files, pattern: re.Pattern) -> list:
    out = []
    for path in files:
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if pattern.search(line):
                out.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    return out


def test_no_tracker_numbers():
    hits = _hits(_user_facing(), TRACKER)
    assert not hits, "tracker numbers (say what and why instead):\n" + "\n".join(hits)


def test_no_paths_that_do_not_ship():
    hits = _hits(_user_facing(), UNSHIPPED)
    assert not hits, "paths that do not ship (cite the paper instead):\n" + "\n".join(hits)


def test_no_development_narrative_in_the_docs():
    hits = _hits(_docs(), NARRATIVE)
    assert not hits, "development narrative (say what and why instead):\n" + "\n".join(hits)


def test_the_patterns():
    assert TRACKER.search("as measured in Issue 15") and TRACKER.search("issues 10 and 11")
    assert not TRACKER.search("opencv/opencv#25539") and not TRACKER.search("no issue here")
    assert NARRATIVE.search("What made it cheaper this round")


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but ``-`` and ``_`` dropped,
    spaces to ``-``."""
    text = re.sub(r"`", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set:
    out, fenced = set(), False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            out.add(_slug(line.lstrip("#")))
    return out


def _links(path: Path):
    fenced = False
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            continue
        for m in LINK.finditer(re.sub(r"`[^`]*`", "", line)):
            yield n, m.group(1)


def test_relative_links_point_to_existing_files_and_headings():
    bad = []
    for doc in _docs():
        for n, target in _links(doc):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
                continue
            file_part, _, anchor = target.partition("#")
            dest = (doc.parent / file_part).resolve() if file_part else doc
            where = f"{doc.relative_to(ROOT)}:{n}: {target}"
            if not dest.exists():
                bad.append(f"{where} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                bad.append(f"{where} (no such heading)")
    assert not bad, "broken links:\n" + "\n".join(bad)


def test_the_link_check_sees_the_links():
    targets = [t for _, t in _links(ROOT / "README.md")]
    assert "docs/node.md" in targets and "docs/debug_image.png" in targets, targets
    assert _slug("What it sees: debug_image, markers, path") == (
        "what-it-sees-debug_image-markers-path"
    )
    assert _slug("From the distro's packages (Debian 12, Ubuntu 24.04)") == (
        "from-the-distros-packages-debian-12-ubuntu-2404"
    )
