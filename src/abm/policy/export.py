"""Export a trained model for deployment: what ``abm export`` and the experiment engine's export job
(:mod:`abm.experiments.jobs`) run."""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from abm.files import FolderLock
from abm.policy.checkpoint import check_export_target, export_checkpoint, resolve_checkpoint


def export_model(run: str | Path, out: str | Path, dtype: str = "float32", overwrite: bool = False) -> Path:
    """Write ``run``'s latest checkpoint (a run folder, or a checkpoint file) to ``out`` without its training
    state, its floating-point weights stored as ``dtype`` (``float32``: unchanged, ``bfloat16``, ``float16``);
    returns the file written. ``out``'s folder is locked meanwhile (a zoo folder has one writer at a time).

    Raises:
        abm.errors.OutputError: ``out`` exists (without ``overwrite``) or is the source itself.
        abm.errors.DataError: no checkpoint, or one that does not read.
    """
    src = resolve_checkpoint(run)
    check_export_target(src, out, overwrite)
    with FolderLock(Path(out).parent, "abm export"):  # not while another command writes that folder
        written = export_checkpoint(src, out, None if dtype == "float32" else getattr(torch, dtype))
    logging.getLogger("abm").info("exported %s (%.1f MiB) -> %s (%.1f MiB)", src, src.stat().st_size / 2**20,
                                  written, written.stat().st_size / 2**20)
    return written
