"""One Ray local cluster shared by every integration test: starting one costs about two seconds; and
`database_incidental`, a test whose PostgreSQL variant runs only with `make test-all`."""

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


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A `database_incidental` test in a module run on both databases (`test_api_server.database`) tests
    the driver or the files, not the database: its PostgreSQL variant repeats the same work (45-58 s of
    the suite for the retried and the cancelled job), so it is `slow`."""
    for item in items:
        params = getattr(getattr(item, "callspec", None), "params", {})
        if item.get_closest_marker("database_incidental") and params.get("database") == "postgresql":
            item.add_marker(pytest.mark.slow)
