"""Policies for evaluation rollouts, loaded so that an outcome depends on (model file, task, split, seed,
settings) alone — not on the command, ``--workers``, ``--gifs``, the backend or the runs before it in a worker.

* :func:`rollout_state` runs a rollout with one torch thread and the global RNGs seeded from the scene seed
  (and puts the caller's back afterwards). The thread count matters: a CPU network's float sums are ordered by
  thread, so a process with torch's default (one thread per core) predicts keyframes millimetres away from a
  one-thread worker's, and a borderline grasp can flip.
* :func:`load_policy` gives every rollout a fresh copy of the policy as loaded (``copy.deepcopy`` of a per-process
  original), so nothing one episode fills (the language and CLIP text caches, the grounding cache's memory, a
  tracking grounder's target) reaches the next one.
* A checkpoint names its CLIP by the path it was trained with, often relative (the zoo's ``models/benchmark-clip``).
  :func:`clip_root` finds the folder that path is relative to — the checkpoint's folder or the nearest parent that
  holds it, else the working folder — and the policy is built there, so ``abm eval`` and ``abm zoo eval`` work
  from any working folder.
* :func:`check_policies` loads each run once before the first rollout, so a missing CLIP or a broken file is one
  error naming the file and the fix instead of a table of crashed episodes.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import os
import random
from collections.abc import Iterator, Mapping, Sequence
from functools import cache
from pathlib import Path
from typing import Any

import torch

from abm.errors import CheckpointError
from abm.evaluation.settings import EvalSettings
from abm.grounding.config import GrounderConfig, grounder_config_from_dict, grounder_from_flags
from abm.grounding.grounders import ClipGrounder
from abm.policy import KeyframePolicy
from abm.policy.checkpoint import load_checkpoint, resolve_checkpoint
from abm.policy.language_config import LanguageConfig, as_language_config

ROLLOUT_THREADS = 1
"""torch threads of every rollout (the pool workers' and Ray actors' count, also for ``--workers 1`` in-process)."""

_ORIGINALS: dict[tuple[Any, ...], KeyframePolicy] = {}  # per process: policies as loaded, never acted with
_CLIP_MEMORIES: dict[str, ClipGrounder] = {}  # per process and CLIP: the grounder whose memories the others use


class PolicyLoadError(CheckpointError):
    """A run's policy cannot be built for evaluation (the message names the file and the fix)."""


@cache
def code_digest() -> str:
    """12 hex digits of SHA-1 over the abm package's Python source as this process found it."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode() + b"\x00" + path.read_bytes())
    return h.hexdigest()[:12]


@contextlib.contextmanager
def rollout_state(seed: int) -> Iterator[None]:
    """One torch thread, and the torch and ``random`` global RNGs seeded with ``seed``; all restored on exit
    (numpy's global RNG needs nothing: abm draws from seeded ``numpy.random.Generator`` s only, ruff NPY002)."""
    threads = torch.get_num_threads()
    py_state = random.getstate()
    torch.set_num_threads(ROLLOUT_THREADS)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            random.seed(seed)
            yield
    finally:
        torch.set_num_threads(threads)
        random.setstate(py_state)


def clip_names(ckpt: Mapping[str, Any]) -> list[str]:
    """The CLIP weights a checkpoint names, without repeats: the ``model`` of the CLIP its grounder and its language
    encoder use (:meth:`~abm.grounding.config.GrounderConfig.clip_model`, a tracking grounder's inner one too)."""
    stored = ckpt.get("grounder")  # the dict forms (file boundary); no grounder: none named
    configs: list[GrounderConfig | LanguageConfig] = [] if stored is None else [grounder_config_from_dict(stored)]
    if ckpt.get("language") is not None:
        configs.append(as_language_config(ckpt["language"]))
    models = [clip.model for config in configs if (clip := config.clip_model()) is not None and clip.model]
    return list(dict.fromkeys(models))


def needs_segmentation(policy: KeyframePolicy) -> bool:
    """Whether a rollout of ``policy`` needs the simulator's segmentation: when its grounder is the oracle (also
    inside another, e.g. tracking's first grounding), which reads the ground-truth masks, or is not described
    by a configuration. Other policies never read it, so their rollouts skip the segmentation draw of every
    camera (:class:`abm.sim.cameras.CameraRig`), which changes none of their observations' colour or depth."""
    spec = policy.grounder_spec
    return spec is None or "oracle" in _grounder_kinds(spec)


def _grounder_kinds(spec: Any) -> list[str]:
    """The ``kind`` of a grounder configuration and of every configuration nested in it."""
    found: list[str] = []
    if isinstance(spec, Mapping):
        found.append(str(spec.get("kind")))
        for value in spec.values():
            found += _grounder_kinds(value)
    return found


def _relative_folder_name(name: str) -> bool:
    """Whether a CLIP name may be a folder relative to where the model was trained (not a test CLIP or an
    absolute or home path; hub names such as ``openai/clip-vit-base-patch32`` qualify too, and simply are not
    found as folders)."""
    return not (name == "tiny" or name.startswith(("random:", "/", "~")))


def _holds(folder: Path, name: str) -> bool:
    return (folder / name / "config.json").is_file()


def clip_root(checkpoint: str | Path, names: Sequence[str]) -> Path | None:
    """The folder the checkpoint's relative CLIP folders ``names`` are found in: the checkpoint's folder or the
    nearest of its parents that holds every one of them, else ``None`` (the working folder, as ``load_clip``
    resolves them)."""
    relative = [n for n in names if _relative_folder_name(n)]
    if not relative:
        return None
    start = Path(checkpoint).resolve().parent
    for folder in (start, *start.parents):
        if all(_holds(folder, n) for n in relative):
            return folder
    return None


def checkpoint_clips(run: str | Path) -> dict[str, Path | None]:
    """CLIP name -> the folder it resolves to for this run (:func:`clip_root`), ``None`` for one found nowhere
    (a hub name, or missing); test CLIPs and absolute paths map to themselves."""
    path = resolve_checkpoint(run).resolve()
    ckpt = load_checkpoint(path)
    names = clip_names(ckpt)
    root = clip_root(path, names) or Path.cwd()
    out: dict[str, Path | None] = {}
    for name in names:
        if not _relative_folder_name(name):
            out[name] = Path(name).expanduser() if name.startswith(("/", "~")) else Path(name)
        else:
            out[name] = (root / name).resolve() if _holds(root, name) else None
    return out


def _build(path: Path, settings: EvalSettings) -> KeyframePolicy:
    clip_model = settings.clip_model
    if clip_model and Path(clip_model).expanduser().exists():  # the user's own path: relative to the working folder
        clip_model = str(Path(clip_model).expanduser().resolve())
    grounder = grounder_from_flags(settings.grounder, clip_model)
    ckpt = load_checkpoint(path)
    root = clip_root(path, clip_names(ckpt))
    with contextlib.chdir(root) if root is not None else contextlib.nullcontext():
        policy = KeyframePolicy.from_checkpoint(path, device=settings.device, grounder=grounder)
        policy.grounder  # noqa: B018 - the grounder loads lazily: build it here, where its CLIP path resolves
    for clip in clip_grounders(policy.grounder):  # one set of memories per CLIP in the process
        first = _CLIP_MEMORIES.setdefault(clip.model_name, clip)
        if first is not clip:
            clip.share_memories(first)
    return policy


def clip_grounders(grounder: Any) -> list[ClipGrounder]:
    """The CLIP grounders in ``grounder``: itself, or the one a tracking grounder wraps (``inner``)."""
    out: list[ClipGrounder] = []
    while grounder is not None:
        if isinstance(grounder, ClipGrounder):
            out.append(grounder)
        grounder = getattr(grounder, "inner", None)
    return out


def load_policy(run: str | Path, settings: EvalSettings) -> KeyframePolicy:
    """A fresh copy of the run's policy for one rollout.

    The checkpoint is read once per process and file version; every call returns a deep copy of that original,
    so no state carries over between rollouts, except what is remembered exactly: the language tokens of each
    text, and the CLIP grounder's frozen backbone, text features, crop embeddings and grounding results
    (:meth:`abm.policy.keyframe_policy.KeyframePolicy.exact_memories`), which every copy shares with the original and
    every policy of the process grounding with the same CLIP shares with the others. A rollout's outcome is the
    one it has alone (the memories give what would be computed again), and the second model rolled out on a
    scene grounds its first observation from memory (:meth:`abm.sim.simulation.Simulation.first_observation`
    gives it the same observation).
    """
    path = resolve_checkpoint(run).resolve()
    stat = path.stat()
    key = (str(path), stat.st_mtime_ns, stat.st_size, settings.grounder, settings.clip_model, settings.device)
    if key not in _ORIGINALS:
        _ORIGINALS[key] = _build(path, settings)
    original = _ORIGINALS[key]
    return copy.deepcopy(original, {id(obj): obj for obj in original.exact_memories()})


def forget_policies() -> None:
    """Drop this process's loaded originals (the driver after :func:`check_policies`, when workers roll out)."""
    _ORIGINALS.clear()
    _CLIP_MEMORIES.clear()


def check_policies(runs: Sequence[str | Path], settings: EvalSettings) -> None:
    """Load every run's policy once; raise :class:`PolicyLoadError` (one line: the file, what failed, the fix)
    for the first that cannot be built."""
    for run in runs:
        try:
            load_policy(run, settings)
        except Exception as err:  # noqa: BLE001 - any failure here would crash every episode of the run
            raise PolicyLoadError(load_error_message(run, err)) from err


def load_error_message(run: str | Path, err: BaseException) -> str:
    """One line: which run failed to load, why, and what to do."""
    text = " ".join(str(err).split()) or type(err).__name__
    try:
        folder = resolve_checkpoint(run).resolve().parent
        missing = [n for n, found in checkpoint_clips(run).items() if found is None and _relative_folder_name(n)]
    except (OSError, ValueError, KeyError):
        missing = []
    if missing:
        return (f"cannot load the policy {run}: its CLIP {', '.join(missing)} (a folder relative to where the model "
                f"was trained, or a hub name) was found neither in {folder} or one of its parents nor in the working "
                f"folder {os.getcwd()} ({type(err).__name__}: {text}); put the CLIP folder at that relative path "
                f"next to the model (the zoo keeps it at models/benchmark-clip), or run from the folder that holds it")
    return (f"cannot load the policy {run}: {type(err).__name__}: {text}; fix the file or the evaluation "
            f"settings (--grounder, --clip-model, --device) and run the command again")
