import pytest

from workers.runtime.checkpoints import CheckpointStore


def files_of(step: int) -> dict[str, bytes]:
    return {"model.safetensors": bytes([step % 256]) * 10, "loop.json": b'{"step": %d}' % step}


def test_round_trip_and_latest(tmp_path):
    store = CheckpointStore(str(tmp_path / "ckpt"), keep=3)
    assert store.latest() is None
    store.save(5, files_of(5))
    store.save(10, files_of(10))
    assert store.latest() == 10
    assert store.load(5) == files_of(5)
    assert store.load(10) == files_of(10)


def test_keeps_only_the_last_k(tmp_path):
    store = CheckpointStore(str(tmp_path), keep=2)
    for step in (1, 2, 3, 4):
        store.save(step, files_of(step))
    assert store.steps() == [3, 4]
    with pytest.raises(FileNotFoundError, match="step 1"):
        store.load(1)


def test_a_crashed_write_is_invisible_and_cleared(tmp_path):
    store = CheckpointStore(str(tmp_path), keep=3)
    store.save(1, files_of(1))
    partial = tmp_path / "step-000000007"  # a save that crashed before its commit marker
    partial.mkdir()
    (partial / "model.safetensors").write_bytes(b"half")
    assert store.steps() == [1]
    assert store.latest() == 1
    store.save(2, files_of(2))
    assert not partial.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["step-000000001", "step-000000002"]


def test_a_crash_while_the_marker_is_written_leaves_the_previous_checkpoint(tmp_path, monkeypatch):
    """A driver killed as the marker's bytes go out (the file created, nothing written yet) must not leave
    an empty marker that makes the step look complete: the resumed job read it and failed on its JSON."""
    store = CheckpointStore(str(tmp_path), keep=3)
    store.save(1, files_of(1))
    write = store.fs.pipe_file

    def killed_at_the_marker(path, value, **kwargs):
        if "COMMITTED" in path:
            write(path, b"")
            raise KeyboardInterrupt("killed")
        return write(path, value, **kwargs)

    monkeypatch.setattr(store.fs, "pipe_file", killed_at_the_marker)
    with pytest.raises(KeyboardInterrupt):
        store.save(2, files_of(2))
    monkeypatch.undo()
    resumed = CheckpointStore(str(tmp_path), keep=3)
    assert resumed.steps() == [1] and resumed.load(1) == files_of(1)
    resumed.save(2, files_of(2))
    assert resumed.steps() == [1, 2] and resumed.load(2) == files_of(2)


def test_saving_a_step_again_replaces_it(tmp_path):
    store = CheckpointStore(str(tmp_path), keep=3)
    store.save(3, {"a": b"old", "b": b"old"})
    store.save(3, {"a": b"new"})
    assert store.load(3) == {"a": b"new"}


def test_works_on_an_fsspec_url():
    store = CheckpointStore("memory://nbake-test-checkpoints", keep=1)
    store.save(7, files_of(7))
    store.save(8, files_of(8))
    assert store.steps() == [8]
    assert store.load(8) == files_of(8)
    store.fs.rm(store.root, recursive=True)


def test_keep_must_be_positive(tmp_path):
    with pytest.raises(ValueError, match="keep"):
        CheckpointStore(str(tmp_path), keep=0)
