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


def cpu_supports_bf16() -> bool:
    """Whether oneDNN reports native bf16 on this CPU (AVX512-BF16 / AMX). Without it, bf16 autocast on
    the CPU is emulated and measured 5-10x slower than float32 (docs/performance.md)."""
    import torch  # kept out of the module top: `abm.machine` is imported by light command modules

    try:
        return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a torch build without the oneDNN query
        return False
