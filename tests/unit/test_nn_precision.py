"""Native bfloat16 is read from the CPU's flags: AVX-512 BF16 or AMX, nothing else."""

from __future__ import annotations

import pytest
import torch

from workers.nn import precision


@pytest.mark.parametrize(
    ("flags", "native"),
    [
        ("fpu avx2 avx512f avx512bw", False),
        ("fpu avx512f avx512_bf16", True),
        ("fpu amx_tile amx_bf16", True),
    ],
)
def test_native_bfloat16_on_a_cpu_is_its_bf16_instructions(tmp_path, monkeypatch, flags, native):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(f"processor\t: 0\nflags\t\t: {flags}\nbugs\t\t: spectre_v1\n")
    monkeypatch.setattr(precision, "CPUINFO", cpuinfo)
    precision._cpu_has_bfloat16.cache_clear()
    try:
        assert precision.native_bfloat16(torch.device("cpu")) is native
    finally:
        precision._cpu_has_bfloat16.cache_clear()


def test_without_cpuinfo_a_cpu_is_taken_as_float32_only(tmp_path, monkeypatch):
    monkeypatch.setattr(precision, "CPUINFO", tmp_path / "missing")
    precision._cpu_has_bfloat16.cache_clear()
    try:
        assert precision.native_bfloat16(torch.device("cpu")) is False
    finally:
        precision._cpu_has_bfloat16.cache_clear()
