"""Typed grounder configurations, the registry of grounder kinds (:data:`GROUNDERS`) and :func:`build_grounder`, the
one way to build a grounder.

* :class:`ClipModelConfig` — which CLIP weights on which device: what the CLIP grounder and the CLIP text encoder
  (:class:`abm.policy.language_config.ClipLanguageConfig`) share (:meth:`GrounderConfig.clip_model`);
* :class:`OracleGrounderConfig` — simulator segmentation (no options);
* :class:`ClipGrounderConfig` — the CLIP grounder (model, mode, dense features, mask-field and proposal settings:
  :class:`MaskFieldConfig`, :class:`ProposalConfig`);
* :class:`TrackingGrounderConfig` — ground once with ``inner``, then track the target's points.

Each is a frozen subclass of :class:`GrounderConfig`, registered in :data:`GROUNDERS` with the grounder class that
builds it (a ``"module:attribute"`` text, imported only when a grounder is built) and what the commands may do with
it (:class:`GrounderKind`). This module imports nothing heavy, so the command line's parsers and
:class:`abm.train.config.TrainConfig` use it at ``abm --help``. The defaults here are the only ones:
:class:`~abm.grounding.grounders.ClipGrounder` and :class:`~abm.grounding.tracking.TrackingGrounder` take theirs
from these classes.

**Adding a grounder**: a configuration dataclass here (a :class:`GrounderConfig` subclass with its ``kind``; the
base class reads and writes its dict form), its :func:`register_grounder` entry, and the grounder class with a
``from_config(config, **runtime)`` constructor in a module of its own. ``--grounder`` of every command, the
checkpoints and the experiment specs pick it up from :data:`GROUNDERS`.

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
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, overload

from abm.configuration import GPU_CLIP_MODEL
from abm.errors import ConfigError
from abm.registry import Registry, resolve

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from abm.grounding.grounders import ClipGrounder, Grounder  # types only: grounders.py loads torch and CLIP

DEFAULT_MODEL = GPU_CLIP_MODEL  # the paper's (abm.configuration holds the defaults shared by commands)
CLIP_MODES: tuple[str, ...] = ("field", "proposals")
DEFAULT_CLIP_MODE = "proposals"  # measured best (docs/grounding.md section 9); "field" is the paper's
DENSE_MODES: tuple[str, ...] = ("maskclip", "clearclip", "sclip", "naclip")
"""Last-block variants for the CLIP grounder's dense features (:mod:`abm.grounding.clip`; training-free; all drop
the residual and the MLP of the last block):

* ``maskclip``: the value path alone, no attention mixing (MaskCLIP);
* ``clearclip``: attention from query-query similarity, ``softmax(q q^T / sqrt(d)) v`` (ClearCLIP);
* ``sclip``: correlative self-attention, ``(softmax(q q^T / sqrt(d)) + softmax(k k^T / sqrt(d))) v`` (SCLIP);
* ``naclip``: key-key similarity plus a Gaussian window over the patch grid, so every patch attends
  mostly to its neighbours, ``softmax(k k^T / sqrt(d) + exp(-dist^2 / (2 sigma^2))) v`` (NACLIP).
"""
DEFAULT_DENSE_MODE = "maskclip"
DEFAULT_INPUT_SIZE: int | None = None  # None: the model's native input size
DEFAULT_SCALES: tuple[int, ...] = ()

NORMALIZATIONS: tuple[str, ...] = ("raw", "minmax", "softmax")
DEFAULT_NEGATIVES: tuple[str, ...] = ("object", "things", "stuff", "texture")
DEFAULT_NORMALIZATION = "softmax"
DEFAULT_THRESHOLD = 0.7
DEFAULT_LOGIT_SCALE = 100.0


@dataclass(frozen=True)
class MaskFieldConfig:
    """How a similarity heatmap becomes a mask.

    Attributes:
        normalization: ``"raw"``, ``"minmax"`` or ``"softmax"`` (see :mod:`abm.grounding.mask_field`).
        threshold: heatmap value (after normalisation) at or above which a point is the target.
        negatives: negative phrases for ``softmax``; each becomes the prompt ``"a photo of a <phrase>"``.
        logit_scale: softmax temperature multiplier (CLIP's learned value is 100).
        fallback: ``"top"`` (keep the top-scoring points when nothing passes) or ``"none"``.
        fallback_top_k: how many points the ``"top"`` fallback keeps.
    """

    normalization: str = DEFAULT_NORMALIZATION
    threshold: float = DEFAULT_THRESHOLD
    negatives: tuple[str, ...] = DEFAULT_NEGATIVES
    logit_scale: float = DEFAULT_LOGIT_SCALE
    fallback: str = "top"
    fallback_top_k: int = 1

    def __post_init__(self) -> None:
        if self.normalization not in NORMALIZATIONS:
            raise ConfigError(f"normalization must be one of {NORMALIZATIONS}, got {self.normalization!r}")
        if self.fallback not in ("top", "none"):
            raise ConfigError(f"fallback must be 'top' or 'none', got {self.fallback!r}")
        if self.fallback_top_k < 1:
            raise ConfigError(f"fallback_top_k must be >= 1, got {self.fallback_top_k}")
        if self.normalization == "softmax" and not self.negatives:
            raise ConfigError("softmax normalisation needs at least one negative phrase")
        object.__setattr__(self, "negatives", tuple(self.negatives))

    def key(self) -> str:
        """A stable text form used in cache keys."""
        return (f"{self.normalization}|{self.threshold:g}|{','.join(self.negatives)}|{self.logit_scale:g}|"
                f"{self.fallback}|{self.fallback_top_k}")


SCORINGS: tuple[str, ...] = ("dense", "crop", "combined")
LEGACY_CLIP_OPTIONS: dict[str, Any] = {"mode": "field", "dense_mode": "maskclip", "input_size": None, "scales": ()}
"""What the CLIP grounder did before these options existed (specs written then do not name them)."""


@dataclass(frozen=True)
class ProposalConfig:
    """How the cloud is split into candidates and how CLIP scores them.

    Attributes:
        voxel: clustering cell size (m).
        table_height: table top height (m); None estimates it as the most common point height.
        table_margin: points up to this height above the table top are table (m).
        min_points: smallest candidate, in points.
        split: also propose colour parts of a cluster and the cluster minus each large colour part (off by
            default: at the first observations of ABM-Bench it lowered IoU, docs/grounding.md section 9).
        color_tol: largest per-channel chromaticity (``rgb / sum``) difference of joined cells
            (:func:`abm.grounding.proposals.same_colour`).
        support_share: a colour part this large (share of its cluster) counts as a possible support.
        max_candidates: at most this many candidates (the largest clusters' candidates first).
        scoring: ``"dense"`` (mean MaskCLIP feature of the candidate's points against the text),
            ``"crop"`` (CLIP image embedding of the candidate's image crops) or ``"combined"``.
        crop_weight: weight of the crop score in ``combined`` (the dense score gets ``1 - crop_weight``).
        crop_margin: crop side = this times the larger side of the candidate's pixel box.
        crop_cameras: crops per candidate (the cameras that see most of its points).
        min_crop_pixels: a camera must see at least this many of the candidate's points to be cropped.
        crop_top_k: ``combined`` crops only the candidates with the ``crop_top_k`` best dense scores (the crops'
            CLIP forwards are most of the cost); 0 crops every candidate.
        hand_filter: leave out the hand's points (:func:`abm.grounding.proposals.hand_points`) when the gripper
            pose is known.
    """

    voxel: float = 0.01
    table_height: float | None = None
    table_margin: float = 0.006
    min_points: int = 15
    split: bool = False
    color_tol: float = 0.05
    support_share: float = 0.3
    max_candidates: int = 40
    scoring: str = "combined"
    crop_weight: float = 0.5
    crop_margin: float = 1.6
    crop_cameras: int = 2
    min_crop_pixels: int = 12
    crop_top_k: int = 8
    hand_filter: bool = True

    def __post_init__(self) -> None:
        if self.scoring not in SCORINGS:
            raise ConfigError(f"proposal scoring must be one of {SCORINGS}, got {self.scoring!r}")
        if self.voxel <= 0 or self.min_points < 1 or self.crop_margin < 1 or not 0 <= self.crop_weight <= 1:
            raise ConfigError("ProposalConfig needs voxel > 0, min_points >= 1, crop_margin >= 1 and crop_weight "
                              f"in [0, 1]; got {self}")

    def key(self) -> str:
        """A stable text form used in cache keys."""
        return "|".join(f"{k}={getattr(self, k)}" for k in self.__dataclass_fields__)


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
        raise ConfigError(f"unknown option(s) {sorted(keys)} for the {kind!r} grounder; it takes {sorted(allowed)}")


def _options(cls: type) -> tuple[str, ...]:
    """The option names of a configuration dataclass (its fields but the private ``_given``)."""
    return tuple(f.name for f in dataclasses.fields(cls) if not f.name.startswith("_"))


@dataclass(frozen=True)
class ClipModelConfig:
    """Which CLIP weights, on which device: the one thing the CLIP grounder (its ``model``, ``device`` and
    ``allow_download`` options) and the CLIP text encoder have in common (both load it with
    :func:`abm.grounding.clip.load_clip_model`).

    Attributes:
        model: hub name, local folder, ``"tiny"`` or ``"random:<preset>"`` (``None``: :data:`DEFAULT_MODEL`).
        device: torch device (``None``: CUDA when available).
        allow_download: let the weights be fetched from the network.
    """

    model: str | None = None
    device: str | None = None
    allow_download: bool = False

    def with_clip(self, model: str | None, device: str | None = None) -> ClipModelConfig:
        """Other weights and device (``None``: the current ones): the ``--clip-model`` / ``--clip-device`` flags."""
        return dataclasses.replace(self, model=self.model if model is None else model,
                                   device=self.device if device is None else device)

    def options(self) -> dict[str, str]:
        """``model`` / ``device`` where set (the ``clip_model`` / ``clip_device`` of a recipe)."""
        return {name: str(value) for name, value in (("model", self.model), ("device", self.device)) if value}


@dataclass(frozen=True)
class GrounderConfig:
    """The base of every grounder configuration: a frozen dataclass per kind, whose fields are its options.

    A subclass sets :attr:`kind` (its name in :data:`GROUNDERS`, ``--grounder`` and files) and may keep the names
    a dict named in a private ``_given: frozenset[str]`` field (not part of equality), which :meth:`to_dict`
    writes back. The base class reads and writes the dict form of options that are plain values; a kind with
    nested options (the CLIP grounder's ``proposals``, tracking's ``inner``) overrides :meth:`from_dict` and
    :meth:`to_dict`.
    """

    kind: ClassVar[str] = ""

    def to_dict(self) -> dict[str, Any]:
        """The JSON form: ``{"kind": ..., option: value}`` of the options named when read or not at their default."""
        given: frozenset[str] = getattr(self, "_given", frozenset())
        out: dict[str, Any] = {"kind": self.kind}
        for name in _explicit(self, given):
            value = getattr(self, name)
            out[name] = value.to_dict() if isinstance(value, GrounderConfig) else _json(value)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GrounderConfig:
        """The configuration of a dict form (its ``kind`` is ignored here; :func:`grounder_config_from_dict`
        picks the class by it).

        Raises:
            ValueError: an option this kind does not take (the message lists the ones it takes).
        """
        options = {k: v for k, v in data.items() if k != "kind"}
        allowed = _options(cls)
        _unknown(cls.kind, set(options) - set(allowed), allowed)
        if any(f.name == "_given" for f in dataclasses.fields(cls)):
            options["_given"] = frozenset(options)
        return cls(**options)

    def with_clip(self, model: str | None, device: str | None = None) -> GrounderConfig | None:
        """These options with the CLIP weights ``model`` on ``device`` (the ``--clip-model`` / ``--clip-device``
        flags); ``None`` for a kind that uses no CLIP (the default)."""
        return None

    def clip_model(self) -> ClipModelConfig | None:
        """The CLIP it grounds with (``None``, the default: none)."""
        return None

    def clip_options(self) -> dict[str, str]:
        """The ``model`` / ``device`` of the CLIP it uses, where set (the inverse of :meth:`with_clip`; empty for a
        kind without CLIP)."""
        clip = self.clip_model()
        return {} if clip is None else clip.options()

    def cache_spec(self, fingerprint: Callable[[str], str]) -> dict[str, Any]:
        """The dict form that names everything its masks depend on, for grounding-cache keys
        (:func:`abm.grounding.grounders.resolved_spec`; ``fingerprint``: a CLIP name -> its identity,
        :func:`abm.grounding.clip.model_fingerprint`). The default: :meth:`to_dict`."""
        return self.to_dict()

    def merged_onto(self, stored: GrounderConfig) -> GrounderConfig:
        """This configuration as an override of ``stored`` (a checkpoint's grounder): of the same kind it only
        replaces the options it names (another CLIP model with the trained threshold); else it replaces."""
        if stored.kind == self.kind:
            return grounder_config_from_dict({**stored.to_dict(), **self.to_dict()})
        return self


@dataclass(frozen=True)
class OracleGrounderConfig(GrounderConfig):
    """The oracle grounder: the points whose segmentation id is named like the target (no options)."""

    kind: ClassVar[str] = "oracle"


@dataclass(frozen=True)
class ClipGrounderConfig(GrounderConfig):
    """The CLIP grounder (:class:`abm.grounding.grounders.ClipGrounder`). Its ``model``, ``device`` and
    ``allow_download`` are its CLIP, a :class:`ClipModelConfig` (:meth:`clip_model`, where they are explained); they
    stay options of their own here, so the dict form files hold is the flat one abm always wrote.

    Attributes:
        model / device / allow_download: its CLIP (:class:`ClipModelConfig`).
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
            raise ConfigError(f"clip grounder mode must be one of {CLIP_MODES}, got {self.mode!r}")
        size: object = self.input_size  # a list when read from JSON
        if isinstance(size, list):
            object.__setattr__(self, "input_size", tuple(int(v) for v in size))
        object.__setattr__(self, "scales", tuple(int(v) for v in self.scales))
        object.__setattr__(self, "negatives", tuple(self.negatives))
        if isinstance(self.proposals, Mapping):
            object.__setattr__(self, "proposals", ProposalConfig(**self.proposals))
        if self.cache is not None:
            object.__setattr__(self, "cache", str(self.cache))

    def with_clip(self, model: str | None, device: str | None = None) -> ClipGrounderConfig:
        """These options with other CLIP weights and device (``None``: the current ones)."""
        given = {name for name, value in (("model", model), ("device", device)) if value is not None}
        return dataclasses.replace(self, model=self.model if model is None else model,
                                   device=self.device if device is None else device, _given=self._given | given)

    def clip_model(self) -> ClipModelConfig:
        return ClipModelConfig(self.model, self.device, self.allow_download)

    def cache_spec(self, fingerprint: Callable[[str], str]) -> dict[str, Any]:
        """:meth:`to_dict` with the model's fingerprint and the current defaults of the options it leaves out.

        Only defaults that differ from :data:`LEGACY_CLIP_OPTIONS` are added (and the full proposal settings in
        ``proposals`` mode), so a spec's key stays the same while the defaults do, and changes when they change.
        The CLIP model is named by ``fingerprint``: a local folder by its content, so moving it keeps the key and
        retraining it into the same folder changes it."""
        out = self.to_dict()
        model = str(out.get("model") or DEFAULT_MODEL)
        identity = fingerprint(model)
        if "model" in out or identity != model:
            out["model"] = identity
        current = {"mode": DEFAULT_CLIP_MODE, "dense_mode": DEFAULT_DENSE_MODE, "input_size": DEFAULT_INPUT_SIZE,
                   "scales": DEFAULT_SCALES}
        out.update({k: v for k, v in current.items() if k not in out and v != LEGACY_CLIP_OPTIONS[k]})
        if out.get("mode") == "proposals":
            given = dict(out.get("proposals") or {})
            if "scoring" in out:
                given["scoring"] = out.pop("scoring")
            out["proposals"] = {**ProposalConfig().__dict__, **given}
        return out

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
class TrackingGrounderConfig(GrounderConfig):
    """Ground with ``inner`` once per episode and target, then track its points
    (:class:`abm.grounding.tracking.TrackingGrounder`, where the options are explained)."""

    kind: ClassVar[str] = "tracking"

    inner: GrounderConfig = field(default_factory=OracleGrounderConfig)
    radius: float = 0.01
    min_kept: float = 0.3
    closed_below: float = 0.5
    color_tol: float = 0.2
    reacquire: bool = False
    reacquire_ratio: float = 0.5
    _given: frozenset[str] = field(default=frozenset(), compare=False, repr=False)

    def __post_init__(self) -> None:
        if isinstance(self.inner, TrackingGrounderConfig):
            raise ConfigError("a tracking grounder cannot track with another tracking grounder")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrackingGrounderConfig:
        data = {k: v for k, v in data.items() if k != "kind"}
        allowed = _options(cls)
        _unknown("tracking", set(data) - set(allowed), allowed)
        given = frozenset(data)
        if "inner" in data:
            inner = data["inner"]
            data["inner"] = grounder_config_from_dict(inner if isinstance(inner, Mapping) else {"kind": str(inner)})
        return cls(**data, _given=given)

    def with_clip(self, model: str | None, device: str | None = None) -> TrackingGrounderConfig:
        """Tracking whose first step grounds with that CLIP (its own ``inner`` when that uses one, else the CLIP
        grounder's defaults)."""
        inner = self.inner.with_clip(model, device) or ClipGrounderConfig().with_clip(model, device)
        return dataclasses.replace(self, inner=inner, _given=self._given | {"inner"})

    def clip_model(self) -> ClipModelConfig | None:
        return self.inner.clip_model()

    def cache_spec(self, fingerprint: Callable[[str], str]) -> dict[str, Any]:
        out = self.to_dict()
        if "inner" in out:
            out["inner"] = self.inner.cache_spec(fingerprint)
        return out

    def merged_onto(self, stored: GrounderConfig) -> GrounderConfig:
        """As :meth:`GrounderConfig.merged_onto`; tracking onto another kind tracks with ``stored`` when this names
        no ``inner``, and an ``inner`` of the stored kind is merged into it."""
        if stored.kind == self.kind:
            return super().merged_onto(stored)
        mine = self.to_dict()
        inner = mine.get("inner")
        if inner is None:
            inner = stored.to_dict()
        elif inner.get("kind") == stored.kind:
            inner = {**stored.to_dict(), **inner}
        return grounder_config_from_dict({**mine, "inner": inner})


@dataclass(frozen=True)
class GrounderKind:
    """One kind of grounder: an entry of :data:`GROUNDERS`.

    Attributes:
        config: its configuration class (the kind's name is ``config.kind``).
        build: ``"module:callable"``: ``callable(config, **runtime) -> Grounder`` (imported when a grounder is built,
            so the registry stays light; :func:`abm.registry.resolve`).
        description: one line on what it does (help texts).
        per_frame: it grounds every observation on its own; ``False`` for a grounder that carries state from one
            step of an episode to the next (tracking), which only rollouts can use (``abm eval``, ``abm run``), not
            training or ``abm ground``.
        cached: its masks are worth computing ahead of training and caching (a learned model's:
            ``abm data ground``).
    """

    config: type[GrounderConfig]
    build: str
    description: str
    per_frame: bool = True
    cached: bool = False

    @property
    def name(self) -> str:
        return self.config.kind

    @property
    def clip(self) -> bool:
        """Whether it takes CLIP weights (``--clip-model``; its configuration overrides
        :meth:`GrounderConfig.with_clip`)."""
        return self.config.with_clip is not GrounderConfig.with_clip


#: every grounder kind, by name (``--grounder`` choices, the ``kind`` of grounder dicts)
GROUNDERS: Registry[GrounderKind] = Registry("grounder kind")


def register_grounder(kind: GrounderKind) -> GrounderKind:
    """Add a grounder kind to :data:`GROUNDERS` under its configuration's ``kind``."""
    if not (isinstance(kind.config, type) and issubclass(kind.config, GrounderConfig)) or not kind.config.kind:
        raise ValueError(f"a grounder's configuration is a GrounderConfig subclass with a kind, got {kind.config!r}")
    return GROUNDERS.register(kind.name, kind)


register_grounder(GrounderKind(OracleGrounderConfig, "abm.grounding.grounders:OracleGrounder.from_config",
                               "the simulator's segmentation: ground-truth masks"))
register_grounder(GrounderKind(ClipGrounderConfig, "abm.grounding.grounders:ClipGrounder.from_config",
                               "CLIP: score 3-D object proposals or threshold the per-point heatmap", cached=True))
register_grounder(GrounderKind(TrackingGrounderConfig, "abm.grounding.tracking:TrackingGrounder.from_config",
                               "ground once per episode with an inner grounder, then track the target's points",
                               per_frame=False))


def grounder_config_from_dict(data: Mapping[str, Any]) -> GrounderConfig:
    """The typed configuration of a grounder dict (a checkpoint's ``"grounder"``, ``{"kind": "clip", ...}``).

    A dict without ``kind`` is the oracle's (as abm always read it).

    Raises:
        ValueError: an unknown kind (:class:`abm.registry.UnknownNameError`, listing the known ones), or options the
            kind does not take (named in the message).
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"a grounder configuration must be a dict with a 'kind', got {data!r}")
    kind = data.get("kind", "oracle")
    cls = GROUNDERS[kind].config
    try:
        return cls.from_dict(data)
    except TypeError as err:  # a bad value type reaching a dataclass
        raise ConfigError(f"bad {kind!r} grounder options {dict(data)}: {err}") from err


def as_grounder_config(value: GrounderConfig | Mapping[str, Any] | str | None) -> GrounderConfig:
    """A typed config from a typed config, a dict, a kind name or ``None`` (the oracle)."""
    if value is None:
        return OracleGrounderConfig()
    if isinstance(value, GrounderConfig):
        return value
    if isinstance(value, str):
        return grounder_config_from_dict({"kind": value})
    return grounder_config_from_dict(value)


def grounder_from_flags(kind: str | None, clip_model: str | None = None,
                        clip_device: str | None = None) -> GrounderConfig | None:
    """The grounder of the ``--grounder KIND [--clip-model M] [--clip-device D]`` flags (``None`` without
    ``--grounder``: the checkpoint's, or the command's default). The CLIP weights go to the kind's own CLIP
    (:meth:`GrounderConfig.with_clip`: the ``clip`` grounder's, the one ``tracking`` grounds its first step with).

    Raises:
        ConfigError: an unknown kind, or CLIP weights for a kind that uses none.
    """
    given = clip_model is not None or clip_device is not None
    if kind is None:
        if given:
            raise ConfigError(f"--clip-model applies to --grounder {' or '.join(GROUNDERS.names(clip=True))}, not "
                              f"the checkpoint default: add --grounder clip to ground with {clip_model or 'it'}")
        return None
    config = grounder_config_from_dict({"kind": kind})
    if not given:
        return config
    with_clip = config.with_clip(clip_model, clip_device)
    if with_clip is None:
        raise ConfigError(f"--clip-model applies to --grounder {' or '.join(GROUNDERS.names(clip=True))}, not "
                          f"{kind!r}: add --grounder clip to ground with {clip_model or 'it'}")
    return with_clip


def merge_grounder_configs(stored: GrounderConfig | None, override: GrounderConfig | None) -> GrounderConfig | None:
    """The grounder of a loaded checkpoint when ``override`` (``--grounder`` / ``--clip-model``) is given.

    ``override`` of the stored kind only replaces the options it names (``to_dict``), e.g. another CLIP model
    with the trained threshold; a ``tracking`` override without ``inner`` tracks with the stored grounder,
    and one whose ``inner`` is of the stored kind merges that way into it (:meth:`GrounderConfig.merged_onto`).
    Any other override replaces.
    """
    if override is None:
        return stored
    if stored is None:
        return override
    return override.merged_onto(stored)


@overload
def build_grounder(config: ClipGrounderConfig, **runtime: Any) -> ClipGrounder: ...


@overload
def build_grounder(config: GrounderConfig | Mapping[str, Any] | None, **runtime: Any) -> Grounder: ...


def build_grounder(config: GrounderConfig | Mapping[str, Any] | None, **runtime: Any) -> Grounder:
    """The grounder object of ``config`` (a dict is read with :func:`grounder_config_from_dict`), built by its
    kind's :attr:`GrounderKind.build`.

    ``runtime`` goes to the grounder's constructor (the CLIP grounder's: ``backbone=`` a loaded model, ``cache=``).
    """
    config = as_grounder_config(config)
    grounder: Grounder = resolve(GROUNDERS[config.kind].build)(config, **runtime)
    return grounder
