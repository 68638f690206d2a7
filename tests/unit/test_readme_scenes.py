"""The README's table of built-in scenes names every scene the server offers (`nbake scenes`,
`GET /v1/scenes`), in order, and no other: a scene added or renamed fails here until the table says so."""

from __future__ import annotations

import re
from pathlib import Path

from workers.scene.generators.builtin import BUILTIN_SCENES

README = Path(__file__).resolve().parents[2] / "README.md"


def test_the_readmes_scene_table_lists_every_built_in_scene():
    text = README.read_text()
    table = text[text.index("**Built-in scenes**") :].split("\n\n")[1]
    listed = re.findall(r"^\| `(\w+)` \|", table, flags=re.MULTILINE)
    assert listed == sorted(BUILTIN_SCENES), "README.md's scene table: a row per `nbake scenes`"
