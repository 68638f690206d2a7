"""Small dependencies every route module shares."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from services.api.services import Services


def _services(request: Request) -> Services:
    return request.app.state.services


ServicesDep = Annotated[Services, Depends(_services)]
