"""The security headers every response of the job API and the inference service carries (JSON, problem
documents, file downloads, `/docs`), set in one ASGI middleware so that no route can forget them.

A response that sets a header itself keeps its own value: the dashboard's Content-Security-Policy allows
its own scripts and styles. Everything else is data, which a browser must neither sniff into HTML nor let
another site frame, and whose address leaks nothing through Referer. The interactive docs load Swagger UI
from its CDN with an inline script, so their policy only forbids framing, `<base>` and form targets.
"""

from __future__ import annotations

from fastapi import FastAPI
from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

DATA_POLICY = "default-src 'none'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'"
DOCS_POLICY = "frame-ancestors 'none'; base-uri 'none'; form-action 'none'"
BASELINE = {"X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer"}


class SecurityHeaders:
    """ASGI middleware: the baseline headers, and the data policy except on `docs_paths`."""

    def __init__(self, app: ASGIApp, docs_paths: tuple[str, ...]):
        self.app, self.docs_paths = app, docs_paths

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        policy = DOCS_POLICY if scope["path"] in self.docs_paths else DATA_POLICY
        wanted = BASELINE | {"Content-Security-Policy": policy}

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in wanted.items():
                    headers.setdefault(name, value)
            await send(message)

        await self.app(scope, receive, with_headers)


def install(app: FastAPI) -> None:
    """Add the middleware to a FastAPI `app`, outermost, so that even its error responses carry them."""
    docs = (app.docs_url, app.redoc_url, app.swagger_ui_oauth2_redirect_url)
    app.add_middleware(SecurityHeaders, docs_paths=tuple(path for path in docs if path))
