"""Typed grounder configurations: one frozen dataclass per grounder kind, and :func:`build_grounder`.

* :class:`OracleGrounderConfig` — simulator segmentation (no options);
* :class:`ClipGrounderConfig` — the CLIP grounder (model, mode, dense features, mask-field and proposal settings);
* :class:`TrackingGrounderConfig` — ground once with ``inner``, then track the target's points.

``GrounderConfig`` is their union. The defaults here are the only ones: :class:`~abm.grounding.grounders.ClipGrounder`
and :class:`~abm.grounding.tracking.TrackingGrounder` take theirs from these classes.

**Files.** Checkpoints (``"grounder"``), run folders and the language encoder's spec hold the JSON form
``{"kind": "oracle"}`` / ``{"kind": "clip", "model": ..., ...}`` / ``{"kind": "tracking", "inner": {...}, ...}``:
:func:`grounder_config_from_dict` reads every dict abm ever wrote (also the shortcut ``scoring`` for
``proposals.scoring`` and a bare kind name as ``inner``), and ``to_dict()`` writes the options that were
named when the config was read, plus every option that differs from its default. So a file read and written
again is unchanged, and so are the grounding-cache keys derived from it (:func:`abm.grounding.grounders.resolved_spec`).
Equality compares the option values only: ``{"kind": "clip"}`` equals ``{"kind": "clip", "mode": "proposals"}``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Union, overload

from abm.grounding.mask_field import (
    DEFAULT_LOGIT_SCALE,
    DEFAULT_NEGATIVES,
    DEFAULT_NORMALIZATION,
    DEFAULT_THRESHOLD,
    MaskFieldConfig,
)
from abm.grounding.proposals import ProposalConfig

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from abm.grounding.grounders import ClipGrounder, Grounder  # grounders.py imports its defaults from this module

GROUNDERS: tuple[str, ...] = ("oracle", "clip", "tracking")
CLIP_MODES: tuple[str, ...] = ("field", "proposals")
DEFAULT_CLIP_MODE = "proposals"  # measured best (docs/grounding.md section 9); "field" is the paper's
DEFAULT_DENSE_MODE = "maskclip"
DEFAULT_INPUT_SIZE: int | None = None  # None: the model's native input size
DEFAULT_SCALES: tuple[int, ...] = ()

_PROPOSAL_FIELDS = tuple(f.name for f in dataclasses.fields(ProposalConfig))


def _json(value: Any) -> Any:
    """Tuples as lists (the JSON form files hold)."""
    if isinstance(value, tuple):
        return [_json(v) for v in value]
    return value


def _explicit(config: DataclassInstance, given: frozenset[str]) -> list[str]:
    """Option names to write: the ones named when read, and the ones differing from their default."""
    out = []
    for f in dataclasses.fields(config):
        if f.name.startswith("_") or not f.init:
            continue
        # every option has a default or a default_factory (typeshed: the factory may be MISSING, not callable)
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[operator]
        if f.name in given or getattr(config, f.name) != default:
            out.append(f.name)
    return out


def _unknown(kind: str, keys: set[str], allowed: tuple[str, ...]) -> None:
    if keys:
        raise ValueError(f"unknown option(s) {sorted(keys)} for the {kind!r} grounder; it takes {sorted(allowed)}")


@dataclass(frozen=True)
class OracleGrounderConfig:
    """The oracle grounder: the points whose segmentation id is named like the target (no options)."""

    kind: ClassVar[str] = "oracle"

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "oracle"}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> OracleGrounderConfig:
        _unknown("oracle", set(data) - {"kind"}, ())
        return cls()


@dataclass(frozen=True)
class ClipGrounderConfig:
    """The CLIP grounder (:class:`abm.grounding.grounders.ClipGrounder`).

    Attributes:
        model: hub name, local folder, ``"tiny"`` or ``"random:<preset>"`` (``None``:
            ``abm.grounding.clip.DEFAULT_MODEL``).
        device: torch device of the backbone (``None``: CUDA when available).
        mode: ``"proposals"`` (score 3-D object candidates) or ``"field"`` (threshold the per-point heatmap).
        dense_mode: last block of the dense features (``maskclip``, ``clearclip``, ``sclip``, ``naclip``).
        input_size: camera images are resized to this side or ``(H, W)`` (``None``: the model's native size).
        scales: extra input sides whose features are averaged in (multi-scale); ``()`` for none.
        normalization / threshold / negatives / logit_scale / fallback / fallback_top_k: the mask-field
            settings (:class:`~abm.grounding.mask_field.MaskFieldConfig`).
        proposals: candidate and scoring settings of ``mode="proposals"``
            (:class:`~abm.grounding.proposals.ProposalConfig`; its ``scoring`` may also be given as a top-level
            ``scoring`` key in the dict form).
        cache: folder of the grounding cache (``None``: memory only).
        cache_features: also keep per-image patch features in the cache.
        allow_download: let the weights be fetched from the network.
    """

    kind: ClassVar[str] = "clip"

    model: str | None = None
    device: str | None = None
    mode: str = DEFAULT_CLIP_MODE
    dense_mode: str = DEFAULT_DENSE_MODE
    input_size: int | tuple[int, ...] | None = DEFAULT_INPUT_SIZE
    scales: tuple[int, ...] = DEFAULT_SCALES
    normalization: str = DEFAULT_NORMALIZATION
    threshold: float = DEFAULT_THRESHOLD
    negatives: tuple[str, ...] = DEFAULT_NEGATIVES
    logit_scale: float = DEFAULT_LOGIT_SCALE
    fallback: str = MaskFieldConfig.fallback
    fallback_top_k: int = MaskFieldConfig.fallback_top_k
    proposals: ProposalConfig = field(default_factory=ProposalConfig)
    cache: str | None = None
    cache_features: bool = True
    allow_download: bool = False
    # option names the dict it was read from named (written back by to_dict); not part of equality
    _given: frozenset[str] = field(default=frozenset(), compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.mode not in CLIP_MODES:
            raise ValueError(f"clip grounder mode must be one of {CLIP_MODES}, got {self.mode!r}")
        size: object = self.input_size  # a list when read from JSON
        if isinstance(size, list):
            object.__setattr__(self, "input_size", tuple(int(v) for v in size))
        object.__setattr__(self, "scales", tuple(int(v) for v in self.scales))
        object.__setattr__(self, "negatives", tuple(self.negatives))
        if isinstance(self.proposals, Mapping):
            object.__setattr__(self, "proposals", ProposalConfig(**self.proposals))
        if self.cache is not None:
            object.__setattr__(self, "cache", str(self.cache))

    def mask_field_config(self) -> MaskFieldConfig:
        return MaskFieldConfig(normalization=self.normalization, threshold=self.threshold, negatives=self.negatives,
                               logit_scale=self.logit_scale, fallback=self.fallback,
                               fallback_top_k=self.fallback_top_k)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": "clip"}
        names = _explicit(self, self._given)
        proposals_given = frozenset(k.split(".", 1)[1] for k in self._given if k.startswith("proposals."))
        prop_names = _explicit(self.proposals, proposals_given)
        top_scoring = "scoring" in self._given
        if top_scoring and "scoring" not in proposals_given:
            prop_names = [n for n in prop_names if n != "scoring"]
        for name in names:
            if name == "proposals":
                continue
            out[name] = _json(getattr(self, name))
        if top_scoring:
            out["scoring"] = self.proposals.scoring
        if prop_names or "proposals" in self._given:
            out["proposals"] = {n: _json(getattr(self.proposals, n)) for n in prop_names}
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ClipGrounderConfig:
        data = {k: v for k, v in data.items() if k != "kind"}
        if isinstance(data.get("config"), MaskFieldConfig):  # make_grounder(config=...) of the Python API
            mf = data.pop("config")
            data = {**{k: getattr(mf, k) for k in ("normalization", "threshold", "negatives", "logit_scale",
                                                    "fallback", "fallback_top_k")}, **data}
        allowed = tuple(f.name for f in dataclasses.fields(cls) if not f.name.startswith("_")) + ("scoring",)
        _unknown("clip", set(data) - set(allowed), allowed)
        given = set(data)
        proposals = data.pop("proposals", None) or {}
        if isinstance(proposals, ProposalConfig):
            proposals = dataclasses.asdict(proposals)
        proposals = dict(proposals)
        _unknown("clip", {f"proposals.{k}" for k in set(proposals) - set(_PROPOSAL_FIELDS)}, tuple(
            f"proposals.{k}" for k in _PROPOSAL_FIELDS))
        given |= {f"proposals.{k}" for k in proposals}
        if "scoring" in data:
            proposals["scoring"] = data.pop("scoring")
        return cls(**data, proposals=ProposalConfig(**proposals), _given=frozenset(given))


@dataclass(frozen=True)
class TrackingGrounderConfig:
    """Ground with ``inner`` once per episode and target, then track its points
    (:class:`abm.grounding.tracking.TrackingGrounder`, where the options are explained)."""

    kind: ClassVar[str] = "tracking"

    inner: OracleGrounderConfig | ClipGrounderConfig = field(default_factory=OracleGrounderConfig)
    radius: float = 0.01
    min_kept: float = 0.3
    closed_below: float = 0.5
    color_tol: float = 0.2
    reacquire: bool = False
    reacquire_ratio: float = 0.5
    _given: frozenset[str] = field(default=frozenset(), compare=False, repr=False)

    def __post_init__(self) -> None:
        inner: object = self.inner  # any configuration may be passed, whatever the annotation says
        if isinstance(inner, TrackingGrounderConfig):
            raise ValueError("a tracking grounder cannot track with another tracking grounder")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": "tracking"}
        for name in _explicit(self, self._given):
            out[name] = self.inner.to_dict() if name == "inner" else getattr(self, name)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrackingGrounderConfig:
        data = {k: v for k, v in data.items() if k != "kind"}
        allowed = tuple(f.name for f in dataclasses.fields(cls) if not f.name.startswith("_"))
        _unknown("tracking", set(data) - set(allowed), allowed)
        given = frozenset(data)
        if "inner" in data:
            inner = data["inner"]
            data["inner"] = grounder_config_from_dict(inner if isinstance(inner, Mapping) else {"kind": str(inner)})
        return cls(**data, _given=given)


GrounderConfig = Union[OracleGrounderConfig, ClipGrounderConfig, TrackingGrounderConfig]  # noqa: UP007
_CLASSES: dict[str, type] = {"oracle": OracleGrounderConfig, "clip": ClipGrounderConfig,
                             "tracking": TrackingGrounderConfig}
GROUNDER_CONFIGS: tuple[type, ...] = tuple(_CLASSES.values())


def grounder_config_from_dict(data: Mapping[str, Any]) -> GrounderConfig:
    """The typed configuration of a grounder dict (a checkpoint's ``"grounder"``, ``{"kind": "clip", ...}``).

    A dict without ``kind`` is the oracle's (as abm always read it).

    Raises:
        ValueError: an unknown kind, or options the kind does not take (named in the message).
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"a grounder configuration must be a dict with a 'kind', got {data!r}")
    kind = data.get("kind", "oracle")
    cls = _CLASSES.get(kind)
    if cls is None:
        raise ValueError(f"unknown grounder kind {kind!r}; choose from {list(GROUNDERS)}")
    try:
        return cls.from_dict(data)  # type: ignore[attr-defined, no-any-return]
    except TypeError as err:  # a bad value type reaching a dataclass
        raise ValueError(f"bad {kind!r} grounder options {dict(data)}: {err}") from err


def as_grounder_config(value: GrounderConfig | Mapping[str, Any] | str | None) -> GrounderConfig:
    """A typed config from a typed config, a dict, a kind name or ``None`` (the oracle)."""
    if value is None:
        return OracleGrounderConfig()
    if isinstance(value, (OracleGrounderConfig, ClipGrounderConfig, TrackingGrounderConfig)):
        return value
    if isinstance(value, str):
        return grounder_config_from_dict({"kind": value})
    return grounder_config_from_dict(value)


def merge_grounder_configs(stored: GrounderConfig | None, override: GrounderConfig | None) -> GrounderConfig | None:
    """The grounder of a loaded checkpoint when ``override`` (``--grounder`` / ``--clip-model``) is given.

    ``override`` of the stored kind only replaces the options it names (``to_dict``), e.g. another CLIP model
    with the trained threshold; a ``tracking`` override without ``inner`` tracks with the stored grounder,
    and one whose ``inner`` is of the stored kind merges that way into it. Any other override replaces.
    """
    if override is None:
        return stored
    if stored is None:
        return override
    s, o = stored.to_dict(), override.to_dict()
    if o["kind"] == s["kind"]:
        return grounder_config_from_dict({**s, **o})
    if o["kind"] == "tracking":
        inner = o.get("inner")
        if inner is None:
            inner = s
        elif inner.get("kind") == s["kind"]:
            inner = {**s, **inner}
        return grounder_config_from_dict({**o, "inner": inner})
    return override


@overload
def build_grounder(config: ClipGrounderConfig, **runtime: Any) -> ClipGrounder: ...


@overload
def build_grounder(config: GrounderConfig | Mapping[str, Any] | None, **runtime: Any) -> Grounder: ...


def build_grounder(config: GrounderConfig | Mapping[str, Any] | None, **runtime: Any) -> Grounder:
    """The grounder object of ``config`` (a dict is read with :func:`grounder_config_from_dict`).

    ``runtime`` goes to the CLIP grounder's constructor (e.g. ``backbone=`` a loaded model, ``cache=``).
    """
    config = as_grounder_config(config)
    if isinstance(config, OracleGrounderConfig):
        if runtime:
            raise ValueError(f"the oracle grounder takes no options, got {sorted(runtime)}")
        from abm.grounding.grounders import OracleGrounder  # grounders.py imports its defaults from this module

        return OracleGrounder()
    if isinstance(config, ClipGrounderConfig):
        from abm.grounding.grounders import ClipGrounder  # grounders.py imports its defaults from this module

        kwargs: dict[str, Any] = dict(
            model=config.model, device=config.device, config=config.mask_field_config(), cache=config.cache,
            input_size=config.input_size, cache_features=config.cache_features,
            allow_download=config.allow_download, dense_mode=config.dense_mode, mode=config.mode,
            proposals=config.proposals, scales=config.scales)
        return ClipGrounder(**{**kwargs, **runtime})
    from abm.grounding.tracking import TrackingGrounder  # tracking.py imports its defaults from this module

    return TrackingGrounder(build_grounder(config.inner, **runtime), radius=config.radius, min_kept=config.min_kept,
                            closed_below=config.closed_below, color_tol=config.color_tol,
                            reacquire=config.reacquire, reacquire_ratio=config.reacquire_ratio)
