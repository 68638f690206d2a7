"""Working memory of inference queries, measured against what each kind declares (`Operation.row_bytes`,
`activation_row_bytes`, `call_bytes`, `params_bytes`), which the inference service admits requests by.

For each measured kind: a query of one service chunk (`chunk_rows`) and of eight, answered in this
process after a warm-up query as the service runs it (a batched operation a chunk at a time, outputs
concatenated); the peak is the kernel's high-water mark of this process (VmHWM, reset
through /proc/self/clear_refs) over its RSS before the call, with the answer's binary encoding included.
`declared` is what the service reserves for the same rows beyond the inputs; `measured / declared` above
1 would mean the admission under-counts.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import torch

from services.inference.batching import in_chunks
from services.inference.settings import InferenceSettings
from services.inference.wire import encode_binary
from tests.bench.common import BenchSection
from tests.support.jobs import run_kind_job
from tests.unit.test_lsnif_model import instanced_scene
from workers.models.registry import QUERY, get_inference
from workers.render.heap import return_freed_memory
from workers.scene.generators.builtin import BUILTIN_SCENES, get_builtin

CHUNK = InferenceSettings.model_fields["chunk_rows"].default
WIDTH, HEIGHT = 64, 48


def _status(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"no {key}")


def _jobs() -> dict:
    sponge = get_builtin("menger_sponge")
    camera = sponge.camera.model_copy(update={"width": 32, "height": 32})
    sponge = sponge.model_copy(update={"camera": camera})
    return {
        "lsnif": (instanced_scene(), {"min_triangles": 1000, "train": {"steps": 60}}, {}),
        "lod": (sponge, {"samplers": 0, "train": {"steps": 20}}, {}),
        "render": (
            BUILTIN_SCENES["cornell_box"](),
            {"samplers": 0, "width": WIDTH, "height": HEIGHT},
            {"layers": ["image", "depth"]},
        ),
    }


def _inputs(kind: str, model, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    if kind == "render":
        return {"pixels": np.stack([rng.integers(WIDTH, size=n), rng.integers(HEIGHT, size=n)], 1)}
    if kind == "lsnif":
        centers = np.array([i.world_bounds.mean(0) for i in model.intersector.instances])
    else:
        centers = model.bounds.mean(0)[None]
    targets = centers[rng.integers(len(centers), size=n)] + rng.normal(scale=0.15, size=(n, 3))
    origins = targets + rng.normal(size=(n, 3)) * 2
    arrays = {"origins": origins, "directions": targets - origins}
    if kind == "lod":
        arrays["incident"] = rng.normal(size=(n, 3))
    return arrays


def _peak(model, params, arrays: dict[str, np.ndarray], batched: bool) -> int:
    """Bytes the answer and its encoding took at their peak over the RSS before the call."""
    rows = len(next(iter(arrays.values())))
    return_freed_memory()
    Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current RSS
    before = _status("VmRSS")
    chunk = CHUNK if batched else rows  # the service runs an unbatched query whole
    answer = in_chunks(lambda part: model.answer(QUERY, params, part), arrays, rows, chunk)
    encode_binary({"meta": answer.meta}, answer.arrays)
    return _status("VmHWM") - before


def run() -> list[BenchSection]:
    section = BenchSection(f"Inference working memory per query: measured vs declared (chunk {CHUNK} rows)")
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory(prefix="nbake-bench-memory-") as folder:
        for kind, (scene, overrides, params) in _jobs().items():
            spec, outcome = run_kind_job(kind, scene, Path(folder) / kind, overrides, seed=5)
            assert outcome.state == "succeeded", outcome.error
            inference = get_inference(kind)
            operation = inference.operations[QUERY]
            model = inference.load(Path(spec.output_dir), "cpu")
            typed = operation.params.model_validate(params)
            rng = np.random.default_rng(0)
            model.answer(QUERY, typed, _inputs(kind, model, 64, rng))  # warm: kernels, operator tables
            for rows in (CHUNK, 8 * CHUNK):
                measured = _peak(model, typed, _inputs(kind, model, rows, rng), operation.batched)
                active = min(rows, CHUNK) if operation.batched else rows
                declared = (
                    rows * operation.row_bytes
                    + active * operation.activation_row_bytes
                    + operation.call_bytes
                    + operation.params_bytes(model, typed)
                )
                section.add(
                    kind=kind,
                    rows=rows,
                    measured_mb=measured / 2**20,
                    declared_mb=declared / 2**20,
                    measured_per_declared=measured / declared,
                )
    section.notes.append(
        "declared: rows x row_bytes + the rows of one chunk x activation_row_bytes + call_bytes + "
        "params_bytes (the "
        "service also reserves the body and twice the converted inputs, which this leaves out)"
    )
    return [section]
