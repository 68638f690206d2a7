"""The rows the job domain adds to the platform's problem table: its state machine, uploads, scenes, and
the assets and artifacts of the store. Both servers answer with this table (the inference service serves
the jobs' artifacts)."""

from __future__ import annotations

from services.artifacts.artifacts import ArtifactNotFound, FileNotFoundInArtifact
from services.artifacts.assets import AssetNotFound
from services.artifacts.staging import UploadError
from services.jobs.states import InvalidTransition
from services.platform.problem_table import PLATFORM_PROBLEMS, ProblemInfo, not_found
from workers.scene.format.errors import SceneError


def _upload(error: UploadError) -> ProblemInfo:
    title = "Upload too large" if error.status == 413 else "Unusable upload"
    return ProblemInfo(error.status, title, error.problem, error.field)


JOB_PROBLEMS = PLATFORM_PROBLEMS.including(
    {
        InvalidTransition: lambda e: ProblemInfo(409, "Conflict", str(e)),
        UploadError: _upload,
        SceneError: lambda e: ProblemInfo(422, "Invalid scene", e.problem, e.field),
        AssetNotFound: not_found,
        ArtifactNotFound: not_found,
        FileNotFoundInArtifact: not_found,
    }
)
