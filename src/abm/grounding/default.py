"""The grounder a command uses when none is named: one resolution order for every command.

``abm quickstart``, ``abm train``, ``abm ground``, ``abm eval`` (when it needs a grounder) and ``abm zoo eval`` all
call :func:`default_grounder` and print its :meth:`GrounderChoice.startup_line`:

1. ``--clip-model`` when given (an error if its weights are not there: a named model is never swapped for another);
2. the pretrained CLIP (:data:`abm.configuration.CPU_CLIP_MODEL` on the CPU, ``GPU_CLIP_MODEL`` on CUDA) when its
   weights are in the local Hugging Face cache (or, for the quickstart only, when it can download them);
3. the benchmark CLIP committed with the model zoo (``models/benchmark-clip`` in a checkout; ``$ABM_BENCHMARK_CLIP``
   overrides, ``~/.cache/abm/benchmark-clip`` is the last place looked; train one with ``abm clip train``);
4. the oracle grounder (the simulator's segmentation), with a loud warning: its masks are ground truth, so a
   result measures the policy, not grounding.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from abm.configuration import CPU_CLIP_MODEL, GPU_CLIP_MODEL
from abm.errors import ConfigError

BENCHMARK_CLIP_ENV = "ABM_BENCHMARK_CLIP"
DEFAULT_BENCHMARK_CLIP = "~/.cache/abm/benchmark-clip"
ZOO_BENCHMARK_CLIP = Path("models/benchmark-clip")  # committed with the model zoo (abm zoo list)


def benchmark_clip_dir() -> Path:
    """Where the benchmark CLIP is looked for (``abm clip train --out DIR``): ``$ABM_BENCHMARK_CLIP``, else the
    model zoo's copy in a repository checkout (``models/benchmark-clip``, relative to the working folder), else
    ``~/.cache/abm/benchmark-clip``."""
    if os.environ.get(BENCHMARK_CLIP_ENV):
        return Path(os.environ[BENCHMARK_CLIP_ENV]).expanduser()
    if (ZOO_BENCHMARK_CLIP / "config.json").is_file():
        return ZOO_BENCHMARK_CLIP
    return Path(DEFAULT_BENCHMARK_CLIP).expanduser()


def hub_reachable(host: str = "huggingface.co", timeout_s: float = 3.0) -> bool:
    """Whether the model hub answers a TCP connection within ``timeout_s`` (so a download is worth trying)."""
    import socket

    try:
        with socket.create_connection((host, 443), timeout=timeout_s):
            return True
    except OSError:
        return False


def clip_present(model: str) -> bool:
    """Whether the weights of ``model`` are on this machine without a download: a folder written by
    ``save_pretrained`` (its ``config.json``), a hub name in the local Hugging Face cache, or a test-only
    random CLIP ('tiny', 'random:ARCH')."""
    if model == "tiny" or model.startswith("random:"):
        return True
    path = Path(model).expanduser()
    if path.is_dir():
        return (path / "config.json").is_file()
    if "/" not in model or model.startswith((".", "/", "~")):
        return False
    try:
        from huggingface_hub import try_to_load_from_cache
    except ImportError:
        return False
    return isinstance(try_to_load_from_cache(model, "config.json"), str)


@dataclass(frozen=True)
class GrounderChoice:
    """The grounder :func:`default_grounder` picked.

    Attributes:
        kind: ``clip`` or ``oracle``.
        model: the CLIP's hub name or folder (``None`` for the oracle).
        source: ``given`` (``--clip-model``), ``pretrained``, ``benchmark`` or ``oracle``.
        description: one line for start-up lines and reports.
    """

    kind: str
    model: str | None
    source: str
    description: str

    @property
    def options(self) -> dict[str, str]:
        """The grounder's options (``{"model": ...}`` for a CLIP, ``{}`` for the oracle)."""
        return {"model": self.model} if self.model else {}

    def startup_line(self, command: str) -> str:
        """``abm COMMAND: grounder: ...`` — every command prints the one it uses before any work."""
        return f"abm {command}: grounder: {self.description}"


ORACLE_WARNING = (
    "WARNING: using the ORACLE grounder (simulator segmentation) instead of CLIP; the masks are ground truth, so "
    "the results measure the policy, not CLIP grounding. Provide weights with --clip-model DIR (the checkout's "
    "models/benchmark-clip, or set $ABM_BENCHMARK_CLIP), or train the benchmark CLIP once: "
    "abm clip train --out {bench} (see docs/grounding.md).")


def default_grounder(clip_model: str | None = None, device: str = "cpu", *, download: bool = False,
                     clip_only: bool = False, loader: Callable[[str, bool], object] | None = None) -> GrounderChoice:
    """The grounder to use when the command line names none (see the module docstring for the order).

    Args:
        clip_model: ``--clip-model``; when given it is the answer, or :class:`~abm.errors.ConfigError` when absent.
        device: the command's device (the pretrained CLIP is the GPU-sized one on CUDA).
        download: try to download the pretrained CLIP when it is not cached (the quickstart, when the hub answers;
            ``abm ground --allow-download``).
        clip_only: a CLIP was asked for (``--grounder clip``): :class:`~abm.errors.ConfigError` instead of the oracle.
        loader: ``loader(model, allow_download)`` loads the weights and raises ``OSError`` when they cannot be
            had; used for the download (default :func:`abm.grounding.clip.load_clip` on the CPU).
    """
    if clip_model:
        if not clip_present(clip_model) and not _fetch(clip_model, download, loader):
            raise ConfigError(f"--clip-model {clip_model}: no CLIP weights there (a folder written by abm clip train "
                              f"or save_pretrained, or a hub name in the local cache; the committed benchmark CLIP is "
                              f"{ZOO_BENCHMARK_CLIP} in a checkout)")
        return GrounderChoice("clip", clip_model, "given", f"CLIP {clip_model} (--clip-model)")
    pretrained = GPU_CLIP_MODEL if str(device).startswith("cuda") else CPU_CLIP_MODEL
    if clip_present(pretrained) or _fetch(pretrained, download, loader):
        return GrounderChoice("clip", pretrained, "pretrained", f"pretrained CLIP {pretrained}")
    bench = benchmark_clip_dir()
    if clip_present(str(bench)):
        return GrounderChoice("clip", str(bench), "benchmark",
                              f"benchmark CLIP trained on ABM-Bench renders ({bench}; abm clip train)")
    if clip_only:
        raise ConfigError(f"no CLIP weights found: the pretrained {pretrained} is not in the local cache "
                          f"({'the download failed' if download else 'no download without --allow-download'}) and "
                          f"there is no benchmark CLIP in {bench} (the committed one is {ZOO_BENCHMARK_CLIP} in a "
                          f"checkout, or set ${BENCHMARK_CLIP_ENV}); give --clip-model DIR, or train one: "
                          f"abm clip train --out {bench}")
    print(f"WARNING: no CLIP weights found (pretrained {pretrained} is not cached; no benchmark CLIP in {bench})\n"
          + ORACLE_WARNING.format(bench=bench), file=sys.stderr)
    return GrounderChoice("oracle", None, "oracle",
                          "oracle (simulator segmentation: ground-truth masks, an upper bound; no CLIP weights found)")


def _fetch(model: str, download: bool, loader: Callable[[str, bool], object] | None) -> bool:
    """Download ``model``'s weights when allowed; whether they are now here."""
    if not download:
        return False
    if loader is None:
        from abm.grounding.clip import ClipWeightsNotFoundError, load_clip  # torch and transformers: only here

        def loader(name: str, allow: bool) -> object:
            try:
                return load_clip(name, device="cpu", allow_download=allow)
            except ClipWeightsNotFoundError as err:
                raise OSError(str(err)) from err
    try:
        loader(model, True)
    except OSError:
        return False
    return True
