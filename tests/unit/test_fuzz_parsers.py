"""Bounded atheris runs of the parsers an attacker reaches (two seconds each, side by side): any
exception other than the parser's own 4xx error is a crash and fails the test with atheris's report.
Longer runs: `python -m tests.fuzz.targets <target> -max_total_time=600`."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TARGETS = ("scene", "archive", "wire", "last_event_id")  # the targets of tests/fuzz/targets.py
# The scene target starts at about 2.2 GB resident (torch, Numba, usd-core and pygltflib are imported by the
# scene loaders); the limit catches an input that more than doubles it, as an alias bomb would.
RSS_LIMIT_MB = 5120

ROOT = Path(__file__).resolve().parents[2]


def test_parsers_survive_bounded_fuzzing(tmp_path):
    pytest.importorskip("atheris")
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        "NBAKE_FUZZ_DIR": str(tmp_path),
    }
    runs = {
        name: subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tests.fuzz.targets",
                name,
                "-max_total_time=2",
                f"-rss_limit_mb={RSS_LIMIT_MB}",
            ],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for name in TARGETS
    }
    for name, run in runs.items():
        output, _ = run.communicate(timeout=300)
        report = "\n".join(line for line in output.splitlines() if not line.startswith("INFO: Instrumenting"))
        assert run.returncode == 0, f"{name}: {report[-3000:]}"
        assert "Done" in report, f"{name} did not run: {report[-3000:]}"
