"""mesogan on a mesh against the real strands it stands in for (issue 17, "On a mesh"): a furred ball
(`fur_ball`) rendered with the neural shell and path-traced with strand geometry grown on it, at several
spp, each frame's FLIP against a converged render of the strands (the whole frame and the pixels the
shell covers), median frame CPU times (one thread), CPU time to equal error, and memory (model and plane
against strand triangles); plus held-out generation quality (pyramid SWD and block error against a black
image).

The model is trained here at the preset `MESOGAN_BENCH_PRESET` (default `quick`) with `MESOGAN_BENCH_STEPS`
steps (default 200, minutes on this CPU), or read from the artifact folder `MESOGAN_ARTIFACT`. With
`MESOGAN_BENCH_ABLATION_STEPS` > 0, the thesis's ablations (no mipmapping, fixed frequencies, no
injection) and the full model are each trained that many steps at that preset and scored on the same
held-out views. Where the preset has far (coarse) views, every model's far views are also scored, and
their aliasing measured as shimmer under sub-pixel pans against path-traced strands
(`evaluate.far_view_shimmer`): the SWD cannot see it there.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

import torch

from tests.bench.common import BenchSection, median_seconds
from tests.support.jobs import run_kind_job
from workers.models.mesogan import KIND, artifact
from workers.models.mesogan.aggregate import ShellAggregate
from workers.models.mesogan.covering import build_shell, covering, neural_material, with_strands
from workers.models.mesogan.evaluate import (
    SHIMMER_SPP,
    far_view_pans,
    generated_pans,
    generation_scores,
    held_out_views,
    real_pans,
    shimmer_figures,
    structure_response,
)
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.run import TRIANGLE_BYTES, covered_pixels
from workers.models.mesogan.sampling import SlabSource, SlabSourceConfig, cone_radius
from workers.models.mesogan.train import phases
from workers.nn.metrics import flip
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.equal_time import seconds_at_error
from workers.runtime.samplers import open_batches
from workers.runtime.sources import SourceSpec
from workers.runtime.training import train_phases
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene

SIZE = 32
SPPS = (1, 2, 4, 8, 16, 64)
REFERENCE_SPP = 256
SEED = 5
PRESET = os.environ.get("MESOGAN_BENCH_PRESET", "quick")


def trained_artifact() -> Path:
    if folder := os.environ.get("MESOGAN_ARTIFACT"):
        return Path(folder)
    steps = int(os.environ.get("MESOGAN_BENCH_STEPS", "200"))
    folder = Path(tempfile.mkdtemp(prefix="bench-mesogan-"))
    overrides = {"train": {"steps": steps}}
    _, outcome = run_kind_job("mesogan", get_builtin("fur_ball"), folder, overrides, preset=PRESET, seed=SEED)
    assert outcome.state == "succeeded", outcome.error
    return folder / "out"


def run() -> list[BenchSection]:
    torch.set_num_threads(1)
    config, model = artifact.load(trained_artifact())
    spec = get_builtin("fur_ball")
    scene = compile_scene(spec)
    cover = covering(scene, config.surfaces, config.shell_height, config.texel)
    shell = build_shell(scene, cover, config.shell_height)
    strands = with_strands(scene, cover, config, config.structure, config.appearance, SEED)
    settings = RenderSettings(
        spp=1, width=SIZE, height=SIZE, max_depth=config.max_depth, seed=SEED, threads=1
    )
    strand_tracer = PathTracer(strands)
    converged = settings.model_copy(update={"spp": REFERENCE_SPP, "seed": SEED + 2})
    reference = render(strand_tracer, converged).image
    material = neural_material(model, config, cover, config.structure, config.appearance, SEED)
    cone = cone_radius(spec.camera.fov, SIZE)
    shell_tracer = PathTracer(scene, aggregate=ShellAggregate(shell, material, config.samples_per_ray, cone))
    mask = covered_pixels(shell, spec.camera, SIZE)

    curve = BenchSection(
        f"mesogan shell vs path-traced strands, fur_ball {SIZE}^2 (reference {REFERENCE_SPP} spp)"
    )
    best: dict[str, tuple[float, float]] = {}
    for spp in SPPS:
        at = settings.model_copy(update={"spp": spp})
        for name, tracer in (("shell", shell_tracer), ("strands", strand_tracer)):
            image = render(tracer, at).image
            seconds = median_seconds(
                lambda tracer=tracer, at=at: render(tracer, at), repeats=3, warmup=0, clock=time.process_time
            )
            error, covered = flip(reference, image), flip(reference, image, mask=mask)
            curve.add(method=name, spp=spp, cpu_seconds=seconds, flip=error, flip_covered=covered)
            if name not in best or covered < best[name][1]:
                best[name] = (seconds, covered)
    strand_rows = [r for r in curve.rows if r["method"] == "strands"]

    def strand_seconds_at(error: float) -> float:
        """The strands' CPU seconds at covered FLIP `error`, log-log along their rows."""
        return seconds_at_error(
            [r["cpu_seconds"] for r in strand_rows], [r["flip_covered"] for r in strand_rows], error
        )

    for row in curve.rows:
        if row["method"] == "shell":
            seconds = strand_seconds_at(row["flip_covered"])
            row["strands_cpu_at_equal_flip"] = seconds
            row["strands_over_shell_cpu"] = seconds / row["cpu_seconds"]
    shell_seconds, shell_error = best["shell"]
    reach = strand_seconds_at(shell_error)
    if math.isfinite(reach):
        curve.notes.append(
            f"strands reach the shell's best covered-pixel FLIP ({shell_error:.3f}) in {reach:.3g} CPU s: "
            f"{reach / shell_seconds:.2f}x the shell's CPU time at that FLIP"
        )
    else:
        curve.notes.append(
            f"the shell's best covered-pixel FLIP ({shell_error:.3f}) is below the strands' at every spp"
        )
    curve.notes.append(
        "strands_cpu_at_equal_flip: the strands' CPU seconds at the shell row's covered FLIP, log-log "
        "interpolated along their curve (their 1-spp time where the shell is worse than that; inf where "
        "the strands never get as low); strands_over_shell_cpu > 1 is where the shell wins"
    )

    memory = BenchSection("mesogan memory: model + generated plane against strand geometry")
    model_bytes = artifact.shipped_bytes(model)
    plane_bytes = sum(level.numel() * 2 for level in material.stack)
    triangles = strands.num_triangles - scene.num_triangles
    memory.add(
        model_bytes=model_bytes,
        plane_bytes=plane_bytes,
        strand_triangles=triangles,
        strand_bytes=triangles * TRIANGLE_BYTES,
        ratio=triangles * TRIANGLE_BYTES / (model_bytes + plane_bytes),
    )

    quality = BenchSection("mesogan generation on 16 held-out path-traced slab views")
    source = SlabSource(SlabSourceConfig(mesogan=config), SEED)
    held_out = held_out_views(source, 16)
    far = held_out_views(source, 16, coarse=True) if config.coarse_distances else None
    aliasing = BenchSection(
        "mesogan aliasing at distance: 16 held-out far views panned by k/8 of a pixel (k < 8), RMS of each "
        "pixel's standard deviation over the pans (shimmer) and over a view's pixels (contrast), "
        f"tonemapped; path-traced strands at {SHIMMER_SPP} spp, their noise taken out"
    )
    models = {"trained": model}
    if steps := int(os.environ.get("MESOGAN_BENCH_ABLATION_STEPS", "0")):
        models |= {f"{name}, {steps} steps": ablation(name, o, steps) for name, o in ABLATIONS.items()}
    if far is not None:
        panned = far_view_pans(source, 16)
        real, noise_variance = real_pans(config, panned, SHIMMER_SPP)
        aliasing.add(model="path-traced strands", **shimmer_figures(real, noise_variance))
        aliasing.notes.append(f"the truth's Monte Carlo noise, taken out: {noise_variance**0.5:.4f}")
    for name, scored in models.items():
        quality.add(model=name, **generation_scores(scored, held_out))
        if far is not None:  # the far views, whose pixels read the coarse mip levels (Sec. 6.2.7)
            quality.add(model=f"{name}, far views only", **generation_scores(scored, far))
            aliasing.add(model=name, **shimmer_figures(generated_pans(scored, panned)))
    conditioning = BenchSection(
        "mesogan conditioning on 16 held-out views: coverage at the lowest / highest density and curliness "
        "labels, height where rays stop at the shortest / longest length label, generated and of real "
        "strands (_real)"
    )
    conditioning.add(model="trained", **structure_response(model, source, 16))
    return [curve, memory, quality, *([aliasing] if far is not None else []), conditioning]


ABLATIONS = {
    "full": {},
    "no mipmapping": {"mipmapping": False},
    "fixed frequencies": {"redraw_frequencies": False},
    "no injection": {"inject": False},
}


def ablation(name: str, overrides: dict, steps: int) -> MesoGAN:
    config = KIND.resolve_config(PRESET, {**overrides, "train": {"steps": steps}})
    spec = SourceSpec(SlabSource, SlabSourceConfig(mesogan=config), SEED)
    torch.manual_seed(SEED)
    model = MesoGAN(config)
    with open_batches(spec, 0) as batches:
        train_phases(model, phases(model), batches, config.train)
    return model.eval()
