"""`services.platform.auth` checks bearer tokens against whatever `TokenStore` an app sets as
`app.state.tokens` (both servers set the job database's): it needs nothing else of the app's state."""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.testclient import TestClient

from services.platform import problems
from services.platform.auth import CanRead, CanSubmit, Principal
from services.platform.problem_table import PLATFORM_PROBLEMS

ACME_READER = Principal("acme", "read")


class KnownTokens:
    """A `TokenStore` of fixed tokens, counting the reads that `cached` could not answer."""

    def __init__(self, tokens: dict[str, Principal], cached: bool):
        self.tokens, self.answers_cached, self.reads = tokens, cached, 0

    def cached(self, token: str) -> Principal | None:
        return self.tokens.get(token) if self.answers_cached else None

    def principal(self, token: str) -> Principal | None:
        self.reads += 1
        return self.tokens.get(token)


def client_with(tokens: KnownTokens) -> TestClient:
    app = FastAPI()
    app.state.tokens = tokens
    problems.install(app, PLATFORM_PROBLEMS)

    @app.get("/read")
    def read(principal: CanRead) -> dict[str, str]:
        return {"tenant": principal.tenant}

    @app.post("/submit")
    def submit(principal: CanSubmit) -> dict[str, str]:
        return {"tenant": principal.tenant}

    return TestClient(app)


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def test_a_token_is_checked_against_the_apps_token_store():
    tokens = KnownTokens({"reader": ACME_READER}, cached=False)
    client = client_with(tokens)
    assert client.get("/read", headers=bearer("reader")).json() == {"tenant": "acme"}
    missing = client.get("/read")
    assert (missing.status_code, missing.headers["www-authenticate"]) == (401, "Bearer")
    assert "Authorization: Bearer" in missing.json()["detail"]
    unknown = client.get("/read", headers=bearer("stranger"))
    assert (unknown.status_code, unknown.json()["detail"]) == (401, "unknown token")
    wider = client.post("/submit", headers=bearer("reader"))
    assert wider.status_code == 403
    assert wider.headers["content-type"] == problems.PROBLEM_JSON
    assert tokens.reads == 3  # nothing was cached: each known or unknown token was read


def test_a_cached_token_is_checked_without_a_read():
    tokens = KnownTokens({"reader": ACME_READER}, cached=True)
    client = client_with(tokens)
    assert client.get("/read", headers=bearer("reader")).status_code == 200
    assert client.post("/submit", headers=bearer("reader")).status_code == 403  # scope of the cached answer
    assert tokens.reads == 0
