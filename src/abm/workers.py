"""Worker processes that never outlive the command that started them.

Pools of ``abm data generate`` and ``abm eval`` start their workers with :func:`die_with_parent`: on
Linux the kernel sends the worker SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``), so a
``kill -9`` of the command leaves no worker running and writing files. Elsewhere a watchdog thread
polls the parent id and exits the worker when it changes.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

_PR_SET_PDEATHSIG = 1


def die_with_parent(poll_s: float = 1.0) -> None:
    """Make the calling process exit when its parent process dies (call it first in a worker)."""
    import multiprocessing

    origin = multiprocessing.parent_process()
    parent = origin.pid if origin is not None and origin.pid else os.getppid()
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0:
                if os.getppid() != parent:  # the parent died before prctl took effect
                    os._exit(1)
                return
        except (OSError, AttributeError):
            pass

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(1)
            time.sleep(poll_s)

    threading.Thread(target=watch, daemon=True, name="abm-parent-watchdog").start()
