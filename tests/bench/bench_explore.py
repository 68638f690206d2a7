"""Active exploration against uniform sampling at equal wall-clock time, and the network's frame against
path tracing to the same error (issue 16, "Targets").

Per scene (`cornell_variable`, 11 dimensions; `mirror_variable`, a box moving in front of a mirror), the
same network, store and time budget are trained twice from the same seed: `active` (greedy chains on
loss x Adam step, progressive resolution) and `uniform` (large steps only, all accepted, fixed R,
Table 5.3). Every `EVAL_EVERY` seconds of training (evaluation time excluded) both are measured at the
same 8 fixed configurations (the middle of every range and 7 seeded draws) against `REFERENCE_SPP`
references: DSSIM and MAPE. The curves are plotted to out/bench-explore-<scene>.png.

The frame row times the active network's frame (Embree G-buffers and the network) against path tracing
of the same configuration at 1 to 256 spp in the same run, and reports the spp path tracing needs to reach
the network's DSSIM and the ratio of the two times. `EXPLORE_BENCH_SECONDS` sets the budget per run.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from tests.bench.common import BenchSection
from workers.models.explore import KIND
from workers.models.explore.evaluate import (
    configuration_errors,
    configurations,
    network_image,
    reference_images,
)
from workers.models.explore.explorer import Explorer
from workers.models.explore.network import PixelGenerator
from workers.models.explore.source import PatchSource, PatchSourceConfig
from workers.nn.metrics import dssim
from workers.render.render import RenderSettings, render
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import InProcessRenders
from workers.runtime.sources import SourceSpec
from workers.runtime.training import Phase, TrainConfig, train_phases
from workers.scene.builtin import get_builtin
from workers.scene.reference import SceneRef

SCENES = ("cornell_variable", "mirror_variable")
SECONDS = float(os.environ.get("EXPLORE_BENCH_SECONDS", "240"))
EVAL_EVERY = SECONDS / 6
SIZE = 32
REFERENCE_SPP = int(os.environ.get("EXPLORE_BENCH_REFERENCE_SPP", "1024"))
CONFIGURATIONS = 8
SEED = 11
PATH_TRACING_SPP = (1, 4, 16, 64, 256)
CHUNK_STEPS = 10
# The default preset made lighter so that minutes of training on the shared 2-core CPU are hundreds of
# steps; a constant rate, since a run is cut by time, not by a step count a decay could end at.
OVERRIDES = {
    "mlp": {"width": 64, "depth": 3},
    "spp": 16,
    "bootstrap": 10,
    "train": {"schedule": {"kind": "constant", "lr": 1e-3}},
}


def train_for(
    scene: str, mode: str, references, tracers, vectors, box
) -> tuple[list[dict], PixelGenerator, dict]:
    """Train `mode` for SECONDS of training time; the error curve measured every EVAL_EVERY seconds."""
    config = KIND.resolve_config("default", {**OVERRIDES, "exploration": mode})
    spec = SourceSpec(PatchSource, PatchSourceConfig(SceneRef(get_builtin(scene)), config), SEED)
    torch.manual_seed(SEED)
    dimensions = spec.build().dimensions
    model = PixelGenerator(dimensions, config.mlp)
    explorer = Explorer(config, dimensions, model, SEED)
    phase = Phase("main", explorer.loss, on_optimizer=explorer.attach)
    curve, trained_seconds, steps, next_eval = [], 0.0, 0, 0.0
    with (
        tempfile.TemporaryDirectory(prefix="bench-explore-") as folder,
        InProcessRenders(spec) as renders,
        explorer.open(renders) as batches,
    ):
        store = CheckpointStore(folder)
        while trained_seconds < SECONDS:
            if trained_seconds >= next_eval:
                errors = configuration_errors(model, tracers, vectors, references, box).means()
                curve.append({"seconds": trained_seconds, "steps": steps, **errors})
                next_eval += EVAL_EVERY
            steps += CHUNK_STEPS
            started = time.perf_counter()
            _train_chunk(model, phase, batches, config.train, steps, store)
            trained_seconds += time.perf_counter() - started
    errors = configuration_errors(model, tracers, vectors, references, box).means()
    curve.append({"seconds": trained_seconds, "steps": steps, **errors})
    return curve, model, explorer.statistics()


def _train_chunk(model, phase, batches, train: TrainConfig, steps: int, store: CheckpointStore) -> None:
    """Continue training to `steps`: the loop resumes from the chunk before's checkpoint (Adam included)."""
    chunk = train.model_copy(update={"steps": steps, "checkpoint_every": CHUNK_STEPS})
    train_phases(model, [phase], batches, chunk, store)


def run() -> list[BenchSection]:
    comparison = BenchSection("explore: active exploration against uniform sampling at equal training time")
    frames = BenchSection("explore: the network's frame against path tracing to the same DSSIM")
    for scene in SCENES:
        config = KIND.resolve_config("default", OVERRIDES)
        source = PatchSource(PatchSourceConfig(SceneRef(get_builtin(scene)), config), SEED)
        vectors = configurations(source.dimensions, CONFIGURATIONS, SEED)
        tracers = [source.tracer.at(v) for v in vectors]
        references = reference_images(tracers, SIZE, REFERENCE_SPP, config.max_depth, SEED + 2)
        curves, models = {}, {}
        for mode in ("active", "uniform"):
            curves[mode], models[mode], statistics = train_for(
                scene, mode, references, tracers, vectors, source.box
            )
            final = curves[mode][-1]
            comparison.add(
                scene=scene, method=mode, seconds=round(final["seconds"], 1), steps=final["steps"],
                dssim=final["dssim"], mape=final["mape"],
                acceptance=statistics["acceptance_rate"], rendered=statistics["patches_rendered"],
            )  # fmt: skip
        active, uniform = curves["active"][-1], curves["uniform"][-1]
        comparison.notes.append(
            f"{scene}: active/uniform DSSIM {active['dssim'] / uniform['dssim']:.3f}, "
            f"MAPE {active['mape'] / uniform['mape']:.3f} after {SECONDS:.0f} s each"
        )
        _plot(scene, curves)
        frames.add(
            **_frame_row(scene, models["active"], tracers[0], vectors[0], references[0], source.box, config)
        )
    return [comparison, frames]


def _frame_row(scene, model, tracer, v, reference, box, config) -> dict:
    timings = []
    for _ in range(5):
        image, seconds = network_image(model, tracer, tracer.scene.spec.camera, box, v, SIZE, SIZE)
        timings.append(seconds)
    network_seconds, network_dssim = float(np.median(timings)), dssim(reference, image)
    row = {"scene": scene, "network_ms": network_seconds * 1e3, "network_dssim": network_dssim}
    matched = None
    for spp in PATH_TRACING_SPP:
        settings = RenderSettings(
            spp=spp, width=SIZE, height=SIZE, max_depth=config.max_depth, seed=SEED, threads=2
        )
        result = render(tracer, settings)
        error = dssim(reference, result.image)
        row[f"pt{spp}_ms"], row[f"pt{spp}_dssim"] = result.seconds * 1e3, error
        if matched is None and error <= network_dssim:
            matched = (spp, result.seconds)
    if matched is not None:
        row["pt_spp_to_match"], row["speedup"] = matched[0], matched[1] / network_seconds
    else:
        row["pt_spp_to_match"], row["speedup"] = (
            f">{PATH_TRACING_SPP[-1]}",
            row[f"pt{PATH_TRACING_SPP[-1]}_ms"] / (network_seconds * 1e3),
        )
    return row


def _plot(scene: str, curves: dict[str, list[dict]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for mode, curve in curves.items():
        seconds = [p["seconds"] for p in curve]
        axes[0].plot(seconds, [p["dssim"] for p in curve], marker="o", label=mode)
        axes[1].plot(seconds, [p["mape"] for p in curve], marker="o", label=mode)
    for axis, name in zip(axes, ("DSSIM", "MAPE"), strict=True):
        axis.set_xlabel("training seconds")
        axis.set_ylabel(name)
        axis.set_title(f"{scene}: {name} at {CONFIGURATIONS} configurations")
        axis.legend()
    figure.tight_layout()
    Path("out").mkdir(exist_ok=True)
    figure.savefig(f"out/bench-explore-{scene}.png", dpi=100)
    plt.close(figure)
