"""Tenancy in the job database, on real SQLite and real PostgreSQL: migration 0002 puts everything that
existed into the default tenant, identical work of two tenants is two jobs, another tenant's job, artifact
or asset is not found, and tokens are stored hashed, survive restarts when created, and stop working the
moment they are revoked on the replica that revokes them, and within `TOKEN_CACHE_S` on every other."""

from __future__ import annotations

import hashlib
from concurrent.futures import ThreadPoolExecutor

import pytest
from alembic import command
from alembic.config import Config
from sqlalchemy import event, text

from services.artifacts.artifacts import ArtifactNotFound
from services.artifacts.assets import AssetNotFound
from services.artifacts.store import BlobStore
from services.jobs.db import MIGRATIONS, Database
from services.jobs.errors import JobNotFound
from services.jobs.repository import JobRepository
from services.jobs.scene_specs import SceneSpecs
from services.jobs.scenes import SceneResolver
from services.jobs.submission import JobRequest, Submitter
from services.jobs.tables import utcnow
from services.jobs.tenants import DEFAULT_TENANT, Tenancy
from services.jobs.tokens import TOKEN_CACHE_S, DatabaseTokens, TokenCache, token_hash
from services.platform.auth import Forbidden, Principal, Unauthorized, authorize
from services.platform.errors import Conflict, InvalidInput
from tests.unit.test_jobs_repository import db, new_job  # noqa: F401 (db is a fixture)

A, B = Principal("acme", "submit"), Principal("bolt", "submit")
ADMIN = Principal(DEFAULT_TENANT, "admin")
TINY = JobRequest(kind="render", scene="cornell_box", preset="quick", config={"width": 8, "height": 8})
ARTIFACT, ASSET = "sha256:" + "a" * 64, "sha256:" + "b" * 64


def test_migration_0002_puts_existing_jobs_and_keys_in_the_default_tenant(db, tmp_path):  # noqa: F811
    with db.engine.begin() as connection:
        tables = ("tenant_quotas", "asset_owners", "job_events", "idempotency_keys", "jobs", "api_tokens")
        for table in tables:
            connection.execute(text(f"DROP TABLE {table}"))
        connection.execute(text("DROP TABLE alembic_version"))
        config = Config()
        config.set_main_option("script_location", str(MIGRATIONS))
        config.attributes["connection"] = connection
        command.upgrade(config, "0001")
    old = new_job("sha256:old")
    later = ("seq", "tenant", "scene_digest")  # tenant: 0002's; scene_digest: 0004's, which moves `scene`
    columns = {c.key: getattr(old, c.key) for c in old.__table__.columns if c.key not in later}
    columns |= {"scene_ref": "{}", "scene": "{}", "config": "{}", "state": "QUEUED", "created_at": utcnow()}
    with db.engine.begin() as connection:  # rows as 0001 holds them, written without today's models
        names = ", ".join(f'"{name}"' for name in columns)
        values = ", ".join(f":{name}" for name in columns)
        connection.execute(text(f"INSERT INTO jobs ({names}) VALUES ({values})"), columns)
        key = {"key": "content:sha256:old", "job": old.id, "now": utcnow()}
        connection.execute(text("INSERT INTO idempotency_keys VALUES (:key, :job, 'r', :now)"), key)
        connection.execute(text("INSERT INTO api_tokens VALUES ('h', 'admin', :now)"), key)
    db.migrate(SceneSpecs(BlobStore(str(tmp_path / "store"))))
    jobs = JobRepository(db)
    with db.engine.connect() as connection:
        assert connection.execute(text("SELECT tenant FROM jobs")).scalar() == DEFAULT_TENANT
        keys = connection.execute(text("SELECT key FROM idempotency_keys")).scalars().all()
        assert keys == ["default/content:sha256:old"]
        assert connection.execute(text("SELECT count(*) FROM api_tokens")).scalar() == 0  # stored at start
    assert jobs.get(old.id, DEFAULT_TENANT).id == old.id


def submitter(db: Database, tmp_path) -> Submitter:  # noqa: F811
    blobs = BlobStore(str(tmp_path / "store"))
    return Submitter(
        JobRepository(db), SceneResolver(blobs, str(tmp_path / "store"), tmp_path, Tenancy(db)), 3
    )


def test_identical_work_is_one_job_per_tenant_and_invisible_to_the_others(db, tmp_path):  # noqa: F811
    submit = submitter(db, tmp_path)
    a, created_a = submit.submit(TINY, principal=A)
    b, created_b = submit.submit(TINY, principal=B)
    assert created_a and created_b and a.id != b.id and a.idempotency_key == b.idempotency_key
    assert (a.tenant, b.tenant) == ("acme", "bolt")
    assert submit.submit(TINY, principal=A)[0].id == a.id
    assert submit.submit(TINY, principal=B)[0].id == b.id
    forced = TINY.model_copy(update={"force": True})
    keyed_a, keyed_b = (submit.submit(forced, "same-key", p)[0] for p in (A, B))
    assert keyed_a.id != keyed_b.id and submit.submit(forced, "same-key", A)[0].id == keyed_a.id

    jobs = submit.jobs
    with pytest.raises(JobNotFound):
        jobs.get(a.id, "bolt")
    with pytest.raises(JobNotFound):
        jobs.request_cancel(a.id, "bolt")
    assert jobs.get(a.id, "acme").id == a.id and jobs.get(a.id).id == a.id  # None: every tenant (admin)
    assert {j.id for j in jobs.list([], None, None, 50, "bolt")[0]} == {b.id, keyed_b.id}
    assert {j.id for j in jobs.list([], None, None, 50)[0]} == {a.id, b.id, keyed_a.id, keyed_b.id}


def test_artifacts_are_their_jobs_tenants_and_assets_their_uploaders(db, tmp_path):  # noqa: F811
    tenancy = Tenancy(db)
    JobRepository(db).create(new_job(tenant="acme", artifact_id=ARTIFACT), None, None)
    assert tenancy.artifact(A, ARTIFACT) == ARTIFACT and tenancy.artifact(ADMIN, ARTIFACT) == ARTIFACT
    for principal, artifact in ((B, ARTIFACT), (Principal(DEFAULT_TENANT, "read"), ARTIFACT), (A, "x")):
        with pytest.raises(ArtifactNotFound):
            tenancy.artifact(principal, artifact)
    unowned = "sha256:" + "c" * 64  # published by no job (by hand): the default tenant's
    assert tenancy.sees_artifact(Principal(DEFAULT_TENANT, "read"), unowned)
    assert not tenancy.sees_artifact(A, unowned)

    tenancy.own_asset("acme", ASSET)
    tenancy.own_asset("acme", ASSET)  # an upload of the same files again
    assert tenancy.asset(A, ASSET) == ASSET
    with pytest.raises(AssetNotFound):
        tenancy.asset(B, ASSET)
    with pytest.raises(InvalidInput, match="no asset"):  # a job of B cannot name A's upload either
        submitter(db, tmp_path).submit(TINY.model_copy(update={"scene": ASSET}), principal=B)
    older = "sha256:" + "d" * 64
    assert tenancy.adopt_unowned_assets([ASSET, older]) == 1  # only the one from before tenants
    assert tenancy.sees_asset(Principal(DEFAULT_TENANT, "read"), older)
    assert not tenancy.sees_asset(Principal(DEFAULT_TENANT, "read"), ASSET)


def test_tokens_are_hashed_kept_across_restarts_and_revoked_at_once(db):  # noqa: F811
    tokens = DatabaseTokens(db)
    tokens.store_configured({"configured-admin": "admin"})
    row, secret = tokens.create("acme", "read", "ci")
    assert authorize(tokens, secret, "read", "") == Principal("acme", "read")
    with pytest.raises(Forbidden):
        authorize(tokens, secret, "submit", "")
    with db.engine.connect() as connection:
        stored = [tuple(r) for r in connection.execute(text("SELECT * FROM api_tokens"))]
    assert not any(secret in str(value) for r in stored for value in r)
    assert hashlib.sha256(secret.encode()).hexdigest() in {r[0] for r in stored}

    tokens.store_configured({"configured-admin": "admin"})  # the next start: created tokens stay
    assert authorize(tokens, secret, "read", "").tenant == "acme"
    assert {(t.tenant, t.scope, t.source) for t in tokens.listing()} == {
        (DEFAULT_TENANT, "admin", "configured"),
        ("acme", "read", "created"),
    }
    configured = next(t for t in tokens.listing() if t.source == "configured")
    with pytest.raises(Conflict):
        tokens.revoke(configured.id)
    tokens.revoke(row.id)
    with pytest.raises(Unauthorized, match="unknown token"):
        authorize(tokens, secret, "read", "")
    with pytest.raises(InvalidInput):
        tokens.create("Not A Tenant", "read")


def test_a_token_revoked_on_another_replica_is_refused_once_its_cached_read_expires(db):  # noqa: F811
    """Each process trusts a token it read for `TOKEN_CACHE_S`: requests in between read no database, and a
    revocation on another replica (or a configured token dropped at its restart) holds after that bound."""
    replica_db = Database(db.url.render_as_string(hide_password=False), db.schema)  # a second API replica
    tokens, other = DatabaseTokens(db), DatabaseTokens(replica_db)
    now = [0.0]
    other.cache.clock = lambda: now[0]
    reads = []
    event.listen(
        replica_db.engine, "before_cursor_execute", lambda *args: reads.append("api_tokens" in args[2])
    )
    try:
        tokens.store_configured({"configured-read": "read"})
        row, secret = tokens.create("acme", "submit")
        for _ in range(3):
            assert authorize(other, secret, "read", "") == Principal("acme", "submit")
            with pytest.raises(Forbidden):  # the scope is checked on the cached answer too
                authorize(other, secret, "admin", "")
        assert sum(reads) == 1  # one read for six checks
        for replica in (tokens, other):
            authorize(replica, "configured-read", "read", "")

        tokens.revoke(row.id)
        tokens.store_configured({})  # the configured token is left out at a restart of the first replica
        for token in (secret, "configured-read"):  # refused at once there
            with pytest.raises(Unauthorized, match="unknown token"):
                authorize(tokens, token, "read", "")
        now[0] += TOKEN_CACHE_S / 2
        assert authorize(other, secret, "read", "").tenant == "acme"  # the documented bound: still trusted
        now[0] += TOKEN_CACHE_S / 2
        for token in (secret, "configured-read"):
            with pytest.raises(Unauthorized, match="unknown token"):
                authorize(other, token, "read", "")
    finally:
        replica_db.dispose()


def test_a_token_read_before_its_revocation_is_not_cached_after_it():
    """A read and a revocation in the same process race: the read began first, the revocation dropped the
    cached entry, then the read would put the token back for another `TOKEN_CACHE_S`."""
    cache, digest = TokenCache(), token_hash("secret")
    began = cache.generation
    cache.drop(digest)  # the revocation, between the read and its caching
    cache.put(digest, Principal("acme", "read"), began)
    assert cache.get(digest) is None
    cache.put(digest, Principal("acme", "read"), cache.generation)  # a read begun after it is cached
    assert cache.get(digest) == Principal("acme", "read")


def test_replicas_starting_together_store_the_configured_tokens_once(db):  # noqa: F811
    """Each replica replaces the configured tokens at start; without turns, two interleave their delete
    and insert and one fails on the token's primary key (seen with two API processes on PostgreSQL)."""
    tokens = {f"configured-{i}": "read" for i in range(50)}
    replicas = [Database(db.url.render_as_string(hide_password=False), db.schema) for _ in range(4)]
    try:
        for _ in range(5):
            with ThreadPoolExecutor(len(replicas)) as pool:
                list(pool.map(lambda replica: DatabaseTokens(replica).store_configured(tokens), replicas))
    finally:
        for replica in replicas:
            replica.dispose()
    assert len([t for t in DatabaseTokens(db).listing() if t.source == "configured"]) == len(tokens)
