"""Between the service's models and the protocol's messages. Jobs go through the REST `JobView`, so both
APIs show a job the same way; JSON-shaped fields (config, plan, progress, inline scenes) are Structs.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from google.protobuf import struct_pb2, timestamp_pb2
from neuralbake.v1 import artifacts_pb2, assets_pb2, files_pb2, jobs_pb2

from services.api.schemas import JobView
from services.artifacts.assets import Asset
from services.artifacts.manifest import FileEntry, Manifest
from services.jobs.states import JobState
from services.jobs.tables import Event, Job
from services.platform.grpc.structs import json_values

STATES = {state: jobs_pb2.JobState.Value(f"JOB_STATE_{state.value}") for state in JobState}
STATE_NAMES = {number: state for state, number in STATES.items()}


def struct(data: dict[str, Any] | None) -> struct_pb2.Struct | None:
    if data is None:
        return None
    message = struct_pb2.Struct()
    message.update(data)
    return message


def plain(message: struct_pb2.Struct, field: str) -> dict[str, Any]:
    """The Struct `field` as JSON values. A Struct holds every number as a double, so whole numbers come
    back as ints, as a JSON body gives them: counts validate strictly (`spp: 64.0` would not) and both
    APIs agree."""
    return _whole_numbers_as_ints(json_values(message, field))


def _whole_numbers_as_ints(value: Any) -> Any:
    if isinstance(value, float) and value.is_integer() and abs(value) <= 2**53:
        return int(value)
    if isinstance(value, dict):
        return {key: _whole_numbers_as_ints(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_whole_numbers_as_ints(item) for item in value]
    return value


def timestamp(value: datetime | None) -> timestamp_pb2.Timestamp | None:
    if value is None:
        return None
    message = timestamp_pb2.Timestamp()
    message.FromDatetime(value)
    return message


def job_message(job: Job) -> jobs_pb2.Job:
    view = JobView.of(job)
    scalars = view.model_dump(
        mode="json",
        exclude={"state", "config", "plan", "progress", "links", "created_at", "started_at", "finished_at"},
        exclude_none=True,
    )
    return jobs_pb2.Job(
        **scalars,
        state=STATES[view.state],
        config=struct(view.config),
        plan=struct(view.plan),
        progress=struct(view.progress),
        created_at=timestamp(view.created_at),
        started_at=timestamp(view.started_at),
        finished_at=timestamp(view.finished_at),
    )


def event_message(event: Event) -> jobs_pb2.JobEvent:
    return jobs_pb2.JobEvent(
        job_id=event.job_id,
        seq=event.seq,
        type=event.type,
        time=timestamp(event.time),
        data=struct(event.data),
    )


def submit_fields(request: jobs_pb2.SubmitJobRequest) -> dict[str, Any]:
    """The `JobRequest` body a SubmitJobRequest stands for (unset optional fields take the defaults)."""
    fields: dict[str, Any] = {
        "kind": request.kind,
        "force": request.force,
        "config": plain(request.config, "config"),
    }
    source = request.WhichOneof("scene")
    if source == "scene_ref":
        fields["scene"] = request.scene_ref
    elif source == "scene_spec":
        fields["scene"] = plain(request.scene_spec, "scene")
    for name in ("preset", "seed", "priority"):
        if request.HasField(name):
            fields[name] = getattr(request, name)
    return fields


def file_message(entry: FileEntry) -> files_pb2.FileEntry:
    return files_pb2.FileEntry(**entry.model_dump(mode="json"))


def asset_message(asset: Asset) -> assets_pb2.Asset:
    return assets_pb2.Asset(
        asset_id=asset.asset_id,
        scene_file=asset.scene_file,
        scene_name=asset.scene_name,
        files=[file_message(entry) for entry in asset.files],
        created=timestamp(asset.created),
    )


def manifest_message(manifest: Manifest) -> artifacts_pb2.Manifest:
    return artifacts_pb2.Manifest(
        schema_version=manifest.schema_version,
        media_type=manifest.media_type,
        artifact_id=manifest.artifact_id,
        kind=manifest.kind,
        job_id=manifest.job_id,
        scene_hash=manifest.scene_hash,
        config=struct(manifest.config),
        code_version=manifest.code_version,
        metrics=manifest.metrics,
        created=timestamp(manifest.created),
        files=[file_message(entry) for entry in manifest.files],
        annotations=manifest.annotations,
    )
