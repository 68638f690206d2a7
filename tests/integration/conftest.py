"""One Ray local cluster shared by every integration test: starting one costs about two seconds."""

from __future__ import annotations

import tempfile

import pytest
import ray


@pytest.fixture(scope="session")
def ray_cluster():
    """A 2-CPU local Ray cluster whose session files live in a private temporary folder."""
    with tempfile.TemporaryDirectory(prefix="nbake-ray-", dir="/tmp") as temp_dir:
        ray.init(num_cpus=2, include_dashboard=False, _temp_dir=temp_dir, log_to_driver=False)
        try:
            yield ray
        finally:
            ray.shutdown()
