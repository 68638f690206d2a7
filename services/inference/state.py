"""What the inference app's routes and the gRPC servicer share: the service and the job database (only
for tokens, read by `services.api.auth`, which looks for `app.state.services.db`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request

from services.inference.service import InferenceService
from services.jobs.db import Database


@dataclass
class InferenceState:
    service: InferenceService
    db: Database


def _state(request: Request) -> InferenceState:
    return request.app.state.services


StateDep = Annotated[InferenceState, Depends(_state)]
