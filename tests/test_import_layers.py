"""Imports flow one way: types (and the small helpers machine, workers, configuration, files,
schema, lazy, progress, ray_pool) -> geometry
-> render / grounding / sim -> samples -> data -> policy -> train -> evaluation / robot -> commands (quickstart, zoo,
cli, every ``*.commands`` module).

Checked on the source text (every ``import`` statement, at module level or inside functions), so a
backwards import cannot hide in a function body.
"""

from __future__ import annotations

import ast
from pathlib import Path

import abm

ROOT = Path(abm.__file__).parent
LAYERS = [
    ("types", "machine", "workers", "configuration", "files", "schema", "lazy", "progress", "ray_pool"),
    ("geometry",),
    ("render", "grounding", "sim"),
    ("samples",),
    ("data",),  # below policy: the dataset yields policy-independent samples
    ("policy",),
    ("train",),
    ("evaluation", "robot", "viewer"),
    ("quickstart", "zoo", "cli", "commands"),
]
RANK = {name: i for i, names in enumerate(LAYERS) for name in names}


def layer(module: str) -> int:
    """Layer of an ``abm`` module (``*.commands`` modules are the command line's, the top layer)."""
    parts = module.split(".")
    if parts[-1] == "commands":
        return RANK["commands"]
    if parts[1] not in RANK:
        raise AssertionError(f"{module}: package {parts[1]!r} is in no layer; add it to LAYERS")
    return RANK[parts[1]]


def imports(path: Path) -> list[tuple[str, int]]:
    """``(imported abm module, line)`` of every absolute import in a file."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found += [(n, node.lineno) for n in names if n.startswith("abm.")]
    return found


def module_name(path: Path) -> str:
    return ".".join(("abm", *path.relative_to(ROOT).with_suffix("").parts)).removesuffix(".__init__")


def test_imports_flow_one_way() -> None:
    backwards = []
    files = sorted(ROOT.rglob("*.py"))
    assert len(files) > 50
    for path in files:
        me = module_name(path)
        if me == "abm":
            continue
        for other, line in imports(path):
            if layer(other) > layer(me):
                backwards.append(f"{path.relative_to(ROOT.parent)}:{line}: {me} imports {other}")
    assert not backwards, "imports against the layer order:\n" + "\n".join(backwards)


def test_the_check_sees_a_backwards_import(tmp_path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from abm.train.loop import train\n")
    assert imports(bad) == [("abm.train.loop", 2)]
    assert layer("abm.train.loop") > layer("abm.policy.keyframe_policy") > layer("abm.data.keyframes")
    assert layer("abm.data.commands") == layer("abm.cli")
