"""Stopping a training whose loss curve has flattened (``abm train --stop-when-flat W``; docs/policy.md).

The rule, checked at every checkpoint step ``s`` once ``s`` reaches the rule's first step (default half the run):
the mean of the logged loss over the last ``W`` steps (rows with step in ``(s - W, s]``) is compared with the mean
over the ``W`` steps before (``(s - 2W, s - W]``); when it improved on it by less than ``tolerance`` (relative:
``(earlier - recent) / earlier``), training ends at ``s``. The loss is the one the run logs in ``log.csv``:
``val_total`` when the run has held-out data (``--val-data``), else the training ``total``. Reading the logged rows,
not every step's loss, makes the rule the same on a finished run's ``log.csv`` (:func:`flat_stop_in_log`, how the
defaults were chosen) as inside the training loop, and a resumed run decides as the uninterrupted one would.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

#: the relative improvement below which a window counts as flat (measured on the second edition's curves:
#: docs/policy.md, "Stopping a flat training")
DEFAULT_TOLERANCE = 0.02


@dataclass(frozen=True)
class FlatStop:
    """Why a training stopped early: at ``step`` the mean loss over the last ``window`` steps (``recent``) improved on
    the mean of the ``window`` steps before (``earlier``) by less than ``tolerance`` (relative); ``loss`` names the
    log.csv column (``total`` or ``val_total``). Its :meth:`to_dict` is what summary.json, config.json and the last
    checkpoint record (``stopped: "flat"``)."""

    step: int
    recent: float
    earlier: float
    window: int
    tolerance: float
    loss: str

    @property
    def improvement(self) -> float:
        """``(earlier - recent) / earlier``: the fraction of the loss the last window took off."""
        return (self.earlier - self.recent) / abs(self.earlier)

    def to_dict(self) -> dict[str, Any]:
        """``{"stopped": "flat", "flat": {step, recent, earlier, window, tolerance, loss, improvement}}``."""
        return {"stopped": "flat", "flat": {**asdict(self), "improvement": self.improvement}}

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> FlatStop | None:
        """The stop a summary, config.json or checkpoint records (:meth:`to_dict`'s keys among its own), or ``None``
        when it records none (a run that trained every step, or one written before the rule existed)."""
        if record.get("stopped") != "flat":
            return None
        flat = record["flat"]
        return cls(int(flat["step"]), float(flat["recent"]), float(flat["earlier"]), int(flat["window"]),
                   float(flat["tolerance"]), str(flat["loss"]))

    def message(self) -> str:
        """The one log line that says it."""
        return (f"abm train: stopped at step {self.step}: the training curve is flat (mean {self.loss} over steps "
                f"{self.step - self.window + 1}-{self.step} {self.recent:.4g}, over the {self.window} steps before "
                f"{self.earlier:.4g}: {self.improvement:+.1%}, less than {self.tolerance:.1%})")


@dataclass(frozen=True)
class FlatRule:
    """The rule's settings: ``window`` steps per mean, the relative ``tolerance``, and ``first_step``, the first step
    at which it may stop a run."""

    window: int
    tolerance: float
    first_step: int

    def check(self, rows: Sequence[tuple[int, float]], step: int, loss: str = "total") -> FlatStop | None:
        """Whether to stop at ``step`` given the logged ``(step, loss)`` rows up to it; ``None``: train on (too
        early, a window without a row, or the loss still falling by at least the tolerance)."""
        if step < max(self.first_step, 2 * self.window):
            return None
        recent = [v for s, v in rows if step - self.window < s <= step]
        earlier = [v for s, v in rows if step - 2 * self.window < s <= step - self.window]
        if not recent or not earlier:
            return None
        found = FlatStop(step, sum(recent) / len(recent), sum(earlier) / len(earlier), self.window, self.tolerance,
                         loss)
        return found if found.earlier != 0 and found.improvement < self.tolerance else None


def flat_stop_in_log(log: Path, rule: FlatRule, checkpoint_every: int) -> FlatStop | None:
    """Where ``rule`` would have stopped the run that wrote ``log`` (a ``log.csv``) checkpointing every
    ``checkpoint_every`` steps; ``None`` when it would have trained to its last logged step."""
    with log.open() as f:
        rows = list(csv.DictReader(f))
    loss = "val_total" if any(r.get("val_total") for r in rows) else "total"
    curve = [(int(r["step"]), float(r[loss])) for r in rows if r.get(loss)]
    for step in range(checkpoint_every, curve[-1][0] + 1 if curve else 0, checkpoint_every):
        stop = rule.check([(s, v) for s, v in curve if s <= step], step, loss)
        if stop is not None:
            return stop
    return None
