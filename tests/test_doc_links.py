"""Every relative link in README.md and docs/ points at a file or folder of the checkout, and every #anchor at a
heading (or an explicit ``id``/``name``) of its page, with GitHub's anchor rules: lower case, punctuation other
than ``-`` and ``_`` dropped, spaces to ``-``, a repeated heading gets ``-1``, ``-2``..."""

from __future__ import annotations

import os
import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
FENCE = re.compile(r"^\s*(```|~~~)")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s*\[[^\]]+\]:\s*(\S+)", re.M)
HTML = re.compile(r"""(?:href|src)\s*=\s*["']([^"']+)["']""")
EXPLICIT = re.compile(r"""<a\s+(?:name|id)\s*=\s*["']([^"']+)["']|\bid\s*=\s*["']([^"']+)["']""")
CODE = re.compile(r"`+[^`]*`+")
#: links to a section being written (page: target -> what is coming); remove an entry once its section is in
PENDING: dict[str, str] = {}


def prose(text: str) -> list[str]:
    """The page's lines outside fenced code blocks."""
    lines, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        lines.append("" if fenced else line)
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor of a heading's text."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # links: their text
    text = re.sub(r"<[^>]+>", "", text).replace("`", "").strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)  # \w keeps letters, digits and _ of every script
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every anchor a link into ``page`` may name."""
    found: set[str] = set()
    counts: dict[str, int] = {}
    for line in prose(page.read_text()):
        for match in EXPLICIT.finditer(line):
            found.add(match.group(1) or match.group(2))
        heading = re.match(r"^\s{0,3}#{1,6}\s+(.*?)\s*#*\s*$", line)
        if heading:
            base = slug(heading.group(1))
            n = counts.get(base, 0)
            counts[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def links(page: Path) -> list[tuple[int, str]]:
    """``(line number, target)`` of every link on the page outside code."""
    out = []
    for number, line in enumerate(prose(page.read_text()), 1):
        line = CODE.sub("", line)
        out += [(number, m.group(1)) for m in LINK.finditer(line)]
        out += [(number, m.group(1)) for m in HTML.finditer(line)]
        out += [(number, m.group(1)) for m in REFERENCE.finditer(line)]
    return out


@cache
def tracked() -> frozenset[str] | None:
    """The files git tracks (a link must reach one as GitHub shows the repository: not through a symlinked
    folder such as configs/, which GitHub does not follow); ``None`` outside a checkout."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    return frozenset(name for name in out.decode().split("\0") if name)


def on_github(path: Path) -> bool:
    """Whether ``path`` (lexical, inside the repository) is a tracked file or a folder holding one."""
    files = tracked()
    if files is None:
        return path.exists()
    name = path.relative_to(ROOT).as_posix()
    return name in files or any(f.startswith(name + "/") for f in files) or name == "."


def broken(page: Path) -> list[str]:
    bad = []
    for number, target in links(page):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("//"):
            continue  # https:, mailto:, ...: not checked here
        path, _, anchor = target.partition("#")
        file = Path(os.path.normpath(page.parent / path)) if path else page
        where = f"{page.relative_to(ROOT)}:{number}: {target}"
        if f"{page.relative_to(ROOT)}: {target}" in PENDING:
            continue
        if not file.is_relative_to(ROOT):
            bad.append(f"{where} (outside the repository)")
        elif not on_github(file):
            bad.append(f"{where} (no such file in the repository{' as GitHub shows it' if file.exists() else ''})")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            bad.append(f"{where} (no heading #{anchor} in {file.relative_to(ROOT)})")
    return bad


def test_slugs_follow_githubs_rules():
    assert slug("Where a training step goes") == "where-a-training-step-goes"
    assert slug("`abm eval`: seeds & protocol (v2)") == "abm-eval-seeds--protocol-v2"
    assert slug("Table 1 — CLIP masks") == "table-1--clip-masks"
    assert slug("[GPU](docs/performance.md) guide") == "gpu-guide"


def test_repeated_headings_get_numbered_anchors(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("# Results\n\n## Results\n\n```\n# not a heading\n```\n<a id=\"here\"></a>\n")
    assert anchors(page) == {"results", "results-1", "here"}


def test_broken_links_are_found(tmp_path, monkeypatch):
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    monkeypatch.setitem(globals(), "tracked", lambda: None)
    (tmp_path / "a.md").write_text("# Top\n[ok](#top) [bad](#nope) [gone](b.md) `[code](x.md)` [web](https://x.y)\n")
    assert broken(tmp_path / "a.md") == ["a.md:2: #nope (no heading #nope in a.md)",
                                         "a.md:2: b.md (no such file in the repository)"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    assert not broken(page), "broken links:\n" + "\n".join(broken(page))
