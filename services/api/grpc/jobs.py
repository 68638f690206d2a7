"""`neuralbake.v1.JobService`: a thin adapter over `Services` (submit, cancel) and the job repository."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import grpc
from neuralbake.v1 import jobs_pb2, jobs_pb2_grpc

from services.api.grpc.messages import STATE_NAMES, event_message, job_message, submit_fields
from services.api.grpc.streams import StreamTracker, pause
from services.jobs.following import follow
from services.jobs.submission import BatchRequest, JobRequest
from services.platform.errors import InvalidInput
from services.platform.grpc.auth import principal

if TYPE_CHECKING:  # annotations only: the inference service reuses this package
    from services.api.services import Services

DEFAULT_PAGE, MAX_PAGE = 50, 200


def idempotency_key(context: grpc.ServicerContext) -> str | None:
    return next((value for key, value in context.invocation_metadata() if key == "idempotency-key"), None)


class JobServicer(jobs_pb2_grpc.JobServiceServicer):
    def __init__(self, services: Services, streams: StreamTracker):
        self.svc, self.streams = services, streams

    def SubmitJob(self, request, context):
        body = JobRequest.model_validate(submit_fields(request))
        job, created = self.svc.submit(body, idempotency_key(context), principal(context))
        return jobs_pb2.SubmitJobResponse(job=job_message(job), created=created)

    def SubmitJobs(self, request, context):
        batch = BatchRequest.model_validate({"jobs": [submit_fields(job) for job in request.jobs]})
        answers = self.svc.submit_many(batch.jobs, idempotency_key(context), principal(context))
        items = [
            jobs_pb2.SubmitJobResponse(job=job_message(job), created=created) for job, created in answers
        ]
        return jobs_pb2.SubmitJobsResponse(items=items)

    def GetJob(self, request, context):
        job = self.svc.jobs.get(request.job_id, principal(context).visible_tenant)
        return jobs_pb2.GetJobResponse(job=job_message(job))

    def ListJobs(self, request, context):
        size = request.page_size or DEFAULT_PAGE
        if not 1 <= size <= MAX_PAGE:
            raise InvalidInput(f"must be 1 to {MAX_PAGE}", "page_size")
        unknown = [s for s in request.states if s not in STATE_NAMES]
        if unknown:
            raise InvalidInput(f"unknown or unspecified state {unknown[0]}", "states")
        states = [STATE_NAMES[s].value for s in request.states]
        tenant, cursor = principal(context).visible_tenant, request.page_token or None
        jobs, cursor = self.svc.jobs.list(states, request.kind or None, cursor, size, tenant)
        return jobs_pb2.ListJobsResponse(jobs=[job_message(j) for j in jobs], next_page_token=cursor or "")

    def CancelJob(self, request, context):
        job = self.svc.cancel(request.job_id, principal(context))
        return jobs_pb2.CancelJobResponse(job=job_message(job))

    def WatchJob(self, request, context) -> Iterator[jobs_pb2.WatchJobResponse]:
        """Events in order until the final state, by the loop `services.jobs.following` shares with SSE."""
        self.svc.jobs.get(request.job_id, principal(context).visible_tenant)  # NOT_FOUND before any is sent
        with self.streams.track("WatchJob"):
            for events in follow(self.svc.jobs, request.job_id, request.after_seq):
                for event in events:
                    yield jobs_pb2.WatchJobResponse(event=event_message(event))
                if not events and not pause(context):
                    return
