"""Tenancy: every token belongs to a tenant, and so does everything made with it (jobs, and through them
artifacts; uploaded assets through `AssetOwner` rows). A caller sees only its own tenant's things, as if the
others did not exist (404, never 403, so ids of other tenants cannot be probed); an admin token sees all.

Configured tokens (NBAKE_TOKENS, the generated admin token) belong to the `default` tenant, as do the jobs
and assets made before tenants existed and artifacts that no job published (placed in the store by hand).
"""

from __future__ import annotations

import re
import threading
from collections import OrderedDict
from collections.abc import Iterable

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError

from services.artifacts.artifacts import ArtifactNotFound
from services.artifacts.assets import AssetNotFound
from services.artifacts.digests import known_digest
from services.jobs.db import Database
from services.jobs.tables import DEFAULT_TENANT, AssetOwner, Job
from services.platform.auth import Principal
from services.platform.errors import InvalidInput

__all__ = ["DEFAULT_TENANT", "Tenancy", "checked_tenant"]
TENANT_NAME = re.compile(r"[a-z0-9][a-z0-9_-]{0,63}")


def checked_tenant(name: str) -> str:
    if not isinstance(name, str) or TENANT_NAME.fullmatch(name) is None:
        raise InvalidInput("1 to 64 characters of a-z, 0-9, '-' and '_', starting alphanumeric", "tenant")
    return name


SEEN_CACHE_SIZE = 4096


class Tenancy:
    """Who may see which asset and artifact, read from the job database. An artifact's tenant never
    changes once its job holds it, so a "yes" is remembered (the inference service asks at every query);
    a "no" is asked again, since the job may be about to record the artifact it just published."""

    def __init__(self, db: Database):
        self.db = db
        self._seen: OrderedDict[tuple[str, str], None] = OrderedDict()
        self._lock = threading.Lock()

    def artifact(self, principal: Principal, artifact_id: str) -> str:
        """`artifact_id` if it is a digest the caller sees; ArtifactNotFound (404) otherwise."""
        if not self.sees_artifact(principal, known_digest(artifact_id, ArtifactNotFound)):
            raise ArtifactNotFound(artifact_id)
        return artifact_id

    def asset(self, principal: Principal, asset_id: str) -> str:
        """`asset_id` if it is a digest the caller sees; AssetNotFound (404) otherwise."""
        if not self.sees_asset(principal, known_digest(asset_id, AssetNotFound)):
            raise AssetNotFound(asset_id)
        return asset_id

    def sees_artifact(self, principal: Principal, artifact_id: str) -> bool:
        """An artifact is its job's: visible to the tenant of a job that published it; one that no job
        published is the default tenant's."""
        if principal.sees_all:
            return True
        key = (principal.tenant, artifact_id)
        with self._lock:
            if key in self._seen:
                self._seen.move_to_end(key)
                return True
        with self.db.reading() as session:
            owners = set(session.scalars(select(Job.tenant).where(Job.artifact_id == artifact_id).distinct()))
        if principal.tenant in owners:
            with self._lock:
                self._seen[key] = None
                while len(self._seen) > SEEN_CACHE_SIZE:
                    self._seen.popitem(last=False)
            return True
        return not owners and principal.tenant == DEFAULT_TENANT  # a job may claim it yet: not remembered

    def sees_asset(self, principal: Principal, asset_id: str) -> bool:
        if principal.sees_all:
            return True
        with self.db.reading() as session:
            return session.get(AssetOwner, (asset_id, principal.tenant)) is not None

    def own_asset(self, tenant: str, asset_id: str) -> None:
        """Record that `tenant` uploaded `asset_id` (again is fine). Recorded before the asset's listing is
        saved, so a listing without any owner is one from before tenants existed."""
        try:
            with self.db.writing() as session:
                if session.get(AssetOwner, (asset_id, tenant)) is None:
                    session.add(AssetOwner(asset_id=asset_id, tenant=tenant))
        except IntegrityError:  # the same tenant uploading the same files at the same time: recorded once
            pass

    def adopt_unowned_assets(self, asset_ids: Iterable[str]) -> int:
        """Give assets that nobody owns (uploaded before tenants existed) to the default tenant; how many."""
        ids = set(asset_ids)
        if not ids:
            return 0
        with self.db.writing() as session:
            owned = set(session.scalars(select(AssetOwner.asset_id).where(AssetOwner.asset_id.in_(ids))))
            session.add_all(AssetOwner(asset_id=i, tenant=DEFAULT_TENANT) for i in sorted(ids - owned))
        return len(ids - owned)
