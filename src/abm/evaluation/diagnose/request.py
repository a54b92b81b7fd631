"""The base of every diagnosis request (:class:`DiagnosisRequest`): a frozen dataclass whose fields say what to
measure and where to write it, that round-trips through JSON (:meth:`~DiagnosisRequest.to_dict`,
:meth:`~DiagnosisRequest.from_dict`) so the experiment engine can hand it to another process, and whose
:meth:`~DiagnosisRequest.run` measures and writes the output file."""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path
from typing import Any, ClassVar, Self, get_type_hints

from abm.errors import ConfigError
from abm.serialize import json_value, typed_value


class DiagnosisRequest:
    """What one diagnosis measures (a frozen dataclass subclass; its registry name is :attr:`kind`).

    Subclasses implement :meth:`run`, which measures, writes the output file (its ``out`` field, when set) and
    returns what it wrote as a JSON-ready value."""

    kind: ClassVar[str]
    """The diagnosis' name in :data:`abm.evaluation.diagnose.DIAGNOSES`."""

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": KIND, FIELD: value, ...}`` (JSON types: paths as text, tuples as lists)."""
        return {"kind": self.kind, **{f.name: json_value(getattr(self, f.name)) for f in fields(self)}}  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Self:
        """The request :meth:`to_dict` wrote (``kind``, when given, must be this class's).

        Raises:
            ConfigError: another kind, a key the request does not have, or a field it needs missing.
        """
        data = dict(data)
        kind = data.pop("kind", cls.kind)
        if kind != cls.kind:
            raise ConfigError(f"a {cls.kind!r} diagnosis request, not {kind!r}")
        hints = get_type_hints(cls)
        names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ConfigError(f"unknown key(s) {', '.join(unknown)} of a {cls.kind!r} diagnosis; known: "
                              f"{', '.join(names)}")
        try:
            return cls(**{k: typed_value(hints[k], v) for k, v in data.items()})
        except TypeError as err:  # a required field missing
            raise ConfigError(f"a {cls.kind!r} diagnosis request: {err}") from None

    def run(self) -> Any:
        """Measure, write the output file and return its content (JSON-ready)."""
        raise NotImplementedError


def write_json(out: Path | None, payload: Any, newline: bool = False) -> None:
    """Write ``payload`` as indented JSON (``indent=1``; a final newline when ``newline``) to ``out`` (its folder
    made), unless ``out`` is ``None``."""
    if out is None:
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(payload, indent=1) + ("\n" if newline else ""))
