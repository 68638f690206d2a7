"""The settings base every server of one deployment reads alike: its data dir, the job database (tokens,
tenancy) and the artifact store, from the same `NBAKE_*` variables; each server's settings add their own."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field


def env_values(variables: Mapping[str, str], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """The fields named in `variables` (field -> environment variable) whose variable is set, then the
    `overrides` that are not None (a command's options win over the environment)."""
    found = {name: os.environ.get(variable) for name, variable in variables.items()}
    return {k: v for k, v in found.items() if v} | {k: v for k, v in overrides.items() if v is not None}


class SharedSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    ENV: ClassVar[dict[str, str]] = {
        "database_url": "NBAKE_DATABASE_URL",
        "database_schema": "NBAKE_DATABASE_SCHEMA",
        "store_url": "NBAKE_STORE_URL",
    }

    data_dir: Path
    database_url: str | None = Field(None, description="default: SQLite file <data_dir>/jobs.db (WAL)")
    database_schema: str | None = Field(None, description="PostgreSQL schema (one per deployment or test)")
    store_url: str | None = Field(None, description="default: <data_dir>/store; s3://bucket/prefix at scale")

    @classmethod
    def from_env(cls, data_dir: Path, **overrides):
        """These settings from `cls.ENV`'s variables, with `overrides` (None: not given) on top."""
        return cls(data_dir=data_dir, **env_values(cls.ENV, overrides))

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{(self.data_dir / 'jobs.db').resolve()}"

    @property
    def store(self) -> str:
        return self.store_url or str((self.data_dir / "store").resolve())
