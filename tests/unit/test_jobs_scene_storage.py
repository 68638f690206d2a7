"""A job row names its scene by digest and the scene's JSON is stored once in the artifact store (issue 50:
every forced resubmission of a 100k-instance USD scene stored its 15 MB again in the job database); the
migration moves the scenes of existing jobs into the store."""

from __future__ import annotations

from pathlib import Path

import pytest
import sqlalchemy as sa
from alembic import command
from alembic.config import Config

from services.api.services import Services
from services.api.settings import ServiceSettings
from services.artifacts.store import BlobStore
from services.jobs.db import MIGRATIONS, Database
from services.jobs.identity import canonical_json
from services.jobs.scene_specs import SceneSpecs
from services.jobs.submission import JobRequest
from services.jobs.tables import Event, Job, utcnow
from services.platform.errors import InvalidInput
from workers.scene.generators.builtin import get_builtin

RESUBMISSIONS = 5


@pytest.fixture
def services(tmp_path):
    built = Services.build(ServiceSettings(data_dir=tmp_path, tokens="t:admin", scheduling=False))
    built.start()
    try:
        yield built
    finally:
        built.stop()


def instanced_box(copies: int) -> dict:
    """The Cornell box with its last object placed `copies` times: a large scene of little geometry."""
    scene = get_builtin("cornell_box").model_dump(mode="json")
    scene["objects"][-1]["instances"] = [{"translate": [0.0, 1e-5 * i, 0.0]} for i in range(copies)]
    return scene


def database_bytes(db: Database) -> int:
    """The SQLite file's size once its write-ahead log is folded into it."""
    with db.engine.connect() as connection:
        connection.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
    return Path(db.url.database).stat().st_size


def test_forced_resubmissions_of_a_large_scene_store_it_once(services):
    scene = instanced_box(4000)
    request = JobRequest(kind="render", scene=scene, preset="quick", force=True)
    first, _ = services.submit(request)
    stored = services.scenes.resolve(scene).spec_json
    scene_bytes = len(canonical_json(stored))
    blobs, size = set(services.blobs.digests()), database_bytes(services.db)
    again = [services.submit(request)[0] for _ in range(RESUBMISSIONS)]
    growth = database_bytes(services.db) - size
    print(f"scene {scene_bytes} bytes; {RESUBMISSIONS} forced resubmissions grew the database {growth} bytes")
    assert len({job.id for job in [first, *again]}) == RESUBMISSIONS + 1
    assert growth < scene_bytes / 4  # each row held the scene: RESUBMISSIONS times its size
    assert {job.scene_digest for job in again} == {first.scene_digest}
    assert set(services.blobs.digests()) == blobs  # the store holds the one copy the first job put there
    assert services.scenes.specs.get(first.scene_digest) == stored


def test_a_refused_job_stores_no_scene(tmp_path):
    """The scene goes into the store only once the job's plan is accepted: a refusal leaves nothing."""
    settings = ServiceSettings(data_dir=tmp_path, tokens="t:admin", scheduling=False, max_job_seconds=1e-3)
    built = Services.build(settings)
    built.start()
    try:
        with pytest.raises(InvalidInput, match="max_job_seconds"):
            built.submit(JobRequest(kind="render", scene=instanced_box(10), preset="quick"))
        assert list(built.blobs.digests()) == []
    finally:
        built.stop()


def migrated(db: Database, revision: str) -> None:
    with db.engine.begin() as connection:
        config = Config()
        config.set_main_option("script_location", str(MIGRATIONS))
        config.attributes["connection"] = connection
        command.upgrade(config, revision)


def job_before_0004(db: Database, scene: dict) -> str:
    """A job and its first event as revision 0003 stored them: the scene's JSON in the row."""
    row = dict(
        id="job-old",
        tenant="default",
        kind="render",
        state="succeeded",
        scene_ref={"source": "inline"},
        scene=scene,
        scene_hash="sha256:" + "1" * 64,
        preset="quick",
        config={"spp": 4},
        seed=0,
        priority=0,
        code_version="old",
        idempotency_key="sha256:" + "2" * 64,
        attempts=1,
        max_attempts=3,
        cancel_requested=False,
        last_event_seq=1,
        created_at=utcnow(),
    )
    event = dict(job_id=row["id"], seq=1, type="state", time=utcnow(), data={})
    with db.engine.begin() as connection:
        for table, values in (("jobs", row), ("job_events", event)):
            connection.execute(sa.Table(table, sa.MetaData(), autoload_with=connection).insert(), values)
    return row["id"]


def test_migration_0004_moves_the_jobs_scenes_into_the_store_and_keeps_their_events(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'jobs.db'}")
    migrated(db, "0003")
    scene = instanced_box(3)
    job_id = job_before_0004(db, scene)
    with pytest.raises(RuntimeError, match="0004 moves the jobs' scenes"):
        db.migrate()  # no store to move them to: refused, nothing changed
    specs = SceneSpecs(BlobStore(str(tmp_path / "store")))
    db.migrate(specs)
    with db.reading() as session:
        job = session.get(Job, 1)
        events = session.scalars(sa.select(Event).where(Event.job_id == job_id)).all()
    assert job.id == job_id and specs.get(job.scene_digest) == scene
    assert [event.seq for event in events] == [1]  # the jobs table was altered in place, not copied
    db.dispose()
