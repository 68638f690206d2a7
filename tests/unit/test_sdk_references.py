"""The SDK reads a job or an artifact reference the same way for every call (`references`), and its
exceptions' messages name the field at fault."""

from __future__ import annotations

import pytest
from neuralbake_client.errors import InvalidRequest, NotFound
from neuralbake_client.models import Job, Manifest
from neuralbake_client.references import NoArtifact, artifact_id_of, job_id_of

DIGEST = "ab" * 32
ARTIFACT = f"sha256:{DIGEST}"


def job(artifact_id: str | None, state: str = "SUCCEEDED") -> Job:
    return Job.model_construct(id="job-1", state=state, artifact_id=artifact_id)


def manifest() -> Manifest:
    return Manifest.model_construct(artifact_id=ARTIFACT, job_id="job-1")


def no_call(ref: str):
    raise AssertionError(f"fetched {ref}")


def test_every_reference_names_the_same_artifact():
    jobs = {"job-1": job(ARTIFACT)}
    for ref in (ARTIFACT, DIGEST, "job-1", jobs["job-1"], manifest()):
        assert artifact_id_of(ref, jobs.__getitem__) == ARTIFACT


def test_a_job_fetched_before_it_finished_is_fetched_again():
    assert artifact_id_of(job(None, "RUNNING"), {"job-1": job(ARTIFACT)}.__getitem__) == ARTIFACT
    with pytest.raises(NoArtifact, match="job-1 is FAILED and has no artifact"):
        artifact_id_of("job-1", {"job-1": job(None, "FAILED")}.__getitem__)


def test_every_reference_names_the_same_job():
    manifests = {ARTIFACT: manifest()}
    for ref in ("job-1", job(None), ARTIFACT, DIGEST, manifest()):
        assert job_id_of(ref, manifests.__getitem__) == "job-1"
    assert job_id_of("job-2", no_call) == "job-2"


def test_an_api_errors_message_names_its_field_once():
    error = InvalidRequest(422, "Unprocessable", "Extra inputs are not permitted", "params.layer")
    assert str(error) == "422 Unprocessable: params.layer: Extra inputs are not permitted"
    named = InvalidRequest(422, "Unprocessable", "params.layer: unknown", "params.layer")
    assert str(named) == "422 Unprocessable: params.layer: unknown"
    assert str(NotFound(404, "Not Found", "no artifact sha256:00")) == "404 Not Found: no artifact sha256:00"
