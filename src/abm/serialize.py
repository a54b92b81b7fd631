"""Typed values to JSON and back: what the experiment engine's typed jobs (:mod:`abm.experiments.jobs`) and the
diagnosis requests (:mod:`abm.evaluation.diagnose.request`) use to cross a process boundary as a JSON file.

:func:`json_value` writes a field's value in JSON types; :func:`typed_value` reads it back as the field's type hint
says, so ``typed_value(hint, json_value(v)) == v`` for the field types these dataclasses use (text, numbers,
``Path``, tuples of them, optional ones, typed configs with ``to_dict``/``from_dict``, plain dataclasses of them).
"""

from __future__ import annotations

import types
from collections.abc import Sequence
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Any, Union, get_args, get_origin, get_type_hints


def json_value(value: Any) -> Any:
    """``value`` in JSON types: a typed config by its own ``to_dict``, another dataclass field by field, paths as
    POSIX text, tuples and lists as lists, anything else as it is."""
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if is_dataclass(value) and not isinstance(value, type):
        return {f.name: json_value(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, Path):
        return value.as_posix()
    if isinstance(value, tuple | list):
        return [json_value(v) for v in value]
    return value


def typed_value(hint: Any, value: Any) -> Any:
    """``value`` read back from :func:`json_value`'s form as the type ``hint`` says (an optional one's inner type;
    a sequence as a tuple; ``Path``; a class with ``from_dict`` through it; another dataclass field by field)."""
    if value is None:
        return None
    origin = get_origin(hint)
    if origin in (Union, types.UnionType):
        (inner,) = [a for a in get_args(hint) if a is not type(None)]
        return typed_value(inner, value)
    if origin in (tuple, list, Sequence):
        return tuple(typed_value(get_args(hint)[0], v) for v in value)
    if hint is Path:
        return Path(value)
    if isinstance(hint, type) and hasattr(hint, "from_dict"):
        return hint.from_dict(value)
    if isinstance(hint, type) and is_dataclass(hint):
        hints = get_type_hints(hint)
        return hint(**{k: typed_value(hints[k], v) for k, v in value.items()})
    return value
