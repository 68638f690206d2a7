"""How the CLI reports a problem the user can fix: one `error: <where>: <problem>` line, exit status 2.

A traceback is for bugs; a bad scene file, an unknown scene name or an unwritable output path are
not bugs, so they get a message a person can act on and the same exit status as a usage error.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import NoReturn

import typer
from pydantic import ValidationError

from workers.scene.format.errors import SceneError
from workers.scene.portability.io import dotted_path

USER_ERROR_EXIT = 2


def fail(where: str, problem: str) -> NoReturn:
    """Print `error: <where>: <problem>` to stderr and exit with status 2."""
    typer.echo(f"error: {where}: {problem}", err=True)
    raise typer.Exit(USER_ERROR_EXIT)


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn scene and settings validation errors raised inside the block into `fail`."""
    try:
        yield
    except SceneError as error:
        fail(error.field, error.problem)
    except ValidationError as error:
        first = error.errors()[0]
        fail(dotted_path(first["loc"], {}) or error.title, first["msg"].removeprefix("Value error, "))
