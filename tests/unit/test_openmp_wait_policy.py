"""Every entry point that loads torch has OpenMP's idle threads wait passively by then: each imports
`workers`, which sets the policy, before torch (the client's remote commands load neither)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
# Records the wait policy at the moment torch is first imported, then imports the entry point.
PROBE = """
import importlib, os, sys
seen = {}
class Probe:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" and "torch" not in seen:
            seen["torch"] = os.environ.get("OMP_WAIT_POLICY")
        return None
sys.meta_path.insert(0, Probe())
importlib.import_module(sys.argv[1])
import torch  # an entry point that does not load torch at import loads it later, after the package
print(seen.get("torch"))
"""


def policy_when_torch_loads(module: str, **env: str) -> str:
    clean = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"} | env
    clean["PYTHONPATH"] = f"{REPO}{os.pathsep}{REPO / 'clients' / 'python'}"
    done = subprocess.run(
        [sys.executable, "-c", PROBE, module], env=clean, capture_output=True, text=True, check=True
    )
    return done.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize(
    "module",
    [
        "services.api.app",
        "services.inference.app",
        "services.cli.serve",
        "services.cli.serve_inference",
        "services.cli.render",
        "workers.driver.jobs",
    ],
)
def test_torch_loads_with_passive_waiting(module):
    assert policy_when_torch_loads(module) == "PASSIVE"


def test_a_policy_the_environment_sets_is_kept():
    assert policy_when_torch_loads("workers.driver.jobs", OMP_WAIT_POLICY="ACTIVE") == "ACTIVE"


@pytest.mark.parametrize(
    ("first", "warned"), [("import torch; import workers", True), ("import workers; import torch", False)]
)
def test_a_program_that_loads_torch_first_is_warned(first, warned):
    clean = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    clean["PYTHONPATH"] = str(REPO)
    done = subprocess.run(
        [sys.executable, "-c", first], env=clean, capture_output=True, text=True, check=True
    )
    assert ("import workers first" in done.stderr) is warned
