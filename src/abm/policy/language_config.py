"""Typed language-encoder configurations and their registry (:data:`LANGUAGES`); light, so the command line's parsers
and :class:`abm.train.config.TrainConfig` use it at ``abm --help``. The encoders are :mod:`abm.policy.language`.

* :class:`HashLanguageConfig` — the weight-free hash encoder (``dim``, ``tokens``, ``seed``);
* :class:`ClipLanguageConfig` — CLIP text tokens of a CLIP model (a :class:`~abm.grounding.config.ClipModelConfig`,
  the one a CLIP grounder names too: :meth:`~abm.grounding.config.GrounderConfig.clip_model`).

**Files.** A checkpoint's ``"language"`` entry is the dict form, ``{"kind": "hash", "dim": D, "tokens": L, "seed":
s}`` or ``{"kind": "clip", "model": ..., "device": ...}``; :func:`language_config_from_dict` reads every one abm
wrote, also the older CLIP form that held a whole CLIP grounder's options (of which the text tokens depend on the
model alone), and ``to_dict()`` writes the CLIP model back.

**Adding a language encoder**: a :class:`LanguageConfig` subclass here with its :func:`register_language` entry, and
the encoder class (``tokens``, ``dim``, ``encode(texts)``, ``spec()``) with a ``from_config(config)`` constructor
(in :mod:`abm.policy.language` or a module of its own). ``abm train --language`` offers it from :data:`LANGUAGES`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from abm.errors import ConfigError
from abm.grounding.config import ClipGrounderConfig, ClipModelConfig, GrounderConfig
from abm.registry import Registry, resolve

if TYPE_CHECKING:
    from abm.policy.language import LanguageEncoder  # types only: the encoders load torch


@dataclass(frozen=True)
class LanguageConfig:
    """The base of every language-encoder configuration: a frozen dataclass per kind.

    A subclass sets :attr:`kind` (its name in :data:`LANGUAGES`, ``--language`` and files). The base class reads
    and writes the dict form of options that are plain values (``None`` ones are left out when written).
    """

    kind: ClassVar[str] = ""

    def to_dict(self) -> dict[str, Any]:
        """The JSON form a checkpoint stores: ``{"kind": ..., option: value}``."""
        out: dict[str, Any] = {"kind": self.kind}
        out.update({f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                    if getattr(self, f.name) is not None})
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LanguageConfig:
        """The configuration of a dict form (its ``kind`` is ignored here).

        Raises:
            ValueError: an option this kind does not take (the message lists the ones it takes).
        """
        options = {k: v for k, v in data.items() if k != "kind"}
        allowed = sorted(f.name for f in dataclasses.fields(cls))
        unknown = sorted(set(options) - set(allowed))
        if unknown:
            raise ConfigError(f"unknown option(s) {unknown} for the {cls.kind!r} language encoder; it takes {allowed}")
        return cls(**options)

    def with_width(self, dim: int) -> LanguageConfig:
        """These options for a policy whose language tokens are ``dim`` wide, where the encoder's width is free
        (the hash encoder's unset ``dim``); an encoder with a width of its own (CLIP's) is returned as it is."""
        return self

    def with_clip(self, model: str | None, device: str | None = None) -> LanguageConfig | None:
        """These options with the CLIP weights ``model`` on ``device`` (``--clip-model`` / ``--clip-device``);
        ``None`` for a kind that uses no CLIP (the default)."""
        return None

    def clip_model(self) -> ClipModelConfig | None:
        """The CLIP whose text tower it uses (``None``, the default: none)."""
        return None

    def clip_options(self) -> dict[str, str]:
        """The ``model`` / ``device`` of the CLIP it uses (``--clip-model`` / ``--clip-device``; empty for none)."""
        clip = self.clip_model()
        return {} if clip is None else clip.options()


@dataclass(frozen=True)
class HashLanguageConfig(LanguageConfig):
    """The weight-free hash encoder (:class:`abm.policy.language.HashLanguageEncoder`).

    Attributes:
        dim: embedding width ``D`` (``None``: the policy's ``lang_dim``, 512 by default).
        tokens: sequence length ``L``.
        seed: changes every vector.
    """

    kind: ClassVar[str] = "hash"

    dim: int | None = None
    tokens: int = 77
    seed: int = 0

    def with_width(self, dim: int) -> HashLanguageConfig:
        return self if self.dim is not None else dataclasses.replace(self, dim=int(dim))


@dataclass(frozen=True)
class ClipLanguageConfig(LanguageConfig):
    """CLIP text tokens of a CLIP model (:class:`abm.policy.language.ClipLanguageEncoder`). Its dict form is
    ``{"kind": "clip"}`` with the model's ``model`` / ``device`` where set (and ``allow_download`` when true).

    Attributes:
        clip: the CLIP model whose text tower encodes the texts (the CLIP grounder's by default:
            :func:`default_language`).
    """

    kind: ClassVar[str] = "clip"

    clip: ClipModelConfig = field(default_factory=ClipModelConfig)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, **self.clip.options()}
        if self.clip.allow_download:
            out["allow_download"] = True
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ClipLanguageConfig:
        """The configuration of its dict form, or of the one older checkpoints hold: a whole CLIP grounder's options
        (read as that grounder's, so an option no CLIP grounder takes is refused; only its model is kept).

        Raises:
            ConfigError: an option that is neither the CLIP model's nor a CLIP grounder's (the message lists them).
        """
        options = {k: v for k, v in data.items() if k != "kind"}
        if set(options) <= {f.name for f in dataclasses.fields(ClipModelConfig)}:
            return cls(ClipModelConfig(**options))
        try:
            return cls(ClipGrounderConfig.from_dict(data).clip_model())
        except ConfigError as err:
            raise ConfigError(f"the 'clip' language encoder takes the CLIP model's options (model, device, "
                              f"allow_download; older checkpoints: a CLIP grounder's): {err}") from None

    def with_clip(self, model: str | None, device: str | None = None) -> ClipLanguageConfig:
        return ClipLanguageConfig(self.clip.with_clip(model, device))

    def clip_model(self) -> ClipModelConfig:
        return self.clip


@dataclass(frozen=True)
class LanguageKind:
    """One kind of language encoder: an entry of :data:`LANGUAGES`.

    Attributes:
        config: its configuration class (the kind's name is ``config.kind``).
        build: ``"module:callable"``: ``callable(config) -> LanguageEncoder`` (imported when an encoder is built).
        description: one line on what it does (help texts).
    """

    config: type[LanguageConfig]
    build: str
    description: str

    @property
    def name(self) -> str:
        return self.config.kind

    @property
    def clip(self) -> bool:
        """Whether it takes CLIP weights (``--clip-model``; its configuration overrides
        :meth:`LanguageConfig.with_clip`)."""
        return self.config.with_clip is not LanguageConfig.with_clip


#: every language encoder kind, by name (``abm train --language`` choices, the ``kind`` of language specs)
LANGUAGES: Registry[LanguageKind] = Registry("language encoder kind")


def register_language(kind: LanguageKind) -> LanguageKind:
    """Add a language encoder kind to :data:`LANGUAGES` under its configuration's ``kind``."""
    if not (isinstance(kind.config, type) and issubclass(kind.config, LanguageConfig)) or not kind.config.kind:
        raise ValueError(f"a language encoder's configuration is a LanguageConfig subclass with a kind, got "
                         f"{kind.config!r}")
    return LANGUAGES.register(kind.name, kind)


register_language(LanguageKind(HashLanguageConfig, "abm.policy.language:HashLanguageEncoder.from_config",
                               "weight-free word hashes: no download; tells instructions apart by their words"))
register_language(LanguageKind(ClipLanguageConfig, "abm.policy.language:ClipLanguageEncoder.from_config",
                               "CLIP text tokens of a CLIP model, the CLIP grounder's by default (the paper's)"))


def language_config_from_dict(data: Mapping[str, Any]) -> LanguageConfig:
    """The typed configuration of a language spec (a checkpoint's ``"language"``, ``{"kind": "hash", ...}``).

    Raises:
        ValueError: an unknown or missing kind (:class:`abm.registry.UnknownNameError`, listing the known ones),
            or options the kind does not take.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"a language encoder configuration must be a dict with a 'kind', got {data!r}")
    kind = data.get("kind")
    cls = LANGUAGES[kind].config  # type: ignore[index]  # None or another non-name: the registry's error
    try:
        return cls.from_dict(data)
    except TypeError as err:  # a bad value type reaching a dataclass
        raise ConfigError(f"bad {kind!r} language encoder options {dict(data)}: {err}") from err


def as_language_config(value: LanguageConfig | Mapping[str, Any] | str) -> LanguageConfig:
    """A typed config from a typed config, a dict or a kind name (that kind's defaults)."""
    if isinstance(value, LanguageConfig):
        return value
    if isinstance(value, str):
        return language_config_from_dict({"kind": value})
    return language_config_from_dict(value)


def default_language(grounder: GrounderConfig) -> LanguageConfig:
    """The language encoder of a training run that names none: the text tower of the CLIP its grounder uses
    (:meth:`~abm.grounding.config.GrounderConfig.clip_model`), else the hash encoder."""
    clip = grounder.clip_model()
    return HashLanguageConfig() if clip is None else ClipLanguageConfig(clip)


def build_language_encoder(config: LanguageConfig | Mapping[str, Any] | str) -> LanguageEncoder:
    """The encoder of ``config`` (a dict is read with :func:`language_config_from_dict`), built by its kind's
    :attr:`LanguageKind.build`."""
    config = as_language_config(config)
    encoder: LanguageEncoder = resolve(LANGUAGES[config.kind].build)(config)
    return encoder
