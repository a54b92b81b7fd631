"""Lazy package exports: ``from abm.render import OrthographicRenderer`` works as before, but importing the
package (which the parsers in ``abm.cli`` do) no longer imports torch, so ``abm --help`` stays fast.

Usage in a package's ``__init__.py``::

    __getattr__, __dir__ = lazy_exports(__name__, {"abm.render.masks": ("soft_mask", ...), ...})
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any


def lazy_exports(package: str, exports: Mapping[str, Iterable[str]]
                 ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` for ``package`` that import ``module`` when one of its names
    is first used (PEP 562); the value is then cached in the package's namespace."""
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where[name]), name)
        setattr(importlib.import_module(package), name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(where) | set(vars(importlib.import_module(package))))

    return __getattr__, __dir__
