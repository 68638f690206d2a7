"""`nbake query ARTIFACT`: the kind's query on the inference service, arrays in from .npy/.npz files and
out to one .npz (e.g. `lsnif`: `-i origins.npy -i directions.npy`, out `hit`, `distance`, `normal`, ...);
`--operation` names another of the kind's operations that answer arrays (`mesogan`'s `generate`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from neuralbake_client.cli.output import Output
from neuralbake_client.cli.overrides import SetOption, parse_sets
from neuralbake_client.cli.remote import (
    USAGE,
    InferenceUrlOption,
    JsonOption,
    TokenOption,
    UrlOption,
    connect,
    exit_with,
    remote_errors,
)

ArtifactArgument = Annotated[
    str,
    typer.Argument(
        metavar="ARTIFACT", help="An artifact id (sha256:...) or its hex digest, or a job id (its artifact)."
    ),
]
InputOption = Annotated[
    list[str] | None,
    typer.Option(
        "--input",
        "-i",
        help="Input arrays: FILE.npz (every array by its name), FILE.npy (named after the file) or "
        "NAME=FILE.npy; repeat.",
    ),
]


def query_command(
    artifact: ArtifactArgument,
    output: Annotated[Path, typer.Option("--output", "-o", help="The .npz file the answer's arrays go to.")],
    input_: InputOption = None,
    set_: SetOption = None,
    operation: Annotated[
        str, typer.Option(help="The kind's operation that answers arrays, e.g. generate (mesogan).")
    ] = "query",
    json_lines: JsonOption = False,
    url: UrlOption = None,
    inference_url: InferenceUrlOption = None,
    token: TokenOption = None,
) -> None:
    """Query an artifact on the inference service: arrays in from .npy/.npz files, out to one .npz."""
    from neuralbake_client.cli.array_files import read_inputs, write_outputs

    if output.suffix != ".npz":
        exit_with(USAGE, f"error: --output: {output} must end in .npz")
    out, params, arrays = Output(json_lines), parse_sets(set_ or []), read_inputs(input_ or [])
    with remote_errors(), connect(url, token, inference_url) as client:
        answer = client.query(artifact, arrays, params, operation=operation)
    write_outputs(output, answer.arrays)
    shapes = {name: {"dtype": a.dtype.name, "shape": list(a.shape)} for name, a in answer.arrays.items()}
    if out.json:
        out.line(
            "answer",
            artifact_id=answer.artifact_id,
            kind=answer.kind,
            meta=answer.meta,
            arrays=shapes,
            output=str(output),
        )
        return
    print(f"{answer.artifact_id}  {answer.kind}  -> {output}")
    for name, shape in shapes.items():
        print(f"  {name:<12} {shape['dtype']:<8} {tuple(shape['shape'])}")
    for key, value in answer.meta.items():
        print(f"  meta.{key}: {value}")
