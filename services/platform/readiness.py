"""Readiness as orchestrators read it: every dependency check passes (200) or each failure is named (503).
Shared by the job service and the inference service."""

from __future__ import annotations

from collections.abc import Callable

from fastapi.responses import JSONResponse

PROBE = "sha256:" + "0" * 64  # a digest no blob has: asking the store for it proves the store answers


def readiness(checks: dict[str, Callable[[], object]], **extra) -> JSONResponse:
    """Run every check; 200 when all pass, else 503 naming each failure and why."""
    results = {}
    for name, check in checks.items():
        try:
            check()
            results[name] = "ok"
        except Exception as error:  # any failure means not ready; say which and why
            results[name] = f"{type(error).__name__}: {error}"
    ready = all(value == "ok" for value in results.values())
    body = {"status": "ok" if ready else "unavailable", **extra, "checks": results}
    return JSONResponse(body, 200 if ready else 503)
