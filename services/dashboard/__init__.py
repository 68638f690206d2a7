"""The web dashboard: static files (HTML, ES modules, CSS; no build step, nothing fetched from elsewhere)
that `nbake serve` serves at `/ui` and that talk to the REST API with the token the user gives.

Every response carries a Content-Security-Policy that allows only this origin's scripts and styles, so
even a job field that escaped the dashboard's text-only rendering could not run a script (the app's
`services.platform.headers` middleware adds the headers every response carries)."""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from starlette.responses import Response
from starlette.staticfiles import StaticFiles
from starlette.types import Scope

STATIC_DIR = Path(__file__).with_name("static")
PREFIX = "/ui"
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self'; "
    "img-src 'self' blob:; connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
    "Cache-Control": "no-cache",  # revalidate (ETag) so an upgraded server's files are used at once
}


class DashboardFiles(StaticFiles):
    async def get_response(self, path: str, scope: Scope) -> Response:
        response = await super().get_response(path, scope)
        response.headers.update(SECURITY_HEADERS)
        return response


def mount_dashboard(app: FastAPI) -> None:
    """Serve the dashboard at `/ui/` (`/ui` redirects there); it is no part of the OpenAPI document."""
    app.mount(PREFIX, DashboardFiles(directory=STATIC_DIR, html=True), name="dashboard")
