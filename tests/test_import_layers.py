"""Imports flow one way: types (and the small helpers errors, machine, workers, configuration, files,
schema, lazy, progress, ray_pool, registry, measured, serialize) -> geometry
-> render / sim -> language (instruction understanding: the benchmark's tasks and catalog are its vocabulary)
-> grounding -> samples -> data -> policy -> train -> evaluation / robot / viewer / zoo / gym
-> clip_training (the benchmark CLIP's trainer) -> experiments (the experiment engine) -> cli (the command line:
parsers in ``abm.cli.<group>``, command functions in ``abm.cli.commands.<group>``).

Checked on the source text (every ``import`` statement, at module level or inside functions), so a
backwards import cannot hide in a function body. Also checked: no library module imports the command line or
the CLIP trainer; the import graph has no cycle (at module level, nor with the imports inside functions added);
at most :data:`MAX_FUNCTION_IMPORTS` imports of ``abm`` modules sit inside functions, each with a comment giving
its reason.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import abm
from abm.lazy import type_checking_exports

ROOT = Path(abm.__file__).parent
LAYERS = [
    ("types", "errors", "machine", "workers", "configuration", "files", "schema", "lazy", "progress", "ray_pool",
     "registry", "measured", "serialize"),
    ("geometry",),
    ("render", "sim"),
    ("language",),  # reads the tasks' skills and the object catalog (sim); nothing here grounds or renders
    ("grounding",),  # grounds the object the instruction names (language) in the points (render: mask views)
    ("samples",),
    ("data",),  # below policy: the dataset yields policy-independent samples
    ("policy",),
    ("train",),
    ("evaluation", "robot", "viewer", "zoo", "gym"),  # gym: the tasks as gymnasium environments
    ("clip_training",),  # uses sim, grounding and render; only the command line, tests and benchmarks use it
    ("experiments",),  # the experiment engine: typed jobs in their own processes, the reports
    ("cli",),
]
RANK = {name: i for i, names in enumerate(LAYERS) for name in names}
#: packages no library module may import (only each other, tests and benchmarks)
APPLICATIONS = ("abm.cli", "abm.clip_training")
#: imports of ``abm`` modules inside functions: each one is an optional heavy dependency or the command line's
#: start-up time, said in a comment on its line
MAX_FUNCTION_IMPORTS = 25


def layer(module: str) -> int:
    """Layer of an ``abm`` module (its first package below ``abm``)."""
    parts = module.split(".")
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


def module_name(path: Path, root: Path = ROOT) -> str:
    return ".".join((root.name, *path.relative_to(root).with_suffix("").parts)).removesuffix(".__init__")


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def module_level_imports(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """Import statements that run when the module is imported: outside functions and ``if TYPE_CHECKING:``
    blocks (class bodies, ``try``/``if`` blocks included)."""
    found: list[ast.Import | ast.ImportFrom] = []

    def visit(nodes: list[ast.stmt]) -> None:
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                found.append(node)
            elif isinstance(node, ast.If) and _is_type_checking(node):
                visit(node.orelse)
            else:
                for child in ast.iter_child_nodes(node):
                    if isinstance(child, ast.ExceptHandler):
                        visit(child.body)
                for field in ("body", "orelse", "finalbody"):
                    if isinstance(getattr(node, field, None), list):
                        visit(getattr(node, field))

    visit(tree.body)
    return found


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports at module level. ``from a.b import c`` counts as an import
    of ``a.b`` (and of ``a.b.c`` when that is a module, or of the module a lazy export ``c`` of ``a.b`` comes
    from); importing a module imports its parent packages, so those count too, except a module's own parents
    (they are always initialised first)."""
    modules = {module_name(p, root): p for p in root.rglob("*.py")}
    lazy = {m: type_checking_exports(p) for m, p in modules.items() if p.name == "__init__.py"}
    graph: dict[str, set[str]] = {}
    for me, path in modules.items():
        is_package = path.name == "__init__.py"
        targets: set[str] = set()
        for node in module_level_imports(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                base = node.module or ""
                if node.level:
                    parts = me.split(".") if is_package else me.split(".")[:-1]
                    parts = parts[:len(parts) - node.level + 1]
                    base = ".".join([*parts, *([node.module] if node.module else [])])
                names = [base, *(f"{base}.{a.name}" for a in node.names),
                         *(lazy[base][a.name] for a in node.names if a.name in lazy.get(base, {}))]
            for name in names:
                parts = name.split(".")
                targets |= {".".join(parts[:k]) for k in range(1, len(parts) + 1)} & modules.keys()
        graph[me] = {t for t in targets if t != me and not me.startswith(t + ".")}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle (``[a, b, ..., a]``) of ``graph``, or ``None``."""
    state: dict[str, int] = {}  # 1: on the current path, 2: finished
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start)):
            return cycle
    return None


def function_level_imports(path: Path, package: str = "abm") -> list[tuple[str, int, str]]:
    """``(imported module, line, the line's text)`` of every import of a ``package`` module inside a function
    (``if TYPE_CHECKING:`` blocks excluded)."""
    source = path.read_text()
    lines = source.splitlines()
    found = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit_stmt(sub, in_function)
                continue
            visit_stmt(child, in_function)

    def visit_stmt(child: ast.AST, in_function: bool) -> None:
        if in_function and isinstance(child, (ast.Import, ast.ImportFrom)):
            if isinstance(child, ast.ImportFrom):
                names = [child.module or ""] if child.level == 0 else [f"{package}."]  # relative: inside it
            else:
                names = [a.name for a in child.names]
            for name in names:
                if name == package or name.startswith(f"{package}."):
                    found.append((name, child.lineno, lines[child.end_lineno - 1]))
        visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)))

    visit(ast.parse(source), False)
    return found


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


def test_no_library_module_imports_the_command_line_or_the_clip_trainer() -> None:
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        me = module_name(path)
        if me.startswith(APPLICATIONS):
            continue
        for other, line in imports(path):
            if other.startswith(APPLICATIONS):
                bad.append(f"{path.relative_to(ROOT.parent)}:{line}: {me} imports {other}")
    assert not bad, "library modules importing an application package:\n" + "\n".join(bad)


def test_the_check_sees_a_backwards_import(tmp_path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from abm.train.loop import train\n")
    assert imports(bad) == [("abm.train.loop", 2)]
    assert layer("abm.train.loop") > layer("abm.policy.keyframe_policy") > layer("abm.data.keyframes")
    assert layer("abm.cli.commands.data") == layer("abm.cli") > layer("abm.clip_training.train")
    assert layer("abm.clip_training.data") > layer("abm.sim.cameras") and layer("abm.clip_training") > layer(
        "abm.grounding.clip")
    assert layer("abm.grounding.conditioning") > layer("abm.language.roles") > layer("abm.sim.tasks")


def test_the_module_level_import_graph_has_no_cycle() -> None:
    graph = import_graph(ROOT)
    assert "abm.sim.tasks.base" in graph["abm.sim.splits"] or "abm.sim.tasks" in graph["abm.sim.splits"]
    cycle = find_cycle(graph)
    assert cycle is None, "module-level import cycle: " + " -> ".join(cycle or ())


def test_the_cycle_check_sees_a_crafted_cycle(tmp_path) -> None:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from pkg.sub import b  # a package importing its module: no cycle\n")
    (pkg / "sub" / "a.py").write_text("from typing import TYPE_CHECKING\n\nfrom pkg.sub.b import g\n\n"
                                      "if TYPE_CHECKING:\n    from pkg.c import h\n")
    (pkg / "sub" / "b.py").write_text("def g():\n    from pkg.sub import a  # in a function: no cycle\n")
    (pkg / "c.py").write_text("from pkg.sub import a\n")
    (pkg / "lazy.py").write_text("")
    (pkg / "d.py").write_text("from pkg import late\n")
    graph = import_graph(pkg)
    assert graph["pkg.d"] == set()  # `late` is no module of pkg ...
    (pkg / "__init__.py").write_text("from typing import TYPE_CHECKING\n\nfrom pkg.lazy import lazy_exports\n\n"
                                     "if TYPE_CHECKING:\n    from pkg.c import late\n\n"
                                     "__getattr__, __dir__ = lazy_exports(__name__, __file__)\n")
    graph = import_graph(pkg)
    assert graph["pkg.d"] == {"pkg.c"}  # ... but a lazy export of pkg.c: importing it imports pkg.c
    assert graph["pkg.sub.a"] == {"pkg.sub.b"} and graph["pkg.c"] == {"pkg.sub", "pkg.sub.a"}
    assert find_cycle(graph) is None
    (pkg / "sub" / "b.py").write_text("try:\n    from .. import c\nexcept ImportError:\n    pass\n")
    cycle = find_cycle(import_graph(pkg))
    assert cycle is not None and cycle[0] == cycle[-1] and {"pkg.sub.b", "pkg.c"} <= set(cycle), cycle


def full_import_graph(root: Path) -> dict[str, set[str]]:
    """:func:`import_graph` plus the imports of ``abm`` modules inside functions (each imports its module and
    that module's packages when the function runs)."""
    graph = import_graph(root)
    modules = set(graph)
    for path in root.rglob("*.py"):
        me = module_name(path, root)
        for name, _, _ in function_level_imports(path, root.name):
            parts = name.split(".")
            targets = {".".join(parts[:k]) for k in range(1, len(parts) + 1)} & modules
            graph[me] |= {t for t in targets if t != me and not me.startswith(t + ".")}
    return graph


def test_no_import_cycle_also_through_the_imports_inside_functions() -> None:
    """A function-level import does not make a cycle legal: two modules that need each other are one module,
    or a third holds what both need. (A registry's ``"module:attribute"`` text is no import.)"""
    cycle = find_cycle(full_import_graph(ROOT))
    assert cycle is None, "import cycle through function-level imports: " + " -> ".join(cycle or ())


def test_the_full_graph_sees_a_cycle_through_a_function(tmp_path) -> None:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.b import g\n")
    (pkg / "b.py").write_text("def g():\n    from pkg.a import f  # a reason\n")
    assert find_cycle(import_graph(pkg)) is None
    cycle = find_cycle(full_import_graph(pkg))
    assert cycle is not None and {"pkg.a", "pkg.b"} <= set(cycle)


def test_few_abm_imports_inside_functions_each_with_its_reason() -> None:
    found = [(path, *hit) for path in sorted(ROOT.rglob("*.py")) for hit in function_level_imports(path)]
    listing = "\n".join(f"{p.relative_to(ROOT.parent)}:{line}: {text.strip()}" for p, _, line, text in found)
    assert len(found) <= MAX_FUNCTION_IMPORTS, (
        f"{len(found)} imports of abm modules inside functions (at most {MAX_FUNCTION_IMPORTS}); import at module "
        f"level unless it pulls an optional heavy dependency or slows `abm --help`:\n{listing}")
    silent = [f"{p.relative_to(ROOT.parent)}:{line}" for p, _, line, text in found if "#" not in text]
    assert not silent, "function-level imports without a '# reason' comment:\n" + "\n".join(silent)


def test_the_function_import_count_sees_nested_and_skips_type_checking(tmp_path) -> None:
    src = tmp_path / "m.py"
    src.write_text("from typing import TYPE_CHECKING\nimport abm.types\n\n"
                   "def f():\n    import json\n    from abm.files import load_yaml  # optional heavy dependency\n"
                   "    if TYPE_CHECKING:\n        from abm.sim.env import TaskEnv\n\n"
                   "    class C:\n        def g(self):\n            import abm.lazy\n")
    hits = function_level_imports(src)
    assert [(m, line) for m, line, _ in hits] == [("abm.files", 6), ("abm.lazy", 12)]
    assert "#" in hits[0][2] and "#" not in hits[1][2]


def test_every_lazy_package_exports_exactly_its_type_checking_names() -> None:
    """``__all__`` lists the names under ``if TYPE_CHECKING:`` (the one list type checkers read), and each
    resolves at run time to the object of the module it is imported from there."""
    import importlib

    packages = [p for p in sorted(ROOT.rglob("__init__.py")) if "lazy_exports(" in p.read_text()]
    assert len(packages) >= 8
    for path in packages:
        package = importlib.import_module(module_name(path))
        where = type_checking_exports(path)
        assert sorted(package.__all__) == sorted(where), path
        for name, module in where.items():
            assert getattr(package, name) is getattr(importlib.import_module(module), name)


def test_lazy_exports_refuse_other_statements_under_type_checking(tmp_path) -> None:
    init = tmp_path / "__init__.py"
    init.write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from . import sibling\n")
    with pytest.raises(ValueError, match="only absolute `from MODULE import NAME`"):
        type_checking_exports(init)
    init.write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from a.b import c as d, e\n")
    assert type_checking_exports(init) == {"d": "a.b", "e": "a.b"}


#: Imports under ``if TYPE_CHECKING:`` that close a circle with the module-level graph (the imported module reaches
#: the importer back at run time). Each names a class for annotations only, from a module the importer must not
#: load when it is imported: docs/architecture.md ("Type-only circles") says why each stays.
TYPE_ONLY_CIRCLES = {
    ("abm.sim.split_file", "abm.sim.tasks.base"),  # Task: the tasks read their split file when they are defined
    ("abm.grounding.config", "abm.grounding.grounders"),  # Grounder: loads torch and CLIP; configs are data
    ("abm.policy.language_config", "abm.policy.language"),  # LanguageEncoder: loads torch; configs are data
}


def type_checking_imports(path: Path, root: Path = ROOT) -> set[str]:
    """The package's modules ``path`` imports inside ``if TYPE_CHECKING:`` blocks."""
    modules = {module_name(p, root) for p in root.rglob("*.py")}
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.If) and _is_type_checking(node):
            for sub in ast.walk(node):
                if isinstance(sub, ast.ImportFrom) and sub.module and sub.level == 0:
                    for name in (f"{sub.module}.{a.name}" for a in sub.names):
                        found |= {name, sub.module} & modules
    return found


def type_only_circles(root: Path) -> set[tuple[str, str]]:
    """``(importer, imported)`` for every type-only import whose module reaches the importer at module level (a
    package's own lazy exports, names of its submodules under ``TYPE_CHECKING``, are no circle: the package never
    imports them at run time, and the submodule imports the package first anyway)."""
    graph = import_graph(root)

    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            node = todo.pop()
            if node == goal:
                return True
            if node not in seen:
                seen.add(node)
                todo += graph.get(node, ())
        return False

    return {(module_name(p, root), other) for p in root.rglob("*.py")
            for other in type_checking_imports(p, root)
            if reaches(other, module_name(p, root)) and not other.startswith(module_name(p, root) + ".")}


def test_every_type_only_circle_is_one_the_architecture_explains() -> None:
    assert type_only_circles(ROOT) == TYPE_ONLY_CIRCLES
    doc = (ROOT.parents[1] / "docs" / "architecture.md").read_text()
    assert all(f"`{a}`" in doc and f"`{b}`" in doc for a, b in TYPE_ONLY_CIRCLES)


def test_the_circle_check_sees_a_type_only_circle(tmp_path) -> None:
    pkg = tmp_path / "abm"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from abm.b import B\n")
    (pkg / "b.py").write_text("from abm.a import x\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from abm.b import B\n")
    assert type_only_circles(pkg) == {("abm.a", "abm.b")}
