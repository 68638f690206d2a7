"""`/v1/tokens` (admin): create a tenant's token (its secret is shown once, only its hash is stored), list
tokens without their secrets, revoke one (refused from the next request on)."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from fastapi import APIRouter, Response
from pydantic import BaseModel, ConfigDict, Field

from services.api.deps import ServicesDep
from services.jobs.tables import ApiToken
from services.jobs.tenants import DEFAULT_TENANT
from services.platform.auth import IsAdmin
from services.platform.problems import PROBLEM_RESPONSES

router = APIRouter(
    prefix="/v1/tokens", tags=["tokens"], responses={s: PROBLEM_RESPONSES[s] for s in (401, 403)}
)


class TokenRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    tenant: str = Field(
        DEFAULT_TENANT,
        min_length=1,
        max_length=64,
        pattern=r"^[a-z0-9][a-z0-9_-]*$",
        description="Whose jobs, assets and artifacts the token sees and makes.",
    )
    scope: Literal["read", "submit", "admin"] = Field(
        "read", description="`admin` tokens see every tenant and manage tokens."
    )
    name: str = Field(
        "", max_length=128, pattern=r"^[^\x00-\x1f\x7f]*$", description="Who or what holds the token."
    )


class TokenView(BaseModel):
    id: str = Field(description="Names the token in listings and revocations; not a secret.")
    tenant: str
    scope: str
    name: str
    source: str = Field(description="`configured` (NBAKE_TOKENS) or `created` (this API).")
    created_at: datetime

    @classmethod
    def of(cls, row: ApiToken) -> TokenView:
        return cls(**{name: getattr(row, name) for name in cls.model_fields})


class CreatedToken(TokenView):
    token: str = Field(description="The secret: shown only in this answer, never stored.")


class TokenList(BaseModel):
    items: list[TokenView]


@router.post("", status_code=201, response_model=CreatedToken, responses={422: PROBLEM_RESPONSES[422]})
def create(body: TokenRequest, svc: ServicesDep, _: IsAdmin) -> CreatedToken:
    """A new token of a tenant; keep its `token` now, it cannot be shown again."""
    row, secret = svc.tokens.create(body.tenant, body.scope, body.name)
    return CreatedToken(**TokenView.of(row).model_dump(), token=secret)


@router.get("", response_model=TokenList)
def list_all(svc: ServicesDep, _: IsAdmin) -> TokenList:
    """Every token, configured and created, oldest first, without secrets."""
    return TokenList(items=[TokenView.of(row) for row in svc.tokens.listing()])


@router.delete(
    "/{token_id}",
    status_code=204,
    response_class=Response,
    responses={s: PROBLEM_RESPONSES[s] for s in (404, 409)},
)
def revoke(token_id: str, svc: ServicesDep, _: IsAdmin) -> Response:
    """Revoke a created token: the next request with it gets 401. Configured tokens are removed from the
    configuration instead (409)."""
    svc.tokens.revoke(token_id)
    return Response(status_code=204)
