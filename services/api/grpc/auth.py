"""Bearer tokens over gRPC: `authorization: Bearer <token>` metadata, checked by the same `authorize` as
REST requests. The health and reflection services stay open, like `/healthz`. A checked call's context
carries the caller's `Principal` (its tenant and scope) to the servicer: `principal(context)`.
"""

from __future__ import annotations

from collections.abc import Callable

import grpc
from neuralbake.v1 import artifacts_pb2, assets_pb2, jobs_pb2

from services.api.auth import authorize
from services.api.grpc.handlers import Behaviour, rewrap
from services.jobs.db import Database
from services.jobs.tenants import Principal

PROTECTED = {
    service.full_name: service
    for module in (jobs_pb2, assets_pb2, artifacts_pb2)
    for service in module.DESCRIPTOR.services_by_name.values()
}
MISSING = "send `authorization: Bearer <token>` metadata"
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


class AuthorizedContext:
    """The call's context (every method delegated) with the principal its token stands for: gRPC's own
    context takes no attributes."""

    def __init__(self, context: grpc.ServicerContext, principal: Principal):
        self._context, self.principal = context, principal

    def __getattr__(self, name: str):
        return getattr(self._context, name)


def principal(context) -> Principal:
    """Who a call checked by `TokenAuth` acts for."""
    return context.principal


class TokenAuth(grpc.ServerInterceptor):
    """Checks the caller's token before the call's behaviour runs (in the call's worker thread).
    `scope_for(method)` names the scope a method needs (None: open); the inference server passes its own."""

    def __init__(self, db: Database, scope_for: Callable[[str], str | None] = needed_scope):
        self.db, self.scope_for = db, scope_for

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        scope = self.scope_for(handler_call_details.method)
        if handler is None or scope is None:
            return handler

        def around(behaviour: Behaviour, streaming: bool) -> Behaviour:
            def checked(request, context):
                caller = authorize(self.db, bearer_token(context), scope, MISSING)
                return behaviour(request, AuthorizedContext(context, caller))

            return checked

        return rewrap(handler, around)
