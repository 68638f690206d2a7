"""Every command and code block of the README, docs/ and the SDK's README runs against a real `nbake
serve` (tests/support/doc_runner.py has the conventions), so that a wrong example fails here rather than
for a user. Blocks that train for minutes are `run slow` and run with `make test-all`."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.doc_blocks import blocks
from tests.support.doc_runner import DocRun

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), ROOT / "clients/python/README.md"]
IDS = [str(doc.relative_to(ROOT)) for doc in DOCS]
TRAINING = [doc for doc in DOCS if any(block.slow for block in blocks(doc))]  # docs with `run slow` blocks


@pytest.mark.timeout(1200)  # README's: 4-5 min on a loaded 2-core machine (local renders, a server, lsnif)
@pytest.mark.parametrize("doc", DOCS, ids=IDS)
def test_the_docs_examples_run(doc, tmp_path):
    with DocRun(tmp_path / "run", ROOT) as run:
        run.run(blocks(doc), slow=False)


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("doc", TRAINING, ids=[str(doc.relative_to(ROOT)) for doc in TRAINING])
def test_the_docs_examples_run_with_the_training_ones(doc, tmp_path):
    with DocRun(tmp_path / "run", ROOT) as run:
        run.run(blocks(doc), slow=True)
