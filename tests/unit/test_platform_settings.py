"""Both servers read the deployment's database and store from the same `NBAKE_*` variables through the
settings base (`services.platform.settings`); a command's options win over the environment."""

from __future__ import annotations

from services.api.settings import ServiceSettings
from services.inference.settings import InferenceSettings

DATABASE = "postgresql://db.example/nbake"


def test_both_servers_read_the_shared_variables_and_their_own(monkeypatch, tmp_path):
    monkeypatch.setenv("NBAKE_DATABASE_URL", DATABASE)
    monkeypatch.setenv("NBAKE_STORE_URL", "s3://bucket/prefix")
    monkeypatch.setenv("NBAKE_MAX_RUNNING", "3")
    monkeypatch.setenv("NBAKE_INFERENCE_DEVICE", "cpu")
    jobs = ServiceSettings.from_env(tmp_path, max_running=None)
    inference = InferenceSettings.from_env(tmp_path, memory_budget_bytes=None)
    for shared in (jobs, inference.shared):
        assert (shared.db_url, shared.store, shared.data_dir) == (DATABASE, "s3://bucket/prefix", tmp_path)
    assert (jobs.max_running, inference.device) == (3, "cpu")


def test_an_option_wins_over_the_environment_and_an_unset_variable_keeps_the_default(monkeypatch, tmp_path):
    monkeypatch.setenv("NBAKE_MAX_RUNNING", "3")
    monkeypatch.delenv("NBAKE_DATABASE_URL", raising=False)
    monkeypatch.setenv("NBAKE_INFERENCE_MEMORY_BYTES", "")  # set but empty: not given
    assert ServiceSettings.from_env(tmp_path, max_running=5).max_running == 5
    inference = InferenceSettings.from_env(tmp_path, device="cuda:1")
    assert inference.device == "cuda:1"
    assert inference.memory_budget_bytes == InferenceSettings.model_fields["memory_budget_bytes"].default
    assert inference.shared.db_url == f"sqlite:///{(tmp_path / 'jobs.db').resolve()}"
