"""`make run` as a newcomer runs it: `scripts/first-run.sh` starts `nbake serve` with its inference
service, trains a quick `lod` model, renders it through the inference service from the reference's
camera, writes the comparison and the report's line, and leaves nothing running."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

REPO = Path(__file__).resolve().parents[2]


def processes_naming(text: str) -> list[str]:
    """Command lines of live processes that mention `text`."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            line = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in line:
            found.append(line)
    return found


def blocks(image: np.ndarray, size: int = 4) -> np.ndarray:
    h, w, c = image.shape
    return (
        image[: h // size * size, : w // size * size]
        .reshape(h // size, size, w // size, size, c)
        .mean((1, 3))
    )


# slow: a training job and a server start (about a minute of the default suite); the README's service
# examples cover the same commands (tests/integration/test_docs_examples.py)
@pytest.mark.slow
def test_make_run_trains_serves_and_compares_a_model_then_stops(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NBAKE_", "RAY_"))}
    done = subprocess.run(
        ["bash", "scripts/first-run.sh"],
        cwd=REPO,
        env={**env, "OUT": str(tmp_path / "run")},
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    data_dir = re.search(r"admin token: (\S+)/admin-token", done.stderr).group(1)
    assert not Path(data_dir).exists() and not processes_naming(data_dir), "make run left its server behind"

    out = tmp_path / "run"
    line = (out / "report.txt").read_text()
    assert re.match(r"lod \(LoD 0, \d+ spp\): \d+ ms a frame at FLIP 0\.\d+; path tracing", line), line
    reference = np.asarray(Image.open(out / "artifact/reference.png").convert("RGB"), dtype=np.float64)
    served = np.asarray(Image.open(out / "served.png").convert("RGB"), dtype=np.float64)
    assert served.shape == reference.shape
    # the served model shows the scene: over 4x4 blocks (its 4-spp noise averaged) it is closer to the
    # reference than the best constant image is (a black, blank or misplaced frame fails here)
    error, constant = np.abs(blocks(served) - blocks(reference)), np.abs(blocks(reference) - reference.mean())
    assert error.mean() < 0.6 * constant.mean(), (error.mean(), constant.mean())
    both = Image.open(out / "side_by_side.png")
    assert both.width == 2 * both.height
