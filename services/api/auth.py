"""Bearer tokens with scopes read < submit < admin, each of one tenant, stored as sha256 hashes in the job
database (the secret itself is never stored).

Configured tokens come from `NBAKE_TOKENS=token:scope,...` and/or a tokens file and belong to the default
tenant; the configured set replaces the stored configured ones at every start (so removing a token revokes
it). With none configured, an admin token is generated into `<data_dir>/admin-token` (mode 0600) and reused
on later starts. An admin creates tenants' tokens through `POST /v1/tokens` (`nbake tokens create`); they
last until revoked.

A token read from the database is trusted for `TOKEN_CACHE_S` (1 s) by the process that read it, so a burst
of requests costs one database read per token and second, not one each (it was a third of a repeated
submission's round trips). A revoked token is refused from the next request on by the process that revoked
it (it drops its own cached entry), and within `TOKEN_CACHE_S` by every other one: API replicas, the gRPC
server, the inference service. Why a time bound and not an exact check: an exact answer on every replica
needs a database read on every request (what the cache removes), and a push (PostgreSQL LISTEN/NOTIFY)
needs the same bound anyway for the notifications a dropped listener connection misses; a second is well
under the time it takes to notice a leak and run `nbake tokens revoke`.
"""

from __future__ import annotations

import hashlib
import os
import re
import secrets
import threading
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy import delete, select
from starlette.concurrency import run_in_threadpool

from services.jobs.db import Database
from services.jobs.errors import Conflict, InvalidInput, JobServiceError
from services.jobs.tables import ApiToken, utcnow
from services.jobs.tenants import DEFAULT_TENANT, Principal, checked_tenant

SCOPES = ("read", "submit", "admin")  # each scope includes the ones before it
ADMIN_TOKEN_FILE = "admin-token"
CONFIGURED, CREATED = "configured", "created"
SECRET_PREFIX = "nbk_"  # created tokens: easy to recognise in a leaked log or a secret scanner
TOKEN_CACHE_S = 1.0  # how long a process trusts a token it read: the bound on a revocation elsewhere
TOKEN_CACHE_SIZE = 4096  # tokens remembered per process (only valid ones: an unknown token is always read)


class Unauthorized(JobServiceError):
    status, title = 401, "Unauthorized"
    headers = {"WWW-Authenticate": "Bearer"}  # noqa: RUF012


class Forbidden(JobServiceError):
    status, title = 403, "Forbidden"


class TokenNotFound(JobServiceError):
    status, title = 404, "Token not found"


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


TOKEN_ID = re.compile(r"tok-[0-9a-f]{16}")


def _token_id() -> str:
    return f"tok-{secrets.token_hex(8)}"


class TokenCache:
    """token hash -> the Principal it was read as, each trusted for `ttl_s` after the read. `generation`
    counts the drops: a read that began before one is not cached (it may predate the revocation)."""

    def __init__(self, ttl_s: float = TOKEN_CACHE_S, clock: Callable[[], float] = time.monotonic):
        self.ttl_s, self.clock = ttl_s, clock
        self.generation = 0
        self._entries: OrderedDict[str, tuple[Principal, float]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, digest: str) -> Principal | None:
        with self._lock:
            found = self._entries.get(digest)
            if found is None:
                return None
            if self.clock() >= found[1]:
                del self._entries[digest]
                return None
            self._entries.move_to_end(digest)
            return found[0]

    def put(self, digest: str, principal: Principal, generation: int) -> None:
        """Remember what a read begun at `generation` found."""
        with self._lock:
            if generation != self.generation:
                return
            self._entries[digest] = (principal, self.clock() + self.ttl_s)
            self._entries.move_to_end(digest)
            while len(self._entries) > TOKEN_CACHE_SIZE:
                self._entries.popitem(last=False)

    def drop(self, digest: str | None = None) -> None:
        """Forget one token (its revocation here), or all of them (the configured set replaced)."""
        with self._lock:
            self.generation += 1
            if digest is None:
                self._entries.clear()
            else:
                self._entries.pop(digest, None)


_caches: weakref.WeakKeyDictionary[Database, TokenCache] = weakref.WeakKeyDictionary()
_caches_lock = threading.Lock()


def token_cache(db: Database) -> TokenCache:
    """The tokens this process read from `db` (one cache per Database object: per server instance)."""
    with _caches_lock:
        if (cache := _caches.get(db)) is None:
            cache = _caches[db] = TokenCache()
        return cache


def store_tokens(db: Database, tokens: dict[str, str]) -> None:
    """Replace the stored configured tokens with `tokens` (of the default tenant), hashed; created tokens
    stay. Replicas starting together take turns (otherwise both delete, both insert, and one fails)."""
    with db.writing_alone() as session:
        session.execute(delete(ApiToken).where(ApiToken.source == CONFIGURED))
        hashes = {token_hash(t): scope for t, scope in tokens.items()}
        taken = set(session.scalars(select(ApiToken.token_hash).where(ApiToken.token_hash.in_(hashes))))
        session.add_all(
            ApiToken(
                token_hash=h, id=_token_id(), tenant=DEFAULT_TENANT, scope=scope, name="", source=CONFIGURED
            )
            for h, scope in hashes.items()
            if h not in taken
        )
    token_cache(db).drop()  # a configured token left out of `tokens` is revoked


def create_token(db: Database, tenant: str, scope: str, name: str = "") -> tuple[ApiToken, str]:
    """A new token of `tenant` with `scope`: (its stored row, its secret). The secret is returned once and
    only its hash is kept."""
    if scope not in SCOPES:
        raise InvalidInput(f"one of {', '.join(SCOPES)}", "scope")
    secret = SECRET_PREFIX + secrets.token_urlsafe(32)
    row = ApiToken(
        token_hash=token_hash(secret),
        id=_token_id(),
        tenant=checked_tenant(tenant),
        scope=scope,
        name=name,
        source=CREATED,
        created_at=utcnow(),
    )
    with db.writing() as session:
        session.add(row)
    return row, secret


def list_tokens(db: Database) -> list[ApiToken]:
    """Every stored token (configured and created), oldest first."""
    with db.reading() as session:
        return list(session.scalars(select(ApiToken).order_by(ApiToken.created_at, ApiToken.id)))


def revoke_token(db: Database, token_id: str) -> ApiToken:
    """Delete a created token; the next request with it gets 401. Configured tokens are revoked by removing
    them from the configuration (they would come back at the next start)."""
    if TOKEN_ID.fullmatch(token_id) is None:
        raise TokenNotFound(f"no token {token_id!r}", "token_id")
    with db.writing() as session:
        row = session.scalars(select(ApiToken).where(ApiToken.id == token_id)).one_or_none()
        if row is None:
            raise TokenNotFound(f"no token {token_id!r}", "token_id")
        if row.source != CREATED:
            raise Conflict(f"{token_id} is configured: remove it from NBAKE_TOKENS and restart", "token_id")
        session.delete(row)
    token_cache(db).drop(row.token_hash)
    return row


def authorize(db: Database, token: str | None, scope: str, missing: str) -> Principal:
    """Who the token acts for if it holds `scope` (or a wider one); Unauthorized / Forbidden otherwise. Both
    APIs check tokens here so they agree on every answer; `missing` tells how that API expects the token."""
    if token is None:
        raise Unauthorized(missing)
    cache, digest = token_cache(db), token_hash(token)
    if (principal := cache.get(digest)) is None:
        generation = cache.generation
        with db.reading() as session:
            stored = session.get(ApiToken, digest)
        if stored is None:
            raise Unauthorized("unknown token")  # never issued, or revoked
        principal = Principal(stored.tenant, stored.scope)
        cache.put(digest, principal, generation)
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
    """A dependency that lets a request through only with a token holding `scope` (or a wider one). A token
    read in the last `TOKEN_CACHE_S` is checked on the event loop; only a database read takes a thread."""

    async def check(
        request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
    ) -> Principal:
        token = None if credentials is None else credentials.credentials
        db: Database = request.app.state.services.db
        if token is not None and (cached := token_cache(db).get(token_hash(token))) is not None:
            return in_scope(cached, scope)
        return await run_in_threadpool(authorize, db, token, scope, "send `Authorization: Bearer <token>`")

    return check


CanRead = Annotated[Principal, Depends(require("read"))]
CanSubmit = Annotated[Principal, Depends(require("submit"))]
IsAdmin = Annotated[Principal, Depends(require("admin"))]
