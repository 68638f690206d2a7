"""What the inference app's routes and the gRPC servicer share: the service, the job database's tokens
(the job server's, so both accept the same ones) and which tenant sees which artifact."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, Request

from services.inference.service import InferenceService
from services.jobs.db import Database
from services.jobs.tenants import Tenancy
from services.jobs.tokens import DatabaseTokens


@dataclass
class InferenceState:
    service: InferenceService
    db: Database
    tokens: DatabaseTokens = field(init=False)
    tenancy: Tenancy = field(init=False)

    def __post_init__(self) -> None:
        self.tokens, self.tenancy = DatabaseTokens(self.db), Tenancy(self.db)


def _state(request: Request) -> InferenceState:
    return request.app.state.inference


StateDep = Annotated[InferenceState, Depends(_state)]
