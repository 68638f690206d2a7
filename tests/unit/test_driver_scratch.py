"""Drivers' scratch folders: named after their process, swept once that process is gone."""

import os
import subprocess
import sys

from workers.driver import scratch


def dead_pid() -> int:
    """The id of a process that has exited (and been reaped)."""
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    return int(child.stdout)


def test_a_folder_is_named_after_its_job_and_process(tmp_path, monkeypatch):
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    folder = scratch.make("job-a-b")
    assert folder.parent == tmp_path and folder.name.startswith("nbake-job-a-b-p")
    assert scratch.owner(folder) == os.getpid()


def test_sweep_removes_only_folders_of_processes_that_are_gone(tmp_path):
    gone = tmp_path / f"nbake-job-1-p{dead_pid()}-x1y_2"
    mine = tmp_path / f"nbake-job-2-p{os.getpid()}-abc"
    unrelated = [tmp_path / "nbake-ray-session", tmp_path / f"other-p{dead_pid()}-abc"]
    for folder in (gone, mine, *unrelated):
        folder.mkdir()
    (gone / "model.safetensors").write_bytes(b"x")
    a_file = tmp_path / f"nbake-job-3-p{dead_pid()}-file"
    a_file.write_text("a file with a scratch folder's name")

    assert scratch.sweep(tmp_path) == [gone]
    assert not gone.exists() and mine.exists() and all(folder.exists() for folder in unrelated)
    assert a_file.exists()


def test_remove_own_leaves_other_processes_folders(tmp_path):
    mine = tmp_path / f"nbake-job-2-p{os.getpid()}-abc"
    other = tmp_path / f"nbake-job-4-p{os.getppid()}-abc"
    for folder in (mine, other):
        folder.mkdir()
    scratch.remove_own(tmp_path)
    assert not mine.exists() and other.exists()


def test_a_running_process_of_another_user_counts_as_running():
    assert scratch.running(1) and scratch.running(os.getpid()) and not scratch.running(dead_pid())
