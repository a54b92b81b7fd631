"""A one-line description of the machine, printed by every benchmark next to its numbers."""

from __future__ import annotations

import os
import platform


def describe_machine() -> str:
    """CPU model, core count, torch version and threads, and the CUDA device when there is one."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    text = f"{cpu}, {os.cpu_count()} cores"
    try:
        import torch

        text += f", torch {torch.__version__}, {torch.get_num_threads()} threads"
        if torch.cuda.is_available():
            text += f", CUDA {torch.cuda.get_device_name()}"
    except ImportError:
        pass
    return text

