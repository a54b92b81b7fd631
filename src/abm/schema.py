"""Declared schemas for the YAML files abm reads (robot files, and the checks split and template files share).

A schema is a mapping ``key -> Field``; :func:`check_mapping` checks a parsed YAML mapping against it:
unknown keys, missing required keys, and each value's type, shape and range. Every error is a
:class:`SchemaError` naming the file, the key (dotted, e.g. ``limits.workspace_lower``) and what is
expected, e.g. ``robot.yaml: limits.max_step_m: expected a finite number > 0, got nan``.

Numbers are finite: YAML's ``.nan`` and ``.inf`` are refused everywhere, and booleans are not numbers.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from abm.errors import DataError


class SchemaError(DataError):
    """A file that does not match its schema: the message names the file, the key and what is expected."""


class _Mismatch(ValueError):
    """Raised by a value check: its message is what was expected."""


Check = Callable[[Any], Any]


@dataclass(frozen=True)
class Field:
    """One key of a schema: ``check`` converts a value (or raises), ``required`` the key must be present."""

    check: Check
    required: bool = False


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def number(low: float | None = None, high: float | None = None, *, low_open: bool = False) -> Check:
    """A finite real number in ``[low, high]`` (``low_open``: ``low`` itself excluded)."""
    parts = []
    if low is not None:
        parts.append(f"{'>' if low_open else '>='} {low:g}")
    if high is not None:
        parts.append(f"<= {high:g}")
    expected = "a finite number" + (" " + " and ".join(parts) if parts else "")

    def check(value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise _Mismatch(expected)
        x = float(value)
        if not math.isfinite(x) or (low is not None and (x <= low if low_open else x < low)) or \
                (high is not None and x > high):
            raise _Mismatch(expected)
        return x

    return check


def integer(low: int | None = None, high: int | None = None) -> Check:
    """A whole number in ``[low, high]``."""
    bounds = [f">= {low}" if low is not None else "", f"<= {high}" if high is not None else ""]
    expected = "a whole number " + " and ".join(b for b in bounds if b)

    def check(value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or \
                (low is not None and int(value) < low) or (high is not None and int(value) > high):
            raise _Mismatch(expected.strip())
        return int(value)

    return check


def text(choices: tuple[str, ...] | None = None) -> Check:
    """A non-empty string (one of ``choices`` when given)."""
    expected = f"one of {list(choices)}" if choices else "a non-empty string"

    def check(value: Any) -> str:
        if not isinstance(value, str) or not value.strip() or (choices and value not in choices):
            raise _Mismatch(expected)
        return value

    return check


def vector(length: int) -> Check:
    """A list of exactly ``length`` finite numbers, as a tuple of floats."""
    expected = f"a list of {length} finite numbers"
    element = number()

    def check(value: Any) -> tuple[float, ...]:
        if isinstance(value, str) or not isinstance(value, Sequence | np.ndarray) or len(value) != length:
            raise _Mismatch(expected)
        try:
            return tuple(element(v) for v in value)
        except _Mismatch:
            raise _Mismatch(expected) from None

    return check


def any_mapping(value: Any) -> dict[Any, Any]:
    """A mapping whose content is checked elsewhere."""
    if not isinstance(value, Mapping):
        raise _Mismatch("a mapping")
    return dict(value)


def strings(value: Any) -> list[str] | dict[str, str]:
    """A non-empty list of strings, or a non-empty mapping of strings to strings (or numbers)."""
    if isinstance(value, Mapping) and value and all(isinstance(v, str | int) for v in value.values()):
        return {str(k): str(v) for k, v in value.items()}
    if isinstance(value, list) and value and all(isinstance(v, str | int) and not isinstance(v, bool)
                                                 for v in value):
        return [str(v) for v in value]
    raise _Mismatch("a non-empty list of names, or a mapping name -> serial")


def check_mapping(path: str | Path, where: str, data: Any, schema: Mapping[str, Field]) -> dict[str, Any]:
    """``data`` checked against ``schema``: a dict of the converted values of the keys present.

    Raises:
        SchemaError: ``data`` is not a mapping, has keys the schema lacks, misses a required key, or a value
            fails its check.
    """
    prefix = f"{path}: {where}: " if where else f"{path}: "
    if not isinstance(data, Mapping):
        raise SchemaError(f"{prefix}expected a mapping with keys {sorted(schema)}, got {_describe(data)}")
    unknown = sorted(str(k) for k in data if k not in schema)
    if unknown:
        raise SchemaError(f"{prefix}unknown keys {unknown} (expected: {sorted(schema)})")
    missing = sorted(k for k, f in schema.items() if f.required and k not in data)
    if missing:
        raise SchemaError(f"{prefix}missing required keys {missing}")
    out = {}
    dot = f"{where}." if where else ""
    for key, value in data.items():
        try:
            out[key] = schema[key].check(value)
        except _Mismatch as err:
            raise SchemaError(f"{path}: {dot}{key}: expected {err}, got {_describe(value)}") from None
    return out
