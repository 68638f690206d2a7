"""The docs test refuses a fenced block it would not run by accident: one without a marker, a skip
without its reason, an unknown marker or a block to run in a language it does not run."""

from __future__ import annotations

import pytest

from tests.support.doc_blocks import MarkerError, blocks
from tests.support.doc_runner import captured, commands


def write(tmp_path, text: str):
    path = tmp_path / "doc.md"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("Text\n\n```sh\nnbake jobs\n```\n", "needs a marker"),
        ("<!-- example: skip -->\n```sh\nkubectl apply\n```\n", "needs a reason"),
        ("<!-- example: maybe -->\n```sh\nnbake jobs\n```\n", "unknown marker"),
        ("<!-- example: run -->\n```yaml\nname: x\n```\n", "cannot run"),
        ("<!-- example: run -->\n```\nnbake jobs\n", "never closed"),
        ("- a list item:\n\n  ```sh\n  nbake jobs\n  ```\n", "needs a marker"),
    ],
)
def test_a_block_the_runner_cannot_classify_is_an_error(tmp_path, text, problem):
    with pytest.raises(MarkerError, match=problem):
        blocks(write(tmp_path, text))


def test_blocks_their_markers_and_commands(tmp_path):
    text = (
        "<!-- example: run -->\n```sh\nnbake submit x \\\n    --wait   # waits\n"
        "# a comment\n\nnbake jobs\n```\n"
        "<!-- example: run slow -->\n```python\nprint(1)\n```\n"
        "<!-- example: skip needs a GPU -->\n```\nanything\n```\n"
    )
    shell, script, skipped = blocks(write(tmp_path, text))
    assert (shell.action, shell.slow, shell.line) == ("run", False, 2)
    assert commands(shell.code) == ["nbake submit x --wait   # waits", "nbake jobs"]
    assert (script.language, script.slow, script.code) == ("python", True, "print(1)\n")
    assert (skipped.action, skipped.reason) == ("skip", "needs a GPU")


def test_a_block_in_a_list_item_loses_its_indent(tmp_path):
    (block,) = blocks(write(tmp_path, "- item\n  <!-- example: run -->\n  ```sh\n  nbake jobs\n  ```\n"))
    assert block.code == "nbake jobs\n"


def test_placeholders_come_from_the_json_lines_printed():
    stdout = (
        '{"event": "submitted", "job": {"id": "job-1", "artifact_id": null}}\n'
        "not json\n"
        '{"event": "result", "job": {"id": "job-1", "artifact_id": "sha256:ab"}}\n'
        '{"event": "token", "id": "tok-1", "token": "nbk_x"}\n'
    )
    assert captured(stdout) == {"JOB": "job-1", "ARTIFACT": "sha256:ab", "TOKEN_ID": "tok-1"}
