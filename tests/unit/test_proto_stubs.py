"""The checked-in gRPC stubs are exactly what `make proto` generates from proto/, and the protos pass
`buf lint` (STANDARD) when buf is installed."""

from __future__ import annotations

import filecmp
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CHECKED_IN = ROOT / "clients/python/neuralbake/v1"


def test_checked_in_stubs_match_a_fresh_generation(tmp_path):
    # -o: treat the venv as up to date, so the test never reinstalls it
    done = subprocess.run(
        ["make", "-s", "-o", ".venv/.installed", "proto", f"PROTO_OUT={tmp_path}", f"PY={sys.executable}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    fresh = tmp_path / "neuralbake/v1"
    generated = sorted(p.name for p in fresh.glob("*_pb2*.py"))
    assert generated == sorted(p.name for p in CHECKED_IN.glob("*_pb2*.py")), "run `make proto`"
    _, mismatch, errors = filecmp.cmpfiles(fresh, CHECKED_IN, generated, shallow=False)
    assert not mismatch and not errors, f"stale stubs {mismatch + errors}: run `make proto`"


def test_protos_pass_buf_lint():
    buf = shutil.which("buf", path=str(Path(sys.executable).parent))
    if buf is None:
        pytest.skip("buf is not installed (pip install buf-bin)")
    done = subprocess.run([buf, "lint", "proto"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
