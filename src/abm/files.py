"""Reading and writing files safely: loaders that never run code from a file.

Every file abm reads is data: checkpoints go through :func:`load_torch_data` (``torch.load`` with
``weights_only=True``), YAML through ``yaml.safe_load``, ``.npz`` through ``np.load(allow_pickle=False)``
and HDF5 through h5py (which never unpickles).
"""

from __future__ import annotations

import pickle
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def load_torch_data(path: str | Path, what: str, allowed_globals: Sequence[Any] = (),
                    map_location: Any = "cpu") -> Any:
    """``torch.load(path, weights_only=True)``: tensors and plain data only, so a crafted file cannot run code.

    Args:
        what: what the file should be, for the messages (``"abm policy checkpoint"``).
        allowed_globals: extra classes the file may hold (``torch.serialization.safe_globals``).

    Raises:
        ValueError: the file holds other Python objects (``refusing to load ...``) or cannot be read.
    """
    import torch

    try:
        with torch.serialization.safe_globals(list(allowed_globals)):
            return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as err:
        raise ValueError(
            f"refusing to load {path}: it holds Python objects other than tensors and plain data, which an "
            f"{what} never does (it may be crafted to run code). Details: {str(err).splitlines()[0]}"
        ) from err
    except Exception as err:  # noqa: BLE001 - any other reading failure means a corrupt file
        raise ValueError(f"cannot read {what} {path}: {err}") from err


def load_yaml(path: str | Path, what: str) -> Any:
    """``yaml.safe_load`` of a file (plain data only: a ``!!python/...`` tag is refused, never run).

    Raises:
        ValueError: naming the file, when it is missing, unreadable or not valid (safe) YAML.
    """
    import yaml

    path = Path(path)
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{path}: {what} not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: cannot read the {what} ({err})") from None
    except yaml.YAMLError as err:
        detail = " ".join(str(err).split())
        raise ValueError(f"{path}: not a valid {what} (YAML error: {detail})") from None
