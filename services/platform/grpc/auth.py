"""Bearer tokens over gRPC: `authorization: Bearer <token>` metadata, checked by the same `authorize` as
REST requests. The health and reflection services stay open, like `/healthz`. A checked call's context
carries the caller's `Principal` (its tenant and scope) to the servicer: `principal(context)`.
"""

from __future__ import annotations

from collections.abc import Callable

import grpc

from services.platform.auth import Principal, TokenStore, authorize
from services.platform.grpc.handlers import Behaviour, rewrap

MISSING = "send `authorization: Bearer <token>` metadata"


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
    """Checks the caller's token against `tokens` before the call's behaviour runs (in the call's worker
    thread). `scope_for(method)` names the scope a full method name needs (None: open)."""

    def __init__(self, tokens: TokenStore, scope_for: Callable[[str], str | None]):
        self.tokens, self.scope_for = tokens, scope_for

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        scope = self.scope_for(handler_call_details.method)
        if handler is None or scope is None:
            return handler

        def around(behaviour: Behaviour, streaming: bool) -> Behaviour:
            def checked(request, context):
                caller = authorize(self.tokens, bearer_token(context), scope, MISSING)
                return behaviour(request, AuthorizedContext(context, caller))

            return checked

        return rewrap(handler, around)
