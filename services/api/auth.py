"""Bearer tokens with scopes read < submit < admin, stored as sha256 hashes in the job database.

Tokens come from `NBAKE_TOKENS=token:scope,...` and/or a tokens file; the configured set replaces the
stored one at every start (so removing a token revokes it). With none configured, an admin token is
generated into `<data_dir>/admin-token` (mode 0600) and reused on later starts.
"""

from __future__ import annotations

import hashlib
import os
import secrets
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy import delete

from services.jobs.db import Database
from services.jobs.errors import JobServiceError
from services.jobs.tables import ApiToken

SCOPES = ("read", "submit", "admin")  # each scope includes the ones before it
ADMIN_TOKEN_FILE = "admin-token"


class Unauthorized(JobServiceError):
    status, title = 401, "Unauthorized"
    headers = {"WWW-Authenticate": "Bearer"}  # noqa: RUF012


class Forbidden(JobServiceError):
    status, title = 403, "Forbidden"


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


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


def store_tokens(db: Database, tokens: dict[str, str]) -> None:
    """Replace the stored tokens with `tokens`, hashed."""
    with db.writing() as session:
        session.execute(delete(ApiToken))
        session.add_all(ApiToken(token_hash=token_hash(t), scope=scope) for t, scope in tokens.items())


def authorize(db: Database, token: str | None, scope: str, missing: str) -> str:
    """The token's scope if it holds `scope` (or a wider one); Unauthorized / Forbidden otherwise. Both APIs
    check tokens here so they agree on every answer; `missing` tells how that API expects the token."""
    if token is None:
        raise Unauthorized(missing)
    with db.reading() as session:
        stored = session.get(ApiToken, token_hash(token))
    if stored is None:
        raise Unauthorized("unknown token")
    if SCOPES.index(stored.scope) < SCOPES.index(scope):
        raise Forbidden(f"this token has scope {stored.scope!r}; this needs {scope!r}")
    return stored.scope


_bearer = HTTPBearer(
    auto_error=False, description="A token from NBAKE_TOKENS or the generated admin-token file."
)


def require(scope: str):
    """A dependency that lets a request through only with a token holding `scope` (or a wider one)."""

    def check(
        request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
    ) -> str:
        token = None if credentials is None else credentials.credentials
        db: Database = request.app.state.services.db
        return authorize(db, token, scope, "send `Authorization: Bearer <token>`")

    return check
