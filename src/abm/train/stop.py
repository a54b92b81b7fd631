"""SIGTERM during training: finish the optimiser step, save a checkpoint, stop like Ctrl-C.

A scheduler that stops a job (the experiment engine, Slurm, ``kill``, ``torchrun`` forwarding its own
termination) sends SIGTERM, whose default action ends the process where it stands: everything since the last
periodic checkpoint is lost. Inside :class:`StopOnTerm` the signal only raises a flag; the training loop reads
it after each optimiser step (under ``torchrun`` reduced over the ranks with the step's losses, so every rank
stops after the same step), so the checkpoint it then saves holds whole steps.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType, TracebackType
from typing import Any


class StopOnTerm:
    """Context manager: while inside, SIGTERM sets :attr:`flag` instead of ending the process.

    The first SIGTERM puts the previous handler back, so a second one acts as it did before (by default: ends the
    process at once, for a step that does not end). Outside the main thread (where Python cannot install
    handlers) it installs nothing and the flag stays down. The previous handler is restored on exit; one
    training loop at a time (not re-entrant).
    """

    def __init__(self) -> None:
        self.flag = False
        self._previous: Any = None
        self._installed = False

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.flag = True
        signal.signal(signal.SIGTERM, self._previous)  # a second SIGTERM acts as before (by default: ends it now)

    def __enter__(self) -> StopOnTerm:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, self._handler)
            self._installed = True
        return self

    def __exit__(self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None) -> None:
        if self._installed:
            signal.signal(signal.SIGTERM, self._previous)
            self._installed = False
