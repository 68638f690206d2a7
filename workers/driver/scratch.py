"""Job drivers' private scratch folders, which a killed driver cannot remove itself.

A driver that uploads its artifact (a service's job) writes the files to a private temporary folder first
and removes it when the job ends. A driver ended from outside (a cancel it did not heed in time, a lost
job, a crash) never reaches its `finally`, so the folder is named after the driver's process,
`nbake-<job>-p<pid>-<random>`, and is removed either by the driver on request just before it is ended
(`remove_own`) or, when it died unannounced, by the next driver on the node (`sweep`): a folder whose
process no longer runs belongs to nobody.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

PREFIX = "nbake-"
NAME = re.compile(rf"^{PREFIX}.+-p(\d+)-[a-z0-9_]+$")  # mkdtemp's random suffix has no '-'


def make(job_id: str) -> Path:
    """A fresh private folder for `job_id`, owned by this process."""
    return Path(tempfile.mkdtemp(prefix=f"{PREFIX}{job_id}-p{os.getpid()}-"))


def owner(folder: Path) -> int | None:
    """The process id in a scratch folder's name; None for any other folder."""
    match = NAME.match(folder.name)
    return int(match.group(1)) if match else None


def running(pid: int) -> bool:
    """Whether process `pid` exists on this node (one of another user counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_own(root: Path | None = None) -> None:
    """Remove this process's scratch folders (a driver runs one job, so they are its job's)."""
    for folder in _folders(root):
        if owner(folder) == os.getpid():
            shutil.rmtree(folder, ignore_errors=True)


def sweep(root: Path | None = None) -> list[Path]:
    """Remove the scratch folders of processes that no longer run; the folders removed."""
    removed = []
    for folder in _folders(root):
        pid = owner(folder)
        if pid is not None and not running(pid):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def _folders(root: Path | None) -> list[Path]:
    root = Path(root or tempfile.gettempdir())
    return [path for path in root.glob(f"{PREFIX}*") if path.is_dir()]
