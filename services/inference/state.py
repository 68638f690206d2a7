"""What the inference app's routes and the gRPC servicer share: the service and the job database (for
tokens, read by `services.api.auth`, which looks for `app.state.services.db`, and for which tenant sees
which artifact)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, Request

from services.inference.service import InferenceService
from services.jobs.db import Database
from services.jobs.tenants import Tenancy


@dataclass
class InferenceState:
    service: InferenceService
    db: Database
    tenancy: Tenancy = field(init=False)

    def __post_init__(self) -> None:
        self.tenancy = Tenancy(self.db)


def _state(request: Request) -> InferenceState:
    return request.app.state.services


StateDep = Annotated[InferenceState, Depends(_state)]
