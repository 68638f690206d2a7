"""Small dependencies every route module shares."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from services.api.services import Services


async def _services(request: Request) -> Services:  # async: a plain def would cost a thread hop
    return request.app.state.services


ServicesDep = Annotated[Services, Depends(_services)]
