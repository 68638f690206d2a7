"""`nbake submit | jobs | show | watch | cancel | download`: the job service from a shell or a CI
pipeline, built on the SDK (the same calls a Python user makes).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.progress import DownloadColumn, Progress, TransferSpeedColumn

from neuralbake_client.cli.output import Output
from neuralbake_client.cli.overrides import SetOption, parse_sets
from neuralbake_client.cli.remote import (
    EXIT_BY_STATE,
    TIMED_OUT,
    USAGE,
    JsonOption,
    TokenOption,
    UrlOption,
    connect,
    exit_with,
    remote_errors,
)
from neuralbake_client.states import JobState

if TYPE_CHECKING:
    from neuralbake_client.client import Client
    from neuralbake_client.models import Job


def scene_argument(scene: str) -> str | Path:
    """A local file or folder is uploaded; anything else is a built-in scene name or an asset id."""
    path = Path(scene)
    return path if path.exists() else scene


TimeoutOption = Annotated[
    str | None,
    typer.Option(
        "--timeout", help="Give up waiting after this long (e.g. 90s, 30m): exit 6; the job goes on."
    ),
]


def follow(client: Client, job: Job, out: Output, timeout: str | None = None) -> None:
    """Print the job's events until its final state, then the job; exit with the state's status (6 when
    `timeout` passes first)."""
    from neuralbake_client.durations import seconds
    from neuralbake_client.errors import WaitTimeout

    try:
        limit = seconds(timeout) if timeout is not None else None
    except ValueError as error:
        exit_with(USAGE, f"error: --timeout: {error}")
    try:
        with out.following(job) as on_event:
            final = client.wait(job, on_event=on_event, timeout=limit)
    except WaitTimeout as error:
        if out.json:
            out.line("timeout", job_id=error.job_id, timeout_s=error.timeout)
        exit_with(TIMED_OUT, f"error: {error} (`nbake watch {error.job_id}` follows it again)")
    warning = client.manifest(final.artifact_id).annotations.get("warning") if final.artifact_id else None
    out.job(final, event="result", warning=warning)
    raise typer.Exit(EXIT_BY_STATE[final.state])


def submit_command(
    scene: Annotated[
        str, typer.Argument(help="A scene file or folder (uploaded), a built-in name or an asset id.")
    ],
    kind: Annotated[
        str,
        typer.Option(
            "--kind",
            "-k",
            help="The model kind: render, lod, prt, lsnif, explore, mesogan "
            "(`nbake kinds` lists the server's, with their parameters).",
        ),
    ],
    preset: Annotated[
        str | None, typer.Option(help="quick, default or paper (the server's default).")
    ] = None,
    set_: SetOption = None,
    seed: Annotated[int | None, typer.Option(min=0, help="Seed of every sampler.")] = None,
    priority: Annotated[int | None, typer.Option(help="Higher starts first.")] = None,
    wait: Annotated[bool, typer.Option("--wait", help="Follow the job; exit with its outcome.")] = False,
    timeout: TimeoutOption = None,
    force: Annotated[bool, typer.Option("--force", help="Run even if identical work exists.")] = False,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Submit a job (or get the identical one already there: said as `reused`). With --wait, exit 0
    succeeded, 1 failed, 3 cancelled, 6 --timeout passed."""
    out, config = Output(json_lines), parse_sets(set_ or [])
    with remote_errors(), connect(url, token) as client:
        job = client.submit(
            kind,
            scene_argument(scene),
            preset=preset,
            config=config,
            seed=seed,
            priority=priority,
            force=force,
        )
        out.job(job, event="submitted")
        if wait:
            follow(client, job, out, timeout)


def jobs_command(
    state: Annotated[list[JobState] | None, typer.Option(help="Only jobs in this state; repeat.")] = None,
    kind: Annotated[str | None, typer.Option(help="Only jobs of this kind.")] = None,
    limit: Annotated[int, typer.Option(min=1, max=200, help="How many (newest first).")] = 20,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """List jobs, newest first."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        for job in client.list(state, kind, limit=limit).items:
            out.job(job)


def show_command(
    job: Annotated[str, typer.Argument(help="A job id, or an artifact id (its job).")],
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Show one job."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        out.job(client.get(job))


def watch_command(
    job: Annotated[str, typer.Argument(help="A job id, or an artifact id (its job).")],
    timeout: TimeoutOption = None,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Follow a job to its end: exit 0 succeeded, 1 failed, 3 cancelled, 6 --timeout passed."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        follow(client, client.get(job), out, timeout)


def cancel_command(
    job: Annotated[str, typer.Argument(help="A job id, or an artifact id (its job).")],
    wait: Annotated[bool, typer.Option("--wait", help="Follow the job until it has stopped.")] = False,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Cancel a queued or running job."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        cancelled = client.cancel(job)
        out.job(cancelled, event="cancel_requested")
        if wait:
            follow(client, cancelled, out)


def download_command(
    artifact: Annotated[
        str, typer.Argument(help="An artifact id or its hex digest, or a job id (its artifact).")
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="Folder to write the files into.")],
    name: Annotated[list[str] | None, typer.Option("--name", help="Only this file; repeat.")] = None,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Download an artifact's files (resuming partial ones, verifying sha256)."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        manifest = client.manifest(artifact)
        try:
            entries = [manifest.file(n) for n in name] if name else manifest.files
        except KeyError as error:
            exit_with(USAGE, f"error: --name: {error.args[0]}")
        if out.json:
            files = client.download(manifest, output, [e.name for e in entries])
        else:
            total = sum(e.size for e in entries)
            with Progress(
                *Progress.get_default_columns()[:2], DownloadColumn(), TransferSpeedColumn()
            ) as bar:
                task = bar.add_task(manifest.artifact_id[:19], total=total)
                files = client.download(
                    manifest,
                    output,
                    [e.name for e in entries],
                    on_bytes=lambda count: bar.advance(task, count),
                )
        for file in files:
            if out.json:
                fields = file.entry.model_dump() | {"path": str(file.path), "resumed_from": file.resumed_from}
                out.line("file", **fields, skipped=file.skipped)
            else:
                print(file.path)


def register(app: typer.Typer) -> None:
    for name, command in (
        ("submit", submit_command),
        ("jobs", jobs_command),
        ("show", show_command),
        ("watch", watch_command),
        ("cancel", cancel_command),
        ("download", download_command),
    ):
        app.command(name)(command)
