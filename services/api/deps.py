"""Small dependencies every route module shares."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from services.api.services import Services
from services.artifacts.digests import parse_digest


def _services(request: Request) -> Services:
    return request.app.state.services


ServicesDep = Annotated[Services, Depends(_services)]


def known_digest(value: str, not_found: type[LookupError]) -> str:
    """An id that is not even a digest names nothing: `not_found` (a 404) like any unknown id."""
    try:
        parse_digest(value)
    except ValueError:
        raise not_found(value) from None
    return value
