"""The one validator of the YAML files abm reads: training recipes (:mod:`abm.configuration`), experiment specs
(:mod:`abm.experiments.spec`) and robot files (:mod:`abm.robot.run`).

A file's mapping is read through a :class:`Reader`, key by key (:meth:`Reader.value` with a check, or the typed
shortcuts :meth:`~Reader.text`, :meth:`~Reader.integer`, :meth:`~Reader.names`, ...), or against a declared schema
(a mapping ``key -> Field``: :meth:`Reader.fields`, :func:`check_mapping`); :meth:`Reader.done` then refuses the
keys nothing read. A check is a function that converts a value or raises :class:`Mismatch` saying what was expected
and what it got (:func:`number`, :func:`integer`, :func:`text`, :func:`vector`, :func:`boolean`, :func:`names`, ...;
:func:`abm.configuration.flag_check` makes one of a command-line option's own check). Every mistake is one error of
the file's kind (:class:`SchemaError` for robot files, :class:`~abm.experiments.spec.SpecError` for specs,
:class:`~abm.errors.ConfigError` for recipes) naming the file, the key path (dotted, with list indices:
``limits.max_step_m``, ``report.figures[0].file``) and what is expected, e.g.
``robot.yaml: limits.max_step_m: expected a finite number > 0, got nan``.

Numbers are finite: YAML's ``.nan`` and ``.inf`` are refused everywhere, and booleans are not numbers.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

from abm.errors import DataError


class SchemaError(DataError):
    """A file that does not match its schema: the message names the file, the key and what is expected."""


class Mismatch(ValueError):
    """Raised by a value check; its message says what was expected and what the value was
    (``expected a whole number >= 1, got 'many'``)."""


Check = Callable[[Any], Any]
_REQUIRED = object()  # the default of a key that must be given


@dataclass(frozen=True)
class Field:
    """One key of a schema: ``check`` converts a value (or raises), ``required`` the key must be present."""

    check: Check
    required: bool = False


def shown(value: Any) -> str:
    """A value as an error message shows it (its ``repr``, cut to 60 characters)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def mismatch(expected: str, value: Any) -> Mismatch:
    """``expected EXPECTED, got VALUE``."""
    return Mismatch(f"expected {expected}, got {shown(value)}")


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
            raise mismatch(expected, value)
        x = float(value)
        if not math.isfinite(x) or (low is not None and (x <= low if low_open else x < low)) or \
                (high is not None and x > high):
            raise mismatch(expected, value)
        return x

    return check


def integer(low: int | None = None, high: int | None = None) -> Check:
    """A whole number in ``[low, high]`` (worded ``from LOW to HIGH`` when both are given)."""
    if low is not None and high is not None:
        expected = f"a whole number from {low} to {high}"
    else:
        bounds = [f">= {low}" if low is not None else "", f"<= {high}" if high is not None else ""]
        expected = ("a whole number " + " and ".join(b for b in bounds if b)).strip()

    def check(value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or \
                (low is not None and int(value) < low) or (high is not None and int(value) > high):
            raise mismatch(expected, value)
        return int(value)

    return check


def text(choices: Sequence[str] | None = None) -> Check:
    """A non-empty string (one of ``choices`` when given)."""
    expected = f"one of {', '.join(choices)}" if choices else "a non-empty string"

    def check(value: Any) -> str:
        if not isinstance(value, str) or not value.strip() or (choices and value not in choices):
            raise mismatch(expected, value)
        return value

    return check


def boolean(value: Any) -> bool:
    """``true`` or ``false``."""
    if not isinstance(value, bool):
        raise mismatch("true or false", value)
    return value


def names(value: Any) -> tuple[str, ...]:
    """A list of distinct non-empty strings."""
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) and v for v in value):
        raise mismatch("a list of names", list(value) if isinstance(value, tuple) else value)
    if len(set(value)) != len(value):
        raise Mismatch(f"names a value twice: {list(value)}")
    return tuple(value)


def vector(length: int) -> Check:
    """A list of exactly ``length`` finite numbers, as a tuple of floats."""
    expected = f"a list of {length} finite numbers"
    element = number()

    def check(value: Any) -> tuple[float, ...]:
        if isinstance(value, str | bytes | Mapping) or not hasattr(value, "__len__") or len(value) != length:
            raise mismatch(expected, value)
        try:
            return tuple(element(v) for v in value)
        except Mismatch:
            raise mismatch(expected, value) from None

    return check


def any_mapping(value: Any) -> dict[Any, Any]:
    """A mapping whose content is checked elsewhere."""
    if not isinstance(value, Mapping):
        raise mismatch("a mapping", value)
    return dict(value)


def strings(value: Any) -> list[str] | dict[str, str]:
    """A non-empty list of strings, or a non-empty mapping of strings to strings (or numbers)."""
    if isinstance(value, Mapping) and value and all(isinstance(v, str | int) for v in value.values()):
        return {str(k): str(v) for k, v in value.items()}
    if isinstance(value, list) and value and all(isinstance(v, str | int) and not isinstance(v, bool)
                                                 for v in value):
        return [str(v) for v in value]
    raise mismatch("a non-empty list of names, or a mapping name -> serial", value)


class Reader:
    """One mapping of a YAML file, read key by key; every error names the file and the key path.

    Args:
        data: the mapping (anything else is refused: ``expected a mapping``).
        source: the file (or what the messages call it: ``recipe cpu``).
        where: the key path of ``data`` in the file (``""`` at the top).
        error: the error class of the file's kind (called with the message).
        keys: the keys the mapping takes, when known in advance (named when ``data`` is no mapping).
    """

    def __init__(self, data: Any, source: str | Path, where: str = "",
                 error: Callable[[str], Exception] = SchemaError, keys: Sequence[str] = ()) -> None:
        self.source, self.where, self.error_type = source, where, error
        if not isinstance(data, Mapping):
            with_keys = f" with keys {sorted(keys)}" if keys else ""
            raise self.error(f"expected a mapping{with_keys}, got {shown(data)}")
        self.data: dict[Any, Any] = dict(data)
        self.used: set[Any] = set()

    def error(self, message: str, key: str | None = None) -> Exception:
        """The error ``SOURCE: WHERE.KEY: MESSAGE`` (the file's kind)."""
        path = ".".join(p for p in (self.where, key) if p)
        return self.error_type(f"{self.source}: {path}: {message}" if path else f"{self.source}: {message}")

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = None) -> Any:
        """The value of ``key`` as the file holds it (``default`` when absent); the key counts as read."""
        self.used.add(key)
        return self.data.get(key, default)

    def value(self, key: str, check: Check, default: Any = _REQUIRED, required: str = "a value") -> Any:
        """``key``'s value converted by ``check`` (``default``, unchecked, when absent; without a default the
        key is required: ``is required (REQUIRED)``)."""
        if key not in self.data:
            self.used.add(key)
            if default is _REQUIRED:
                raise self.error(f"is required ({required})", key)
            return default
        try:
            return check(self.raw(key))
        except Mismatch as err:
            raise self.error(str(err), key) from None

    def sub(self, key: str, default: Any = None) -> Self:
        """The mapping under ``key`` (``default``, else an empty one, when absent)."""
        return self.at(self.raw(key, {} if default is None else default), key)

    def at(self, data: Any, key: str, keys: Sequence[str] = ()) -> Self:
        """A reader of ``data``, found at ``key`` below this mapping (``key`` may hold an index: ``files[0]``)."""
        return type(self)(data, self.source, ".".join(p for p in (self.where, key) if p), self.error_type, keys)

    def text(self, key: str, default: str | None = None) -> str:
        """A text (one line: the line breaks of a folded paragraph become spaces)."""
        def check(value: Any) -> str:
            if not isinstance(value, str):
                raise mismatch("a text", value)
            return " ".join(value.split()) if "\n" in value else value

        return str(self.value(key, check, _REQUIRED if default is None else default, "a text"))

    def integer(self, key: str, default: int | None = None, low: int = 1, high: int = 10**9) -> int:
        """A whole number from ``low`` to ``high``."""
        return int(self.value(key, integer(low, high), _REQUIRED if default is None else default,
                              f"a whole number >= {low}"))

    def number(self, key: str, default: float | None = None) -> float:
        """A finite number."""
        return float(self.value(key, number(), _REQUIRED if default is None else default, "a number"))

    def flag(self, key: str, default: bool = False) -> bool:
        """``true`` or ``false``."""
        return bool(self.value(key, boolean, default))

    def names(self, key: str, default: Sequence[str] | None = None) -> tuple[str, ...]:
        """A list of distinct names."""
        found = self.value(key, names, _REQUIRED if default is None else tuple(default), "a list of names")
        return tuple(found)

    def choice(self, key: str, choices: Sequence[str], default: str | None = None) -> str:
        """One of ``choices``."""
        return str(self.value(key, text(choices), _REQUIRED if default is None else default, "a text"))

    def fields(self, schema: Mapping[str, Field]) -> dict[str, Any]:
        """Every key of the declared ``schema`` present, converted by its field's check: the mapping's other keys
        and a required key that is missing are refused."""
        self.done(list(schema))
        missing = sorted(k for k, f in schema.items() if f.required and k not in self.data)
        if missing:
            raise self.error(f"missing required keys {missing}")
        return {key: self.value(key, schema[key].check) for key in self.data}

    def done(self, expected: Sequence[str] | None = None) -> None:
        """Refuse the keys nothing read and ``expected`` (the keys the mapping takes; default: the keys read) does
        not name, so a typo is never silently ignored: ``unknown keys [...] (expected: [...])``."""
        allowed = set(self.used if expected is None else expected)
        unknown = sorted(str(k) for k in self.data if k not in allowed and k not in self.used)
        if unknown:
            raise self.error(f"unknown keys {unknown} (expected: {sorted(map(str, allowed))})")


def check_mapping(path: str | Path, where: str, data: Any, schema: Mapping[str, Field]) -> dict[str, Any]:
    """``data`` (at the key path ``where`` of the file ``path``) checked against ``schema``: a dict of the
    converted values of the keys present (:meth:`Reader.fields`).

    Raises:
        SchemaError: ``data`` is not a mapping, has keys the schema lacks, misses a required key, or a value
            fails its check.
    """
    return Reader(data, path, where, SchemaError, keys=list(schema)).fields(schema)
