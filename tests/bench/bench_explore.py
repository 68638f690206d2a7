"""Active exploration against uniform sampling at equal training time, and the network's frame against
path tracing to the same error (issue 16, "Targets").

Per scene (`cornell_variable`, 11 dimensions; `mirror_variable`, a box moving in front of a mirror), the
same network, store and time budget are trained once per arm from the same seed: `active` (greedy chains
on loss x Adam step, progressive resolution), `uniform` (large steps only, all accepted, fixed R, the
thesis's baseline of Table 5.3) and `uniform_schedule` (uniform with active's resolution schedule, so the
chains are measured apart from the schedule). All are measured every `EVAL_EVERY` seconds of training
(evaluation excluded) at the same 8 fixed hard configurations (`HARD`: the variable that carries the
scene's hardest effect at its hard end, the sphere near a mirror finish, the box by the mirror; the others
seeded uniform draws) against `REFERENCE_SPP` references: DSSIM and MAPE. The curves are in the third
table and plotted to out/bench-explore-<scene>-<seed>.png; out/bench-explore-<scene>-<seed>-maps.png
shows the frames at the end and where in them each arm's DSSIM lies (`_error_maps`). The notes give each
arm's ratio to the uniform arms at the end of the budget and as the mean over the second half of the
curve (`late_mean`).

Each run is measured twice: its weights as they are, and the explorer's exponential average of them
(`average_decay`, about the last 50 steps; the average is what a job saves). At a constant rate
(the bench's until explore24) the weights themselves oscillate: one seed's DSSIM was 0.10 and 0.16
ten steps apart, so one snapshot's active / uniform ratio said little; the average cuts that noise
and lowered DSSIM by up to a half (0.044 to 0.025 after 120 CPU s; never more than 1% higher;
explore4 notes). The rate now decays over the budget (`DECAY`), as a job's does.
`EXPLORE_BENCH_SEEDS` (comma-separated) repeats every run with other seeds; `EXPLORE_BENCH_OVERRIDES`
(JSON) changes the config of every run; `EXPLORE_BENCH_ARMS` (JSON, name -> config changes) adds arms or
redefines them, `EXPLORE_BENCH_RUN` (comma-separated names) runs only those arms and
`EXPLORE_BENCH_SCENES` only those scenes.

Time is the training process's CPU time (`time.process_time`: rendering the patches, the chains' targets
and the Adam steps; one torch thread, patches rendered in process), not wall time: on the shared 2-core
machine wall time mostly measures the other jobs. So the runs (scenes x arms x seeds) can share
the machine, `EXPLORE_BENCH_WORKERS` processes at a time. `EXPLORE_BENCH_SECONDS` sets the budget per run.

The frame rows time the frame of the first arm's (`active`'s) averaged network (Embree G-buffers and the
network; served with RGSS's 4 points a pixel, and with `ANTIALIASING`^2 pixel centres a pixel as in every
measured frame, `evaluate`) against path tracing of the same configurations at 1 to 256 spp in the same
run, both in CPU time on one thread: the mean DSSIM over the configurations, and the CPU time path tracing
needs for the network's mean DSSIM, log-log interpolated over spp (until explore8: configuration 0 only,
wall time, path tracing on 2 threads, and the first of 1/4/16/64/256 spp at or below the network's DSSIM,
which charged a 4 x 4 frame at 0.0172 for 256 spp because 64 spp scored 0.0178).

Until explore5 the network's frames read one pixel centre per pixel, which alone costs DSSIM 0.063
against the area-averaged references: every run sat at that floor (0.068-0.071 after 60 CPU s), so error
was flat across configurations and active against uniform measured noise.
"""

from __future__ import annotations

import contextlib
import json
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from tests.bench.common import BenchSection
from workers.models.explore import KIND
from workers.models.explore.config import ExploreConfig
from workers.models.explore.evaluate import (
    ANTIALIASING,
    RGSS,
    configuration_errors,
    network_image,
    reference_images,
)
from workers.models.explore.explorer import Explorer
from workers.models.explore.network import PixelGenerator
from workers.models.explore.source import PatchSource, PatchSourceConfig
from workers.nn.metrics import dssim
from workers.nn.ssim import ssim_map
from workers.nn.tonemap import srgb_encode
from workers.render.render import RenderSettings, render
from workers.runtime.equal_time import seconds_at_error
from workers.runtime.samplers import InProcessRenders
from workers.runtime.sources import SourceSpec
from workers.runtime.training import Progress, train_phases
from workers.scene.format.variables import dimension_names
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

# EXPLORE_BENCH_SCENES (comma-separated) runs only those scenes
SCENES = tuple(os.environ.get("EXPLORE_BENCH_SCENES", "cornell_variable,mirror_variable").split(","))
# the four training runs go to this many processes at once (each measures its own CPU time)
WORKERS = int(os.environ.get("EXPLORE_BENCH_WORKERS", "2"))
SECONDS = float(os.environ.get("EXPLORE_BENCH_SECONDS", "240"))
EVAL_EVERY = SECONDS / 6
# EXPLORE_BENCH_SIZE: the side of the measured frames and their references
SIZE = int(os.environ.get("EXPLORE_BENCH_SIZE", "32"))
# mirror_variable's 1024-spp references (light the mirror reflects onto the room: caustic paths) were
# DSSIM 0.017 from 8192-spp ones, a third of the networks' error there (cornell_variable: 0.002); 8192
# spp costs ~40 CPU s per scene (explore13)
REFERENCE_SPP = int(os.environ.get("EXPLORE_BENCH_REFERENCE_SPP", "8192"))
CONFIGURATIONS = 8
SEED = 11  # of the configurations and the references
SEEDS = tuple(int(x) for x in os.environ.get("EXPLORE_BENCH_SEEDS", str(SEED)).split(","))  # of the runs
PATH_TRACING_SPP = (1, 2, 4, 8, 16, 32, 64, 128, 256)
# The hard end of each scene's hardest variable (normalised): a sphere near a mirror finish (roughness
# 0.02-0.09: sharp reflections of the room and the light), a box by the mirror (its reflection beside it)
HARD = {
    "cornell_variable": {"sphere_roughness": (0.0, 0.15)},
    "mirror_variable": {"box.z": (0.0, 0.35)},
    "mirror_room_variable": {"box.z": (0.0, 0.35)},
}
# The default preset made lighter so that minutes of training on the shared 2-core CPU are hundreds of
# steps; the rate here is the peak, decayed over the CPU budget rather than over steps (`DECAY`). The
# preset's beta 2.2 (p_s 0.9) was the bench's own until explore27 (`ExploreConfig.reuse_beta`).
OVERRIDES = {
    "mlp": {"width": 64, "depth": 3},
    "spp": 16,
    "bootstrap": 10,
    "train": {"steps": 10_000_000, "schedule": {"kind": "constant", "lr": 1e-3}, "progress_every": 5},
}


def _merged(base: dict, changes: dict) -> dict:
    return {
        **base,
        **{k: _merged(base[k], v) if isinstance(base.get(k), dict) else v for k, v in changes.items()},
    }


# EXPLORE_BENCH_OVERRIDES: a JSON object merged into OVERRIDES (e.g. '{"train_rejected": false}')
OVERRIDES = _merged(OVERRIDES, json.loads(os.environ.get("EXPLORE_BENCH_OVERRIDES", "{}")))
# Each arm's changes to OVERRIDES; ratios are taken against both uniform baselines
ARMS: dict[str, dict] = {
    "active": {"exploration": "active"},
    "uniform": {"exploration": "uniform"},
    "uniform_schedule": {"exploration": "uniform", "resolution_schedule": True},
}
ARMS.update(json.loads(os.environ.get("EXPLORE_BENCH_ARMS", "{}")))
RUN = tuple(os.environ.get("EXPLORE_BENCH_RUN", ",".join(ARMS)).split(","))
BASELINES = ("uniform", "uniform_schedule")
# The rate decays by a cosine of the CPU time spent to DECAY_FLOOR of OVERRIDES' at the end of the budget,
# as a job's decays over its steps and as its uniform baseline's over its equal-time steps
# (`EXPLORE_BENCH_DECAY=constant`: the rate stays OVERRIDES'; the bench's rule until explore24). With the
# constant rate the end points moved by up to 20% between measurements, and active/uniform on
# cornell_variable at 300 CPU s, seed 3, was 0.85 over the second half; decayed, 0.68 at the end (explore24)
DECAY = os.environ.get("EXPLORE_BENCH_DECAY", "cosine")
DECAY_FLOOR = 0.05
MAP_WHITE = 0.2  # the per-pixel DSSIM drawn white in the error maps (`_error_maps`)


def hard_configurations(scene: str, count: int, seed: int) -> np.ndarray:
    """`count` fixed scene vectors: seeded uniform draws with the scene's `HARD` dimensions in their range."""
    names = dimension_names(get_builtin(scene))
    vectors = np.random.default_rng([seed, 0x5EED]).random((count, len(names)))
    for name, (low, high) in HARD[scene].items():
        k = names.index(name)
        vectors[:, k] = low + (high - low) * vectors[:, k]
    return vectors


def late_mean(curve: list[dict], key: str) -> float:
    """The mean of `key` over the curve's measurements in the second half of the budget: the averaged
    weights' DSSIM still moves by up to 20% between measurements 50 CPU s apart (mirror_variable's
    uniform_schedule, seed 3: 0.0496 at 250 s, 0.0611 at 300 s; explore10), so one end point's ratio
    can flip the verdict (active/uniform_schedule 0.90 there, 1.13 over the second half)."""
    return float(np.mean([p[key] for p in curve if p["seconds"] >= SECONDS / 2]))


class _BudgetSpent(Exception):
    pass


def train_for(
    scene: str, arm: str, seed: int, references: list[np.ndarray], vectors: np.ndarray
) -> tuple[list[dict], dict[str, torch.Tensor], dict]:
    """Train `arm` from `seed` for SECONDS of its process's CPU time: the error curve (of the weights and of
    their average) measured every EVAL_EVERY seconds, the trained weights and the explorer's figures (runs
    in a process of its own)."""
    torch.set_num_threads(1)
    config = _arm_config(arm)
    spec = SourceSpec(PatchSource, PatchSourceConfig(SceneRef(get_builtin(scene)), config), seed)
    source = spec.build()
    tracers = [source.tracer.at(v) for v in vectors]
    torch.manual_seed(seed)
    model = PixelGenerator.of(config, source.dimensions)
    explorer = Explorer(config, source.dimensions, model, seed)
    phase = explorer.phase()
    curve: list[dict] = []
    clock = {"trained": 0.0, "since": time.process_time(), "next_eval": EVAL_EVERY}
    scales: list[float] = []  # the parameter groups' own `lr_scale`, which the decay multiplies

    def measure(steps: int) -> None:
        bounces = config.mirror_bounces
        errors = configuration_errors(model, tracers, vectors, references, source.box, bounces).means()
        mean = configuration_errors(
            explorer.average, tracers, vectors, references, source.box, bounces
        ).means()
        curve.append(
            {
                "seconds": clock["trained"],
                "steps": steps,
                **errors,
                **{f"avg_{k}": v for k, v in mean.items()},
            }
        )

    def on_progress(event: Progress) -> None:
        clock["trained"] += time.process_time() - clock["since"]
        if clock["trained"] >= clock["next_eval"] or clock["trained"] >= SECONDS:
            measure(event.step)
            clock["next_eval"] += EVAL_EVERY
        if clock["trained"] >= SECONDS:
            raise _BudgetSpent
        if DECAY == "cosine":
            if not scales:
                scales.extend(group.get("lr_scale", 1.0) for group in explorer.adam.param_groups)
            _decay_rates(explorer.adam, scales, clock["trained"] / SECONDS)
        clock["since"] = time.process_time()

    with InProcessRenders(spec) as renders, explorer.open(renders) as batches:
        measure(0)
        clock["since"] = time.process_time()
        with contextlib.suppress(_BudgetSpent):
            train_phases(model, [phase], batches, config.train, on_progress=on_progress)
    return curve, explorer.average.state_dict(), explorer.statistics()


def _decay_rates(adam: torch.optim.Optimizer, scales: list[float], spent: float) -> None:
    """Each parameter group's `lr_scale` (the factor the trainer sets its scheduled rate by, every step)
    at `scales` times a cosine of the fraction of the budget `spent`, down to DECAY_FLOOR at its end."""
    cosine = 0.5 * (1 + math.cos(math.pi * min(spent, 1.0)))
    for group, scale in zip(adam.param_groups, scales, strict=True):
        group["lr_scale"] = scale * (DECAY_FLOOR + (1 - DECAY_FLOOR) * cosine)


def run() -> list[BenchSection]:
    comparison = BenchSection("explore: active exploration against uniform sampling at equal training time")
    frames = BenchSection("explore: the network's frame against path tracing to the same DSSIM")
    curves_section = BenchSection("explore: DSSIM and MAPE at the hard configurations over training time")
    config = KIND.resolve_config("default", OVERRIDES)
    sources = {s: PatchSource(PatchSourceConfig(SceneRef(get_builtin(s)), config), SEED) for s in SCENES}
    vectors = {s: hard_configurations(s, CONFIGURATIONS, SEED) for s in SCENES}
    tracers = {s: [sources[s].tracer.at(v) for v in vectors[s]] for s in SCENES}
    references = {
        s: reference_images(tracers[s], SIZE, REFERENCE_SPP, config.max_depth, SEED + 2) for s in SCENES
    }
    runs = [(scene, arm, seed) for scene in SCENES for arm in RUN for seed in SEEDS]
    with ProcessPoolExecutor(WORKERS, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {r: pool.submit(train_for, *r, references[r[0]], vectors[r[0]]) for r in runs}
        results = {r: future.result() for r, future in futures.items()}
    baselines = [b for b in BASELINES if b in RUN]
    for scene in SCENES:
        ratios: dict[tuple[str, str, str, str], list[float]] = {}
        end, second_half = f"after {SECONDS:.0f} CPU s", f"mean over {SECONDS / 2:.0f}-{SECONDS:.0f} CPU s"
        for seed in SEEDS:
            curves = {arm: results[scene, arm, seed][0] for arm in RUN}
            for arm in RUN:
                _, _, statistics = results[scene, arm, seed]
                for point in curves[arm]:
                    curves_section.add(scene=scene, method=arm, seed=seed, **point)
                final = curves[arm][-1]
                comparison.add(
                    scene=scene, method=arm, seed=seed, seconds=round(final["seconds"], 1),
                    steps=final["steps"], dssim=final["dssim"], avg_dssim=final["avg_dssim"],
                    mape=final["mape"], avg_mape=final["avg_mape"],
                    acceptance=statistics["acceptance_rate"], rendered=statistics["patches_rendered"],
                    chain_age=statistics["mean_chain_age"],
                )  # fmt: skip
                for baseline in baselines:
                    if arm in BASELINES[BASELINES.index(baseline) :]:
                        continue  # a baseline against itself or a later one
                    for key in ("avg_dssim", "avg_mape"):
                        ratio = final[key] / curves[baseline][-1][key]
                        ratios.setdefault((arm, baseline, key, end), []).append(ratio)
                        late = late_mean(curves[arm], key) / late_mean(curves[baseline], key)
                        ratios.setdefault((arm, baseline, key, second_half), []).append(late)
            _plot(scene, seed, curves)
            models = {arm: _averaged_model(arm, sources[scene], results[scene, arm, seed][1]) for arm in RUN}
            _error_maps(
                scene, seed, models, tracers[scene], vectors[scene], references[scene], sources[scene]
            )
        for (arm, baseline, key, when), values in ratios.items():
            comparison.notes.append(
                f"{scene}: {arm}/{baseline} {key} {when} each, seeds {list(SEEDS)}: "
                + " ".join(f"{v:.3f}" for v in values)
                + f" (mean {np.mean(values):.3f})"
            )
        model = _averaged_model(RUN[0], sources[scene], results[scene, RUN[0], SEEDS[0]][1])
        rows = _frame_rows(
            scene, model, tracers[scene], vectors[scene], references[scene], sources[scene].box,
            _arm_config(RUN[0]),
        )  # fmt: skip
        for row in rows:
            frames.add(**row)
    return [comparison, frames, curves_section]


def _arm_config(arm: str) -> ExploreConfig:
    """The default preset with OVERRIDES and the arm's changes."""
    return KIND.resolve_config("default", _merged(OVERRIDES, ARMS[arm]))


def _averaged_model(arm: str, source: PatchSource, state: dict[str, torch.Tensor]) -> PixelGenerator:
    model = PixelGenerator.of(_arm_config(arm), source.dimensions)
    model.load_state_dict(state)
    return model


def _error_maps(scene, seed, models, tracers, vectors, references, source) -> None:
    """out/bench-explore-<scene>-<seed>-maps.png, a row per configuration: the reference, each arm's
    measured frame (sRGB, in `RUN`'s order), then each arm's per-pixel DSSIM, white at `MAP_WHITE`, over
    the window-centres SSIM covers (its 11-pixel window leaves out a 5-pixel border, black here)."""
    bounces = {arm: _arm_config(arm).mirror_bounces for arm in models}
    rows = []
    for tracer, v, reference in zip(tracers, vectors, references, strict=True):
        camera = tracer.scene.spec.camera
        frames = [
            network_image(model, tracer, camera, source.box, v, SIZE, SIZE, ANTIALIASING, bounces[arm])[0]
            for arm, model in models.items()
        ]
        encoded = [srgb_encode(torch.from_numpy(image)) for image in (reference, *frames)]
        maps = []
        for frame in encoded[1:]:
            error = (1 - ssim_map(encoded[0], frame).mean(-1)) / 2
            border = (SIZE - error.shape[0]) // 2
            maps.append(
                torch.nn.functional.pad(error / MAP_WHITE, (border,) * 4)[..., None].expand(-1, -1, 3)
            )
        rows.append(torch.cat([*encoded, *maps], dim=1))
    grid = (torch.cat(rows).clamp(0, 1) * 255).round().to(torch.uint8).numpy()
    scale = 4  # 32^2 frames are too small to see
    Image.fromarray(grid.repeat(scale, 0).repeat(scale, 1)).save(f"out/bench-explore-{scene}-{seed}-maps.png")


def _frame_rows(scene, model, tracers, vectors, references, box, config) -> list[dict]:
    """Per frame kind: the network's mean DSSIM over the configurations and its median CPU time a frame,
    against path tracing's (one thread each): the CPU time path tracing needs for the same mean DSSIM,
    log-log interpolated between the spp of `PATH_TRACING_SPP`."""
    traced = []
    for spp in PATH_TRACING_SPP:
        settings = RenderSettings(
            spp=spp, width=SIZE, height=SIZE, max_depth=config.max_depth, seed=SEED, threads=1
        )
        errors, times = [], []
        for tracer, reference in zip(tracers, references, strict=True):
            started = time.process_time()
            image = render(tracer, settings).image
            times.append(time.process_time() - started)
            errors.append(dssim(reference, image))
        traced.append((spp, float(np.mean(errors)), float(np.median(times))))
    rows = []
    for antialiasing in (RGSS, ANTIALIASING):  # served frames, measured frames
        errors, times = [], []
        for tracer, v, reference in zip(tracers, vectors, references, strict=True):
            for _ in range(3):
                started = time.process_time()
                image, _ = network_image(
                    model, tracer, tracer.scene.spec.camera, box, v, SIZE, SIZE, antialiasing,
                    config.mirror_bounces,
                )  # fmt: skip
                times.append(time.process_time() - started)
            errors.append(dssim(reference, image))
        network_dssim, network_seconds = float(np.mean(errors)), float(np.median(times))
        row = {
            "scene": scene, "antialiasing": str(antialiasing), "network_ms": network_seconds * 1e3,
            "network_dssim": network_dssim,
            **{f"pt{spp}_ms": seconds * 1e3 for spp, _, seconds in traced},
            **{f"pt{spp}_dssim": error for spp, error, _ in traced},
        }  # fmt: skip
        matched = seconds_at_error([t for _, _, t in traced], [e for _, e, _ in traced], network_dssim)
        reached = math.isfinite(matched)
        row["pt_ms_to_match"] = matched * 1e3 if reached else f">{PATH_TRACING_SPP[-1]} spp"
        row["speedup"] = (matched if reached else traced[-1][2]) / network_seconds
        rows.append(row)
    return rows


def _plot(scene: str, seed: int, curves: dict[str, list[dict]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for mode, curve in curves.items():
        seconds = [p["seconds"] for p in curve]
        for axis, key in zip(axes, ("dssim", "mape"), strict=True):
            line = axis.plot(seconds, [p[key] for p in curve], marker="o", label=mode)[0]
            axis.plot(
                seconds,
                [p[f"avg_{key}"] for p in curve],
                ls="--",
                color=line.get_color(),
                label=f"{mode}, averaged",
            )
    for axis, name in zip(axes, ("DSSIM", "MAPE"), strict=True):
        axis.set_xlabel("training CPU seconds")
        axis.set_ylabel(name)
        axis.set_yscale("log")  # the arms part by tens of percent at errors a tenth of the first point's
        axis.set_title(f"{scene}: {name} at {CONFIGURATIONS} configurations")
        axis.legend()
    figure.tight_layout()
    Path("out").mkdir(exist_ok=True)
    figure.savefig(f"out/bench-explore-{scene}-{seed}.png", dpi=100)
    plt.close(figure)
