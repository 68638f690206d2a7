"""What a job costs besides its kind's own work, counted the same way in every kind's plan.

A quick job spends much of its time here rather than training: the scheduler handing it to a driver actor,
imports, the scene's fetch and compile, loading the compiled kernels, sampler actors starting, the
report's path tracing (its curve and reference) and writing the artifact. Plans that counted only their
training were 2-40x below what quick jobs took through `nbake serve`. Each cost is a count (processes,
triangles, bytes, path segments, images) times a per-unit cost, so it scales with the scene and config,
and a plan stays a pure function of them. The per-unit costs were measured on one core of a 2-core AMD
EPYC; `docs/results/plans.md` has the commands and figures.
"""

from __future__ import annotations

from dataclasses import dataclass

from workers.runtime.contract import PlanItem
from workers.runtime.kind_config import KindConfig, TrainedKindConfig
from workers.runtime.report import PATH_TRACING_SPP
from workers.scene.portability.reference import SceneRef

# Scheduler to the kind's first line: Ray starts the driver actor's worker process, which imports the
# driver, torch (the runtime's batch streams need it), Numba and Embree: a warm `render` job's first log
# came 3.2 s after RUNNING at load 1.5, 4-7 s at loads 5-9.
DRIVER_START_S = 3.0
# A kind that trains imports its networks and the training runtime too: in fresh interpreters, importing
# `lsnif`'s method took 1.6-1.8x `render`'s run in two of three measurements (0.9x in the third).
TRAINING_IMPORT_S = 2.0
# Loading the machine's cached Numba kernels into a process on its first render (compiling them is once
# per machine and is not counted): the first 8x8 1-spp render in a fresh process less a second, 0.4-2.2 s.
KERNEL_LOAD_S = 1.5
# A sampler actor's start: Ray placing the job's reservation and starting the actor's process, which
# imports torch and the path tracer (a quick `render` with one actor took 9-11 s more than without, at
# load 9, kernel load and compile included).
SAMPLER_START_S = 4.0
# Compiling a scene: flattening its triangles and building Embree's BVH, 4e-6 to 2.2e-5 s a triangle
# (menger_sponge's 36k, fur_patch's 96k).
SCENE_S_PER_TRIANGLE = 1.5e-5
# Fetching a scene's files into the node's cache and parsing them: fur_patch as a PLY read at 5e-8 to
# 1.1e-7 s a byte.
SCENE_S_PER_BYTE = 7e-8
# Path tracing for the report, per path segment (a bounce and its shadow ray): Embree's hits plus NumPy
# shading, 2.2-8.7 us a sample on one thread at 2.5-6 rays a sample (cornell_box, env_lit_objects,
# menger_sponge).
PATH_SEGMENT_S = 1.0e-6
# Paths end by Russian roulette or escape long before a deep `max_depth`: the segments counted a sample.
MEAN_SEGMENTS = 4
# Each image the report renders and scores (a render's set-up, FLIP and PSNR), and then writing the
# report, its plot and previews and publishing the artifact: a quick `prt` job's 7 images of 16x16 and
# report took 0.55 s from its last log to SUCCEEDED, `lsnif`'s at 32x32 2.4 s, 1.4 s of it paths.
IMAGE_S = 0.05
REPORT_S = 0.5


@dataclass(frozen=True)
class Evaluation:
    """Path tracing a job does to measure its model: `images` renders of `pixels` pixels each, `samples`
    samples a pixel over all of them, paths up to `max_depth` segments."""

    pixels: int
    samples: int
    max_depth: int
    images: int

    @property
    def segments(self) -> int:
        return self.pixels * self.samples * min(self.max_depth, MEAN_SEGMENTS)


def report_view(pixels: int, evaluation_spp: int, reference_spp: int, max_depth: int = 8) -> Evaluation:
    """The shared report's path tracing of one view (`PathTracedView`): a 1-spp warm-up, the curve's
    counts below the reference, the reference and the model's frame."""
    curve = [spp for spp in PATH_TRACING_SPP if spp < reference_spp]
    return Evaluation(pixels, 1 + sum(curve) + reference_spp + evaluation_spp, max_depth, len(curve) + 3)


@dataclass(frozen=True)
class FixedCosts:
    """The fixed costs of one job, in seconds, and what they were counted from."""

    handoff: float
    scene: float
    kernels: float
    samplers: float
    evaluation: float
    report: float
    triangles: int
    scene_bytes: int
    segments: int

    @property
    def seconds(self) -> float:
        return self.handoff + self.scene + self.kernels + self.samplers + self.evaluation + self.report

    def item(self) -> PlanItem:
        return PlanItem(
            name="fixed costs",
            choice=f"{self.seconds:.1f} s",
            reason=f"hand-off and imports {self.handoff:.1f} s, scene {self.scene:.1f} s "
            f"({self.triangles:,} triangles, {self.scene_bytes:,} bytes of files), kernel load "
            f"{self.kernels:.1f} s, sampler actors {self.samplers:.1f} s, evaluation {self.evaluation:.1f} s "
            f"({self.segments:,} path segments), report and artifact {self.report:.1f} s",
        )


def fixed_costs(scene: SceneRef, config: KindConfig, evaluation: tuple[Evaluation, ...] = ()) -> FixedCosts:
    """The fixed costs of running `config` on `scene`: `evaluation` is the path tracing its kind does to
    measure the model (`report_view` for the shared report's view, plus the kind's own)."""
    trains = isinstance(config, TrainedKindConfig)
    triangles = sum(
        count * len(obj.instances or [None])
        for obj, count in zip(scene.spec.objects, scene.object_triangles(), strict=True)
    )
    folder = scene.local_folder()
    scene_bytes = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) if folder else 0
    compile_s = triangles * SCENE_S_PER_TRIANGLE + scene_bytes * SCENE_S_PER_BYTE
    # sampler actors start side by side, each compiling the scene and loading the kernels itself, while
    # the driver waits for them all
    samplers = config.samplers > 0
    segments = sum(e.segments for e in evaluation)
    return FixedCosts(
        handoff=DRIVER_START_S + (TRAINING_IMPORT_S if trains else 0.0),
        scene=compile_s * (2 if samplers else 1),
        kernels=KERNEL_LOAD_S * (2 if samplers else 1),
        samplers=SAMPLER_START_S if samplers else 0.0,
        evaluation=segments * PATH_SEGMENT_S + sum(e.images for e in evaluation) * IMAGE_S,
        report=REPORT_S if trains else 0.0,
        triangles=triangles,
        scene_bytes=scene_bytes,
        segments=segments,
    )
