"""neuralbake-client: the Python SDK of the neuralbake job service and its inference service (REST or
gRPC).

from neuralbake_client import Client

with Client("http://127.0.0.1:8080", token) as client:
    job = client.submit("render", Path("scenes/chair"), preset="quick")
    job = client.wait(job, on_progress=lambda p: print(p.step, p.total))
    client.download(job, "out/chair")
    answer = client.query(job, {"pixels": [[0, 0], [5, 7]]})

Names are imported on first use (PEP 562), so `nbake --help` and the other commands of the command line
in `neuralbake_client.cli` start without loading httpx, gRPC, pydantic or NumPy they do not need.
"""

from __future__ import annotations

import importlib
from typing import Any

_MODULES = {
    "aio": ["AsyncClient"],
    "answers": ["QueryAnswer", "RenderedImage"],
    "client": ["Client"],
    "download": ["DownloadedFile"],
    "errors": [
        "ApiError",
        "ChecksumMismatch",
        "Conflict",
        "ConnectionFailed",
        "InvalidRequest",
        "NeuralbakeError",
        "NotFound",
        "PermissionDenied",
        "ServerError",
        "TooLarge",
        "TooManyRequests",
        "Unauthenticated",
        "Unavailable",
        "WaitTimeout",
    ],
    "models": [
        "Asset",
        "CreatedToken",
        "FileEntry",
        "Job",
        "JobEvent",
        "JobList",
        "JobState",
        "KindInfo",
        "Manifest",
        "ModelInfo",
        "PresetInfo",
        "Progress",
        "QuotaLimits",
        "QuotaUse",
        "SceneInfo",
        "TenantQuotas",
        "Token",
    ],
    "retry": ["Retry"],
    "transport_grpc": ["DeadlineExceeded"],
}
_HOME = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted(_HOME)


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
