"""The arrays of `nbake query`: read from .npy and .npz files, written to one .npz."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from neuralbake_client.cli.remote import USAGE, exit_with


def read_inputs(items: list[str]) -> dict[str, np.ndarray]:
    """`FILE.npz` (every array under its name), `FILE.npy` (named after the file) or `NAME=FILE.npy`."""
    arrays: dict[str, np.ndarray] = {}
    for item in items:
        name, sep, file = item.partition("=")
        path = Path(file if sep else item)
        try:
            if path.suffix == ".npz":
                if sep:
                    exit_with(USAGE, f"error: --input: {item}: an .npz file brings its own names")
                with np.load(path, allow_pickle=False) as archive:
                    found = {key: archive[key] for key in archive.files}
            elif path.suffix == ".npy":
                found = {name if sep else path.stem: np.load(path, allow_pickle=False)}
            else:
                exit_with(USAGE, f"error: --input: {path}: use .npy or .npz files")
        except (OSError, ValueError, zipfile.BadZipFile) as error:
            exit_with(USAGE, f"error: --input: {path}: {error}")
        for key in found.keys() & arrays.keys():
            exit_with(USAGE, f"error: --input: array {key!r} is given twice")
        arrays |= found
    return arrays


def write_outputs(path: Path, arrays: dict[str, np.ndarray]) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **arrays)
    except OSError as error:
        exit_with(USAGE, f"error: --output: {path}: {error}")
