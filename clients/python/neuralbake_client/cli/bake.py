"""`nbake bake PIPELINE.yaml` and `nbake diff LOCK_A LOCK_B`: a whole asset library baked as one build,
gated on quality, and what changed between two builds.

Exit statuses of `bake` (a CI job branches on them): 0 every item passed its gates; 1 a job failed, was
cancelled or was refused; 2 the pipeline file or an option is wrong; 4 the server is unreachable or the
token refused; 5 a gate failed (and nothing worse); 6 the build's timeout came first.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from neuralbake_client.cli.output import Output
from neuralbake_client.cli.remote import (
    FAILED,
    GATES_FAILED,
    SUCCEEDED,
    TIMED_OUT,
    USAGE,
    JsonOption,
    TokenOption,
    UrlOption,
    connect,
    exit_with,
    remote_errors,
)

if TYPE_CHECKING:
    from neuralbake_client.bake import BuildResult, ItemResult


def exit_status(result: BuildResult) -> int:
    """The worst outcome of the build's items, as an exit status."""
    if any(result.count(outcome) for outcome in ("failed", "cancelled", "refused")):
        return FAILED
    if result.count("timed_out"):
        return TIMED_OUT
    return GATES_FAILED if result.count("gates_failed") else SUCCEEDED


def _line(item: ItemResult) -> str:
    how = "from the lock" if item.reused and not item.submitted else "reused" if item.reused else "trained"
    failed = [
        f"{gate.gate} ({gate.value:.4g})" for gate in item.gates if not gate.passed and gate.value is not None
    ]
    missing = [gate.note for gate in item.gates if not gate.passed and gate.value is None]
    detail = "; ".join(failed + missing) or item.error or ""
    return f"{item.outcome:<12} {item.name}  [{how}]  {detail}".rstrip()


def bake_command(
    pipeline_file: Annotated[Path, typer.Argument(help="The pipeline (YAML): assets, kinds, gates.")],
    lock: Annotated[
        Path | None,
        typer.Option(
            help="The previous build's lock, rewritten when this build passes. Default: "
            "PIPELINE.lock.json beside the pipeline."
        ),
    ] = None,
    summary: Annotated[Path | None, typer.Option(help="Write the build's summary (JSON) here.")] = None,
    junit: Annotated[Path | None, typer.Option(help="Write a JUnit XML report here.")] = None,
    timeout: Annotated[
        str | None, typer.Option(help="The build's timeout (e.g. 30m); overrides the file's.")
    ] = None,
    concurrency: Annotated[int | None, typer.Option(min=1, max=256, help="Jobs in flight at once.")] = None,
    refresh: Annotated[
        bool, typer.Option("--refresh", help="Submit every item, even those the lock has unchanged.")
    ] = False,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Bake every asset of a pipeline into its kinds, check each model against its gates, write a summary,
    a JUnit report and a lock. Exit 0 passed, 1 a job failed, 5 a gate failed, 6 timed out."""
    from neuralbake_client.bake import Baker
    from neuralbake_client.build_lock import BuildLock
    from neuralbake_client.durations import seconds
    from neuralbake_client.junit import junit_xml
    from neuralbake_client.pipeline import PipelineError, load_pipeline

    out = Output(json_lines)
    lock_path = lock or pipeline_file.with_name(pipeline_file.stem + ".lock.json")
    try:
        pipeline = load_pipeline(pipeline_file)
        overrides = {"timeout": seconds(timeout)} if timeout else {}
        pipeline = pipeline.model_copy(
            update=overrides | ({"concurrency": concurrency} if concurrency else {})
        )
        previous = BuildLock.read(lock_path)
    except (PipelineError, ValueError) as error:
        exit_with(USAGE, f"error: {error}")
    with remote_errors(), connect(url, token) as client:
        try:
            baker = Baker(client, pipeline, pipeline_file.parent, previous, refresh=refresh)
        except PipelineError as error:
            exit_with(USAGE, f"error: {error}")
        if out.json:
            baker.on_update = lambda item: out.line("item", **item.model_dump(mode="json"))
            result = baker.run()
        else:
            columns = (
                TextColumn("bake"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[counts]}"),
                TimeElapsedColumn(),
            )
            with Progress(*columns, console=out.console) as bar:
                task, running = bar.add_task("bake", total=len(baker.items), counts=""), set()

                def update(item: ItemResult) -> None:
                    if item.done:
                        running.discard(item.name)
                        bar.console.print(_line(item), highlight=False)
                        bar.advance(task)
                    else:
                        running.add(item.name)
                    bar.update(task, counts=f"{len(running)} in flight")

                baker.on_update = update
                result = baker.run()
    status = exit_status(result)
    for report in (summary, junit):
        if report is not None:
            report.parent.mkdir(parents=True, exist_ok=True)
    if summary:
        body = result.model_dump(mode="json", exclude={"lock"}) | {
            "exit_status": status,
            "lock": str(lock_path),
        }
        summary.write_text(json.dumps(body, indent=2) + "\n")
    if junit:
        junit.write_bytes(junit_xml(result, pipeline_file.stem))
    if status == SUCCEEDED:
        result.lock.write(lock_path)
    counts = {
        o: result.count(o) for o in ("passed", "gates_failed", "failed", "cancelled", "refused", "timed_out")
    }
    if out.json:
        out.line(
            "build",
            exit_status=status,
            seconds=round(result.seconds, 3),
            submitted=result.submitted,
            **counts,
        )
    else:
        listed = ", ".join(f"{n} {o.replace('_', ' ')}" for o, n in counts.items() if n)
        print(f"{len(result.items)} items: {listed}; {result.submitted} submitted; {result.seconds:.1f} s")
    raise typer.Exit(status)


def diff_command(
    before: Annotated[Path, typer.Argument(help="The earlier build's lock.")],
    after: Annotated[Path, typer.Argument(help="The later build's lock.")],
    changed_only: Annotated[
        bool, typer.Option("--changed", help="Leave out items that did not change.")
    ] = False,
    json_lines: JsonOption = False,
) -> None:
    """What changed between two builds: per asset and kind, the artifacts and their metrics side by side."""
    from neuralbake_client.build_lock import BuildLock, diff_locks

    try:
        changes = diff_locks(BuildLock.read(before), BuildLock.read(after))
    except ValueError as error:
        exit_with(USAGE, f"error: {error}")
    changes = [c for c in changes if not (changed_only and c.change == "same")]
    out = Output(json_lines)
    if out.json:
        for change in changes:
            metrics = {m: {"before": b, "after": a} for m, b, a in change.metric_rows()}
            artifacts = {
                "before": change.before and change.before.artifact_id,
                "after": change.after and change.after.artifact_id,
            }
            out.line("diff", name=change.name, change=change.change, artifacts=artifacts, metrics=metrics)
        return
    table = Table("item", "change", "metric", "before", "after", "delta")
    for change in changes:
        rows = change.metric_rows() or [("", None, None)]
        for index, (metric, b, a) in enumerate(rows):
            delta = f"{a - b:+.4g}" if a is not None and b is not None else ""
            table.add_row(
                change.name if index == 0 else "",
                change.change if index == 0 else "",
                metric,
                "" if b is None else f"{b:.4g}",
                "" if a is None else f"{a:.4g}",
                delta,
            )
    Console().print(table)
