"""What a job or an artifact is named by, read once for every SDK call and `nbake` command, so that each
accepts the same references: a job (`job-...` or a `Job`) or an artifact (its id `sha256:<hex>`, the bare
hex digest, or a `Manifest`). A call about an artifact given a job takes the job's artifact; a call about
a job given an artifact takes the job that made it.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import TYPE_CHECKING

from neuralbake_client.errors import NeuralbakeError

if TYPE_CHECKING:
    from neuralbake_client.models import Job, Manifest

JOB_PREFIX, ARTIFACT_PREFIX = "job-", "sha256:"
HEX_DIGEST = re.compile(r"[0-9a-f]{64}")


class NoArtifact(NeuralbakeError):
    """An artifact was asked of a job that has none (yet): it has not succeeded."""


def names_a_job(ref: str) -> bool:
    return ref.startswith(JOB_PREFIX)


def names_an_artifact(ref: str) -> bool:
    """An artifact id or a bare digest (not a job id)."""
    return ref.startswith(ARTIFACT_PREFIX) or HEX_DIGEST.fullmatch(ref) is not None


def as_artifact_id(ref: str) -> str:
    """`sha256:<hex>` for a bare digest; anything else as it is (the server judges it)."""
    return ARTIFACT_PREFIX + ref if HEX_DIGEST.fullmatch(ref) else ref


# The models (pydantic) are imported by the functions that take them, so that `nbake` reads references
# without loading pydantic at start-up.


def job_id_of(ref: Job | Manifest | str, manifest: Callable[[str], Manifest]) -> str:
    """The job's id; for an artifact, its job's (`manifest` fetches an artifact's manifest by id)."""
    from neuralbake_client.models import Job, Manifest

    if isinstance(ref, Job):
        return ref.id
    if isinstance(ref, Manifest):
        return ref.job_id
    return manifest(as_artifact_id(ref)).job_id if names_an_artifact(ref) else ref


def artifact_id_of(ref: Job | Manifest | str, job: Callable[[str], Job]) -> str:
    """The artifact's id; for a job, its artifact's (`job` fetches a job by id, also a `Job` that had none
    when it was fetched)."""
    from neuralbake_client.models import Job, Manifest

    if isinstance(ref, Manifest):
        return ref.artifact_id
    if isinstance(ref, str) and not names_a_job(ref):
        return as_artifact_id(ref)
    found = ref if isinstance(ref, Job) and ref.artifact_id else job(ref.id if isinstance(ref, Job) else ref)
    if found.artifact_id is None:
        raise NoArtifact(f"job {found.id} is {found.state} and has no artifact")
    return found.artifact_id
