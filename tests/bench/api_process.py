"""One API-only job server process (no scheduler) for the load benchmarks: several of these share one
database and one store, as replicas behind a load balancer would.

    python -m tests.bench.api_process PORT DATA_DIR STORE_DIR DATABASE_URL SCHEMA
"""

from __future__ import annotations

import sys
from pathlib import Path

import uvicorn

from services.api.app import create_app
from services.api.settings import ServiceSettings
from services.cli.lifetime import die_with_parent
from tests.integration.test_api_server import TOKENS_ENV


def main(port: str, data_dir: str, store: str, database_url: str, schema: str) -> None:
    die_with_parent()
    settings = ServiceSettings(
        data_dir=Path(data_dir),
        store_url=store,
        database_url=database_url,
        database_schema=schema,
        tokens=TOKENS_ENV,
        scheduling=False,  # an API-only replica: no scheduler, no Ray
    )
    uvicorn.run(create_app(settings), host="127.0.0.1", port=int(port), log_level="warning")


if __name__ == "__main__":
    main(*sys.argv[1:])
