"""What an upload sends: a scene directory becomes one tar.gz (the server unpacks it with its path,
symlink and size checks); a scene file or an archive goes as it is.
"""

from __future__ import annotations

import tarfile
import tempfile
from pathlib import Path
from typing import BinaryIO

ARCHIVE_SUFFIXES = (".zip", ".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tar.xz")


def upload_parts(path: str | Path) -> list[tuple[str, BinaryIO]]:
    """(name, stream) pairs to upload for `path`; the caller closes the streams."""
    path = Path(path)
    if path.is_dir():
        return [(f"{path.resolve().name}.tar.gz", pack_directory(path))]
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such scene file or directory")
    return [(path.name, path.open("rb"))]


def pack_directory(folder: Path) -> BinaryIO:
    """A tar.gz of the folder's regular files, relative to it; symlinks are left out, not followed."""
    spool = tempfile.TemporaryFile()  # noqa: SIM115  (returned open; the caller closes it)
    with tarfile.open(fileobj=spool, mode="w:gz") as tar:
        for file in sorted(folder.rglob("*")):
            if file.is_file() and not file.is_symlink():
                tar.add(file, arcname=file.relative_to(folder).as_posix(), recursive=False)
    spool.seek(0)
    return spool
