"""Bearer tokens with scopes read < submit < admin, each of one tenant, checked the same way by every server
over REST and gRPC (`services.platform.grpc.auth`).

A server keeps its tokens in a `TokenStore`, set on its app as `app.state.tokens`: the job server and the
inference service both use the job database's (`services.jobs.tokens`), so they share one set of tokens.
Configured tokens come from `NBAKE_TOKENS=token:scope,...` and/or a tokens file and belong to the default
tenant; with none configured, an admin token is generated into `<data_dir>/admin-token` (mode 0600) and
reused on later starts.
"""

from __future__ import annotations

import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Protocol

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.concurrency import run_in_threadpool

from services.platform.errors import ServiceError

SCOPES = ("read", "submit", "admin")  # each scope includes the ones before it
ADMIN_TOKEN_FILE = "admin-token"


class Unauthorized(ServiceError):
    status, title = 401, "Unauthorized"
    headers = {"WWW-Authenticate": "Bearer"}  # noqa: RUF012


class Forbidden(ServiceError):
    status, title = 403, "Forbidden"


@dataclass(frozen=True)
class Principal:
    """Who a request acts for: its token's tenant and scope (read < submit < admin)."""

    tenant: str
    scope: str

    @property
    def sees_all(self) -> bool:
        """An admin token of the deployment sees every tenant's jobs, assets and artifacts."""
        return self.scope == "admin"

    @property
    def visible_tenant(self) -> str | None:
        """The tenant whose things this caller may see; None: every tenant's."""
        return None if self.sees_all else self.tenant


class TokenStore(Protocol):
    """Who each token stands for. `cached` answers without blocking (None: not known without a read);
    `principal` may read storage (None: no such token)."""

    def cached(self, token: str) -> Principal | None: ...

    def principal(self, token: str) -> Principal | None: ...


def parse_tokens(text: str, source: str) -> dict[str, str]:
    """`token:scope` items separated by commas or newlines -> {token: scope}; ValueError naming the item."""
    tokens = {}
    for raw in text.replace(",", "\n").splitlines():
        item = raw.split("#", 1)[0].strip()
        if not item:
            continue
        token, _, scope = item.rpartition(":")
        if not token or scope not in SCOPES:
            raise ValueError(
                f"{source}: {item[:4]}...: expected token:scope with scope one of {', '.join(SCOPES)}"
            )
        tokens[token] = scope
    return tokens


def configured_tokens(tokens: str | None, tokens_file: Path | None) -> dict[str, str]:
    found = parse_tokens(tokens, "NBAKE_TOKENS") if tokens else {}
    if tokens_file is not None:
        found |= parse_tokens(Path(tokens_file).read_text(), str(tokens_file))
    return found


def generated_admin_token(data_dir: Path) -> tuple[str, Path]:
    """The admin token of this data dir, created (mode 0600) the first time."""
    path = data_dir / ADMIN_TOKEN_FILE
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return path.read_text().strip(), path
    token = secrets.token_urlsafe(32)
    with os.fdopen(fd, "w") as out:
        out.write(token + "\n")
    return token, path


def authorize(tokens: TokenStore, token: str | None, scope: str, missing: str) -> Principal:
    """Who the token acts for if it holds `scope` (or a wider one); Unauthorized / Forbidden otherwise. Both
    APIs check tokens here so they agree on every answer; `missing` tells how that API expects the token."""
    if token is None:
        raise Unauthorized(missing)
    principal = tokens.principal(token)
    if principal is None:
        raise Unauthorized("unknown token")  # never issued, or revoked
    return in_scope(principal, scope)


def in_scope(principal: Principal, scope: str) -> Principal:
    if SCOPES.index(principal.scope) < SCOPES.index(scope):
        raise Forbidden(f"this token has scope {principal.scope!r}; this needs {scope!r}")
    return principal


_bearer = HTTPBearer(
    auto_error=False,
    description="A token from NBAKE_TOKENS, the generated admin-token file or `nbake tokens create`.",
)


def require(scope: str):
    """A dependency that lets a request through only with a token holding `scope` (or a wider one), checked
    against the app's `app.state.tokens`. A cached token is checked on the event loop; only a read of the
    store takes a thread."""

    async def check(
        request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
    ) -> Principal:
        token = None if credentials is None else credentials.credentials
        tokens: TokenStore = request.app.state.tokens
        if token is not None and (cached := tokens.cached(token)) is not None:
            return in_scope(cached, scope)
        return await run_in_threadpool(
            authorize, tokens, token, scope, "send `Authorization: Bearer <token>`"
        )

    return check


CanRead = Annotated[Principal, Depends(require("read"))]
CanSubmit = Annotated[Principal, Depends(require("submit"))]
IsAdmin = Annotated[Principal, Depends(require("admin"))]
