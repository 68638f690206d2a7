"""Bearer tokens over gRPC: `authorization: Bearer <token>` metadata, checked against the same stored
tokens and scopes as the REST API. The health and reflection services stay open, like `/healthz`.
"""

from __future__ import annotations

import grpc
from neuralbake.v1 import artifacts_pb2, assets_pb2, jobs_pb2

from services.api.auth import SCOPES, Forbidden, Unauthorized, token_hash
from services.api.grpc.handlers import Behaviour, rewrap
from services.jobs.db import Database
from services.jobs.tables import ApiToken

PROTECTED = {
    service.full_name: service
    for module in (jobs_pb2, assets_pb2, artifacts_pb2)
    for service in module.DESCRIPTOR.services_by_name.values()
}
SUBMIT_METHODS = frozenset(
    {
        "/neuralbake.v1.JobService/SubmitJob",
        "/neuralbake.v1.JobService/CancelJob",
        "/neuralbake.v1.AssetService/UploadAsset",
    }
)


def needed_scope(method: str) -> str | None:
    """The scope a full method name needs; None for the open (health, reflection) services."""
    service = method.strip("/").split("/", 1)[0]
    if service not in PROTECTED:
        return None
    return "submit" if method in SUBMIT_METHODS else "read"


def bearer_token(context: grpc.ServicerContext) -> str | None:
    for key, value in context.invocation_metadata():
        if key == "authorization":
            scheme, _, token = value.partition(" ")
            return token.strip() if scheme.lower() == "bearer" and token.strip() else None
    return None


def authorize(db: Database, token: str | None, scope: str) -> str:
    """The token's scope if it holds `scope` (or a wider one); Unauthorized / Forbidden otherwise."""
    if token is None:
        raise Unauthorized("send `authorization: Bearer <token>` metadata")
    with db.reading() as session:
        stored = session.get(ApiToken, token_hash(token))
    if stored is None:
        raise Unauthorized("unknown token")
    if SCOPES.index(stored.scope) < SCOPES.index(scope):
        raise Forbidden(f"this token has scope {stored.scope!r}; this needs {scope!r}")
    return stored.scope


class TokenAuth(grpc.ServerInterceptor):
    """Checks the caller's token before the call's behaviour runs (in the call's worker thread)."""

    def __init__(self, db: Database):
        self.db = db

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        scope = needed_scope(handler_call_details.method)
        if handler is None or scope is None:
            return handler

        def around(behaviour: Behaviour, streaming: bool) -> Behaviour:
            def checked(request, context):
                authorize(self.db, bearer_token(context), scope)
                return behaviour(request, context)

            return checked

        return rewrap(handler, around)
