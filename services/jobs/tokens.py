"""The tokens stored in the job database, which the job server and the inference service share: sha256
hashes (the secret itself is never stored), each of one tenant. Configured tokens are replaced by the
configured set at every start (so removing a token revokes it); an admin creates tenants' tokens through
`POST /v1/tokens` (`nbake tokens create`), which last until revoked.

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
import re
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

from sqlalchemy import delete, select

from services.jobs.db import Database
from services.jobs.tables import DEFAULT_TENANT, ApiToken, utcnow
from services.jobs.tenants import checked_tenant
from services.platform.auth import SCOPES, Principal
from services.platform.errors import Conflict, InvalidInput, ServiceError

CONFIGURED, CREATED = "configured", "created"
SECRET_PREFIX = "nbk_"  # created tokens: easy to recognise in a leaked log or a secret scanner
TOKEN_CACHE_S = 1.0  # how long a process trusts a token it read: the bound on a revocation elsewhere
TOKEN_CACHE_SIZE = 4096  # tokens remembered per process (only valid ones: an unknown token is always read)
TOKEN_ID = re.compile(r"tok-[0-9a-f]{16}")


class TokenNotFound(ServiceError):
    status, title = 404, "Token not found"


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


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


class DatabaseTokens:
    """The job database's tokens as one server instance sees them (a `services.platform.auth.TokenStore`):
    build one per instance and hand the same object to its REST app and its gRPC server, so that a
    revocation through either is seen by both at once."""

    def __init__(self, db: Database):
        self.db = db
        self.cache = TokenCache()

    def cached(self, token: str) -> Principal | None:
        return self.cache.get(token_hash(token))

    def principal(self, token: str) -> Principal | None:
        digest = token_hash(token)
        if (principal := self.cache.get(digest)) is not None:
            return principal
        generation = self.cache.generation
        with self.db.reading() as session:
            stored = session.get(ApiToken, digest)
        if stored is None:
            return None
        principal = Principal(stored.tenant, stored.scope)
        self.cache.put(digest, principal, generation)
        return principal

    def check(self) -> None:
        """Readiness: the token table can be read (`nbake serve` has created it)."""
        with self.db.reading() as session:
            session.execute(select(ApiToken.scope).limit(1))

    def store_configured(self, tokens: dict[str, str]) -> None:
        """Replace the stored configured tokens with `tokens` (of the default tenant), hashed; created tokens
        stay. Replicas starting together take turns (otherwise both delete, both insert, and one fails)."""
        with self.db.writing_alone() as session:
            session.execute(delete(ApiToken).where(ApiToken.source == CONFIGURED))
            hashes = {token_hash(t): scope for t, scope in tokens.items()}
            taken = set(session.scalars(select(ApiToken.token_hash).where(ApiToken.token_hash.in_(hashes))))
            session.add_all(
                ApiToken(
                    token_hash=h,
                    id=_token_id(),
                    tenant=DEFAULT_TENANT,
                    scope=scope,
                    name="",
                    source=CONFIGURED,
                )
                for h, scope in hashes.items()
                if h not in taken
            )
        self.cache.drop()  # a configured token left out of `tokens` is revoked

    def create(self, tenant: str, scope: str, name: str = "") -> tuple[ApiToken, str]:
        """A new token of `tenant` with `scope`: (its stored row, its secret). The secret is returned once
        and only its hash is kept."""
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
        with self.db.writing() as session:
            session.add(row)
        return row, secret

    def listing(self) -> list[ApiToken]:
        """Every stored token (configured and created), oldest first."""
        with self.db.reading() as session:
            return list(session.scalars(select(ApiToken).order_by(ApiToken.created_at, ApiToken.id)))

    def revoke(self, token_id: str) -> ApiToken:
        """Delete a created token; the next request with it gets 401. Configured tokens are revoked by
        removing them from the configuration (they would come back at the next start)."""
        if TOKEN_ID.fullmatch(token_id) is None:
            raise TokenNotFound(f"no token {token_id!r}", "token_id")
        with self.db.writing() as session:
            row = session.scalars(select(ApiToken).where(ApiToken.id == token_id)).one_or_none()
            if row is None:
                raise TokenNotFound(f"no token {token_id!r}", "token_id")
            if row.source != CREATED:
                raise Conflict(
                    f"{token_id} is configured: remove it from NBAKE_TOKENS and restart", "token_id"
                )
            session.delete(row)
        self.cache.drop(row.token_hash)
        return row
