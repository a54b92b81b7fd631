"""No committed text file names a folder of the machine it was written on (a path under the root folders work,
home, root, tmp or Users): commands, reports and recorded results name paths relative to the checkout, so they hold
on every clone. Files are the tracked ones (``git ls-files``), or the tree without its working folders where git is
not at hand. This file builds its own examples from parts, so it passes its own scan."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MACHINE_PATH = re.compile(r"(?<![\w.~-])/(?:work|home|root|tmp|Users)/[\w.-]")
SKIPPED_DIRS = {".git", ".venv", "runs", "out", "data", "__pycache__", ".pytest_cache", ".ruff_cache", ".mypy_cache",
                "wheels"}


def tracked_files(root: Path) -> list[Path]:
    """The files git tracks under ``root``, else every file outside the working folders."""
    if shutil.which("git") and (root / ".git").exists():
        listing = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
        return [root / name for name in listing.decode().split("\0") if name]
    return [p for p in root.rglob("*") if p.is_file() and not SKIPPED_DIRS & set(p.relative_to(root).parts)]


def machine_paths(root: Path) -> list[str]:
    """``file:line: text`` of every machine-local path in the text files under ``root`` (binary files skipped)."""
    found = []
    for path in tracked_files(root):
        name = path.relative_to(root).as_posix()
        if not path.is_file():
            continue
        data = path.read_bytes()
        if b"\0" in data[:8192]:
            continue
        for number, line in enumerate(data.decode("utf-8", "replace").splitlines(), 1):
            if MACHINE_PATH.search(line):
                found.append(f"{name}:{number}: {line.strip()[:160]}")
    return found


def test_no_committed_file_names_a_machine_folder() -> None:
    found = machine_paths(ROOT)
    assert not found, "machine-local paths in committed files (name them relative to the checkout):\n" + "\n".join(
        found)


def _under(root: str, rest: str) -> str:
    """A machine-like path built from parts, so that this file never spells one out."""
    return "/" + root + "/" + rest


def test_the_scan_sees_a_machine_path_and_leaves_others_alone(tmp_path: Path) -> None:
    (tmp_path / "a.md").write_text("ok: runs/x, https://example.com/home/x, ~/x, a/tmp/b\n")
    model = _under("work", "wt/runs/clip")
    (tmp_path / "b.json").write_text(f'{{"model": "{model}"}}\n')
    (tmp_path / "c.bin").write_bytes(b"\0" + _under("home", "user/x").encode())
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "d.txt").write_text(_under("tmp", "scratch") + "\n")  # a working folder: never committed
    assert machine_paths(tmp_path) == [f'b.json:1: {{"model": "{model}"}}']
