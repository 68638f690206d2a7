"""Sampler -> trainer pipeline throughput with 0 (in-process), 1 and 2 Ray sampler actors.

The source costs a few milliseconds of NumPy per batch, like a small path-traced batch; the trainer is the
real loop harness fitting a small MLP. Ratios are against producing batches in-process in the same run.
"""

from __future__ import annotations

import os
import statistics
import tempfile
from collections.abc import Callable

import ray
import torch

from tests.bench.common import BenchSection, median_seconds
from workers.runtime.samplers import BatchStream, InProcessBatches, SamplerPool
from workers.runtime.sources import AnalyticSource, AnalyticSourceConfig, SourceSpec
from workers.runtime.training import TrainConfig, train

BATCH_SIZE = 4096
STEPS = 40
ROUNDS = 5
SPEC = SourceSpec(AnalyticSource, AnalyticSourceConfig(batch_size=BATCH_SIZE, samples_per_point=48), seed=0)


def small_mlp() -> torch.nn.Module:
    return torch.nn.Sequential(
        torch.nn.Linear(3, 64),
        torch.nn.ReLU(),
        torch.nn.Linear(64, 64),
        torch.nn.ReLU(),
        torch.nn.Linear(64, 3),
    )


def mse(model: torch.nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    return torch.nn.functional.mse_loss(model(batch["inputs"]), batch["targets"])


def training_run(batches: BatchStream) -> Callable[[], object]:
    """A training run of STEPS steps fed by `batches`, restarted at batch 0."""

    def run_once() -> None:
        batches.seek(0)
        train(small_mlp(), mse, batches, TrainConfig(steps=STEPS, progress_every=STEPS))

    return run_once


def drawing_run(batches: BatchStream) -> Callable[[], object]:
    """Drawing STEPS batches with no trainer: the producers' own rate."""

    def run_once() -> None:
        batches.seek(0)
        for _ in range(STEPS):
            next(batches)

    return run_once


def interleaved_medians(runs: list[Callable[[], object]], rounds: int = ROUNDS) -> list[float]:
    """Median seconds of each run, timed round-robin so that drifting load on the machine hits all alike."""
    for run_once in runs:
        run_once()  # warm up: actors started, allocations made
    times = [[median_seconds(run_once, repeats=1, warmup=0) for run_once in runs] for _ in range(rounds)]
    return [statistics.median(column) for column in zip(*times, strict=True)]


def run() -> list[BenchSection]:
    threads = torch.get_num_threads()
    # one trainer thread: with sampler processes on the same two cores, a second OpenMP thread oversubscribes
    # them and its barriers stall the trainer; in-process gets the same single thread for a fair ratio
    torch.set_num_threads(1)
    try:
        return [pipeline_section()]
    finally:
        torch.set_num_threads(threads)


def pipeline_section() -> BenchSection:
    source = SPEC.build()
    section = BenchSection(f"sampler -> trainer pipeline (batch {BATCH_SIZE}, {STEPS} steps, MLP 3-64x2-3)")
    section.notes.append(
        f"source: {median_seconds(lambda: source.batch(1), repeats=10) * 1e3:.2f} ms of NumPy per batch; "
        f"trainer torch threads {torch.get_num_threads()}; medians of {ROUNDS} interleaved rounds; "
        "ratio = samples/s against in-process in this run"
    )
    with tempfile.TemporaryDirectory(prefix="nbake-bench-ray-", dir="/tmp") as temp_dir:
        # Ray nices its workers to 15; on a shared machine that would measure other people's load
        ray.init(
            num_cpus=2,
            include_dashboard=False,
            _temp_dir=temp_dir,
            log_to_driver=False,
            _system_config={"worker_niceness": 0},
        )
        try:
            producers = {"in-process": InProcessBatches(SPEC)}
            # half a logical CPU each: all three actors must coexist on 2 CPUs for the interleaved timing
            producers |= {
                f"{n} actor(s)": SamplerPool(SPEC, actors=n, actor_options={"num_cpus": 0.5}) for n in (1, 2)
            }
            streams = list(producers.values())
            training = interleaved_medians([training_run(s) for s in streams])
            drawing = interleaved_medians([drawing_run(s) for s in streams])
            for stream in streams:
                stream.close()
        finally:
            ray.shutdown()
    section.notes.append(f"load average over the last minute at the end: {os.getloadavg()[0]:.1f} on 2 cores")
    samples = STEPS * BATCH_SIZE
    for name, train_s, draw_s in zip(producers, training, drawing, strict=True):
        section.add(
            producer=name,
            pipeline_samples_per_s=samples / train_s,
            pipeline_ratio=training[0] / train_s,
            production_only_samples_per_s=samples / draw_s,
            production_ratio=drawing[0] / draw_s,
        )
    return section
