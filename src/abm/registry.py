"""Named extension points: :class:`Registry`, a read-only mapping of names to entries with one way to add an entry
and one error for a name it does not hold, and :func:`resolve`, which imports a ``"module:attribute"`` reference.

Every extension point of abm is one registry, defined next to what it registers:

* grounders: :data:`abm.grounding.config.GROUNDERS` (:class:`~abm.grounding.config.GrounderKind`);
* language encoders: :data:`abm.policy.language_config.LANGUAGES` (:class:`~abm.policy.language_config.LanguageKind`);
* policy variants: :data:`abm.policy.variants.VARIANTS` (:class:`~abm.policy.variants.VariantSpec`);
* tasks: :data:`abm.sim.tasks.base.TASKS` (a :class:`~abm.sim.tasks.base.Task` class);
* robots' cameras and arms: :data:`abm.robot.kinds.CAMERA_KINDS`, :data:`abm.robot.kinds.ARM_KINDS`
  (:class:`~abm.robot.kinds.DeviceKind`);
* dataset formats: :data:`abm.data.formats.DATASET_FORMATS` (:class:`~abm.data.formats.DatasetFormat`);
* diagnoses: :data:`abm.evaluation.diagnose.DIAGNOSES` (:class:`~abm.evaluation.diagnose.DiagnosisKind`);
* report section kinds: :data:`abm.experiments.report.kinds.SECTIONS`
  (:class:`~abm.experiments.report.kinds.SectionKind`);
* the experiment engine's job kinds: :data:`abm.experiments.jobs.JOBS` (a
  :class:`~abm.experiments.jobs.TypedJob` dataclass).

The command line's choice lists are the registries' names (``choices=GROUNDERS.names()``). So that ``abm --help``
stays light, an entry holds what is heavy (a grounder class, an exporter) as a ``"module:attribute"`` text that
:func:`resolve` imports when it is used, and the registries of light modules are importable without torch,
numpy or mujoco (the tasks' registry is the exception: a task is its class; the task commands take names
as text and check them when they run).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping
from typing import Any, Generic, TypeVar

from abm.errors import ConfigError

T = TypeVar("T")


class UnknownNameError(ConfigError, KeyError):
    """A name no entry of a registry has; the message lists the known names.

    A :class:`~abm.errors.ConfigError` (so a ``ValueError``: a bad option value) and a ``KeyError`` (a registry is
    a mapping), so code that caught either before the registries existed still catches it."""

    def __str__(self) -> str:  # KeyError's own would quote the message
        return str(self.args[0]) if self.args else ""


class Registry(Mapping[str, T], Generic[T]):
    """Names -> entries of one extension point, in the order they were registered.

    A read-only :class:`~collections.abc.Mapping` (``REGISTRY[name]``, ``name in REGISTRY``, ``sorted(REGISTRY)``)
    plus :meth:`register`, :meth:`names` (optionally only the entries with given attribute values, for commands
    that take a subset) and :meth:`unregister` (for tests that add a temporary entry).

    Args:
        what: what a name names, for the error message (``"grounder kind"`` -> ``unknown grounder kind 'x';
            choose from oracle, clip``).
    """

    def __init__(self, what: str) -> None:
        self.what = what
        self._entries: dict[str, T] = {}

    def register(self, name: str, entry: T) -> T:
        """Add ``entry`` under ``name`` and return it (so it can decorate a class).

        Raises:
            ValueError: ``name`` is registered already, or is not a non-empty word without spaces.
        """
        if not isinstance(name, str) or not name or name != name.strip() or " " in name:
            raise ValueError(f"a {self.what} name is a non-empty word without spaces, got {name!r}")
        if name in self._entries:
            raise ValueError(f"{self.what} {name!r} registered twice")
        self._entries[name] = entry
        return entry

    def unregister(self, name: str) -> T:
        """Remove ``name`` and return its entry (tests add a temporary entry and remove it again)."""
        entry = self[name]
        del self._entries[name]
        return entry

    def names(self, **where: Any) -> tuple[str, ...]:
        """The registered names in order; with ``where`` (``cached=True``) only those whose entry has every
        attribute equal to the given value (a command that takes a subset derives it here)."""
        return tuple(name for name, entry in self._entries.items()
                     if all(getattr(entry, key) == value for key, value in where.items()))

    def unknown(self, name: object, known: tuple[str, ...] | None = None) -> UnknownNameError:
        """The error for ``name`` (raise it): what it is not, and the names there are (``known``: a subset)."""
        listed = ", ".join(self.names() if known is None else known) or "none registered"
        return UnknownNameError(f"unknown {self.what} {name!r}; choose from {listed}")

    def __getitem__(self, name: str) -> T:
        try:
            return self._entries[name]
        except (KeyError, TypeError):  # TypeError: an unhashable name (a list read from a file)
            raise self.unknown(name) from None

    def __contains__(self, name: object) -> bool:
        try:
            return name in self._entries
        except TypeError:
            return False

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(self._entries)})"


def resolve(reference: str | Callable[..., Any]) -> Any:
    """The object a ``"package.module:attribute"`` text names (imported now; ``attribute`` may be dotted, e.g.
    ``"abm.grounding.grounders:ClipGrounder.from_config"``), or ``reference`` itself when it is not text.

    Raises:
        ValueError: the text is not of the form ``module:attribute``.
        ImportError, AttributeError: the module or the attribute does not exist.
    """
    if not isinstance(reference, str):
        return reference
    module, sep, attribute = reference.partition(":")
    if not sep or not module or not attribute:
        raise ValueError(f"expected 'module:attribute', got {reference!r}")
    value: Any = importlib.import_module(module)
    for part in attribute.split("."):
        value = getattr(value, part)
    return value
