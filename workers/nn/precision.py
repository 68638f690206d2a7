"""Whether a device multiplies bfloat16 matrices natively (and so faster than float32).

On a CPU that means the AVX-512 BF16 or AMX instructions: without them oneDNN emulates bfloat16 products,
which are then no faster than float32 ones. On CUDA, what `torch.cuda.is_bf16_supported` reports."""

from __future__ import annotations

import functools
from pathlib import Path

import torch

CPU_FLAGS = ("avx512_bf16", "amx_bf16")
CPUINFO = Path("/proc/cpuinfo")


def native_bfloat16(device: torch.device) -> bool:
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported()
    return device.type == "cpu" and _cpu_has_bfloat16()


@functools.cache
def _cpu_has_bfloat16() -> bool:
    try:
        text = CPUINFO.read_text()
    except OSError:  # not Linux: no way to tell, so float32
        return False
    lines = (line.split(":", 1) for line in text.splitlines() if line.startswith("flags"))
    flags = next((value.split() for _, value in lines), [])
    return any(flag in flags for flag in CPU_FLAGS)
