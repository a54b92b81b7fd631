"""Lazy package exports: ``from abm.render import OrthographicRenderer`` works as before, but importing the
package (which the parsers in ``abm.cli`` do) does not import torch, so ``abm --help`` stays fast.

A package's ``__init__.py`` names its exports once, as imports under ``if TYPE_CHECKING:`` (what type checkers
and editors read), and hands its own file to :func:`lazy_exports`, which reads that block to import each name
on first use (PEP 562)::

    from typing import TYPE_CHECKING

    from abm.lazy import lazy_exports

    if TYPE_CHECKING:
        from abm.render.masks import soft_mask

    __getattr__, __dir__ = lazy_exports(__name__, __file__)

    __all__ = ["soft_mask"]
"""

from __future__ import annotations

import ast
import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any


def type_checking_exports(init_file: str | Path) -> dict[str, str]:
    """``name -> module`` of the ``from MODULE import NAME`` statements under ``if TYPE_CHECKING:`` in a file."""
    tree = ast.parse(Path(init_file).read_text(encoding="utf-8"))
    where: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for statement in node.body:
                if not isinstance(statement, ast.ImportFrom) or statement.module is None or statement.level:
                    raise ValueError(f"{init_file}: only absolute `from MODULE import NAME` may stand under "
                                     "`if TYPE_CHECKING:` (they are the package's lazy exports)")
                where.update({alias.asname or alias.name: statement.module for alias in statement.names})
    return where


def lazy_exports(package: str, init_file: str | Path) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` for ``package`` (whose ``__init__.py`` is ``init_file``) that
    import a name's module when the name is first used; the value is then cached in the package's namespace."""
    where = type_checking_exports(init_file)

    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where[name]), name)
        setattr(importlib.import_module(package), name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(where) | set(vars(importlib.import_module(package))))

    return __getattr__, __dir__
