"""Names mean one thing: every ``*Error`` is an exception, and no two modules define a class, or a public
module-level constant, of the same name (two ``TrainConfig`` or two ``PLACEHOLDER`` would say two things).

Checked on the source (AST), so a module with an optional heavy dependency is covered without importing it.
"""

from __future__ import annotations

import ast
import importlib
from collections import defaultdict
from pathlib import Path

import abm

ROOT = Path(abm.__file__).parent


def definitions(path: Path) -> tuple[list[str], list[str]]:
    """``(classes, UPPER_CASE constants)`` defined at the module level of one file."""
    tree = ast.parse(path.read_text())
    classes = [n.name for n in tree.body if isinstance(n, ast.ClassDef)]
    constants = [t.id for n in tree.body if isinstance(n, (ast.Assign, ast.AnnAssign))
                 for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
                 if isinstance(t, ast.Name) and t.id.isupper() and not t.id.startswith("_")]
    return classes, constants


def duplicated(files: list[Path]) -> dict[str, list[str]]:
    """Names defined in more than one file -> those files. The task modules (``sim/tasks/``) each set the same
    parameters (``NUM_DISTRACTORS``, ...) for their own task: their constants are theirs alone."""
    where: dict[str, list[str]] = defaultdict(list)
    for path in files:
        classes, constants = definitions(path)
        if path.parent.name == "tasks":
            constants = []
        for name in {*classes, *constants}:
            where[name].append(str(path.relative_to(ROOT.parent)))
    return {name: paths for name, paths in where.items() if len(paths) > 1}


def test_no_name_is_defined_twice() -> None:
    twice = duplicated(sorted(ROOT.rglob("*.py")))
    assert not twice, "defined in several modules:\n" + "\n".join(f"{k}: {v}" for k, v in sorted(twice.items()))


def test_the_check_sees_a_second_definition(tmp_path: Path) -> None:
    (tmp_path / "a.py").write_text("class TrainConfig:\n    pass\nPLACEHOLDER = 'X'\n")
    (tmp_path / "b.py").write_text("from a import TrainConfig\nclass TrainConfig:\n    pass\n_PRIVATE = 1\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path / "pkg"
    try:
        found = duplicated([tmp_path / "a.py", tmp_path / "b.py"])
    finally:
        ROOT = saved
    assert set(found) == {"TrainConfig"}


def test_every_error_class_is_an_exception() -> None:
    records = []
    for path in sorted(ROOT.rglob("*.py")):
        classes, _ = definitions(path)
        errors = [c for c in classes if c.endswith("Error")]
        if not errors:
            continue
        module = importlib.import_module(".".join(("abm", *path.relative_to(ROOT).with_suffix("").parts)))
        records += [f"{module.__name__}.{c}" for c in errors if not issubclass(getattr(module, c), BaseException)]
    assert not records, f"named *Error but not exceptions: {records}"
