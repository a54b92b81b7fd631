"""One progress reporter for every command (:class:`Progress`).

On a terminal it is a tqdm bar. When the output is not a terminal (CI, ``nohup``, a pipe, a log file) or
the bar is turned off (``--no-progress``) it writes plain lines instead, at most one per ``every`` of the
work (10 %) or per ``interval_s`` (a minute), whichever comes first, plus one at the end, so a log stays
readable: ``train abm/small: 140/1400 steps (10 %), 2.1 min, ~19 min left, loss=0.412``.

The time left is the rate since the first unit finished times the units left: the start-up before it (imports,
loading a model, a renderer's first frame) is not a rate, and counting it made the first estimate of a 26-minute
evaluation read ~84 minutes. Until :data:`MIN_UNITS_FOR_ETA` units have finished since then, lines say
``estimating time left``.
"""

from __future__ import annotations

import sys
import time
from typing import IO, Any

#: units finished after the first one before a line estimates the time left
MIN_UNITS_FOR_ETA = 3


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds >= 60 else f"{seconds:.0f} s"


class Progress:
    """Progress of ``total`` units of work (see the module docstring).

    Args:
        total: units of work (steps, episodes, ...).
        desc: what is done, at the start of every line.
        unit: the units' name in the plain lines (``steps``, ``ep``).
        initial: units already done (a resumed job).
        bar: a bar on a terminal (``False``: plain lines even there).
        enabled: ``False`` reports nothing (e.g. the non-zero ranks of a distributed job).
        stream: where to write (default ``sys.stderr``, looked up when writing).
        every: a plain line every this fraction of ``total``.
        interval_s: ... or after this many seconds without one.
    """

    def __init__(self, total: int, desc: str, unit: str = "it", initial: int = 0, bar: bool = True,
                 enabled: bool = True, stream: IO[str] | None = None, every: float = 0.1,
                 interval_s: float = 60.0) -> None:
        self.total, self.desc, self.unit, self.n = int(total), desc, unit, int(initial)
        self.enabled, self._stream = enabled, stream
        self.every, self.interval_s = every, interval_s
        self.postfix: dict[str, Any] = {}
        self._start_n, self._t0 = self.n, time.monotonic()
        self._last_t, self._last_n = self._t0, self.n
        self._first: tuple[float, int] | None = None  # (time, units) when the first unit of this process finished
        self._closed = False
        self._bar = None
        if enabled and bar and self.stream.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, file=self.stream,
                             dynamic_ncols=True)

    @property
    def stream(self) -> IO[str]:
        return self._stream or sys.stderr

    @property
    def interactive(self) -> bool:
        """Whether a bar is drawn (else plain lines are written)."""
        return self._bar is not None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, n: int = 1, **postfix: Any) -> None:
        """``n`` more units done; ``postfix`` values (``loss=0.41``) are shown beside the count."""
        self.n += n
        self.postfix.update(postfix)
        if self._first is None:
            self._first = (time.monotonic(), self.n)
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
            if postfix:
                self._bar.set_postfix({k: _text(v) for k, v in self.postfix.items()}, refresh=False)
            return
        now = time.monotonic()
        step = max(1, round(self.every * self.total)) if self.total else 0
        crossed = step and self.n // step > self._last_n // step
        if crossed or now - self._last_t >= self.interval_s:
            self._line(now)

    def write(self, message: str) -> None:
        """A line of its own (above the bar on a terminal)."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        """End the bar, or write the final plain line (unless the last one already showed the end)."""
        if self._closed:
            return
        self._closed = True
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.close()
        elif self.n != self._last_n:  # nothing was done (a resumed job already complete): nothing to say
            self._line(time.monotonic())

    def _line(self, now: float) -> None:
        elapsed = now - self._t0
        done = self.n - self._start_n
        text = f"{self.desc}: {self.n}/{self.total} {self.unit}"
        if self.total:
            text += f" ({100 * self.n / self.total:.0f} %)"
        text += f", {_minutes(elapsed)}"
        if 0 < done and self.n < self.total:
            text += f", {self._left(now)}"
        if self.postfix:
            text += ", " + ", ".join(f"{k}={_text(v)}" for k, v in self.postfix.items())
        print(text, file=self.stream, flush=True)
        self._last_t, self._last_n = now, self.n


    def _left(self, now: float) -> str:
        """``~T left`` from the rate since the first unit finished, or ``estimating time left`` (module doc)."""
        assert self._first is not None  # a unit was done
        since, units = now - self._first[0], self.n - self._first[1]
        if units < MIN_UNITS_FOR_ETA or since <= 0:
            return "estimating time left"
        return f"~{_minutes(since / units * (self.total - self.n))} left"


def _text(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)
