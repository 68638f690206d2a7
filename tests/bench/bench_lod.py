"""`lod` on three assets (issue 7, "What to report"), each trained as a job at the `default` preset.

Assets: `dense_foliage`'s tree (unstructured, thin leaves), a level-4 Menger sponge (fractal, dense and
correlated), `thin_walls`'s rooms (structured, thin walls) and a dark closed blob (closed, smooth, small
throughputs: where the log appearance output once trained to black). Per LoD: FLIP against path tracing the
full geometry at the resolution where a voxel is about a pixel (mean over pixels that see the asset),
with and without light sampling from voxels; render time at LoD 0's resolution and equal spp, the
speed-up over LoD 0 and over path tracing; mean path length against brute-force path tracing
(Fig. 15); occupancy. Per asset: storage of networks + grid against the asset's mesh, training time per
network, threshold accuracy gain. Then the light-leak test: the sealed `closed_box` seen from inside at
every LoD, with optimal and with fixed 0.5 thresholds (Fig. 10): the correct image is black, so its mean
radiance is the leaked energy; with the default visibility table and with a colliding 2^8 one. Last, the
linear against the log appearance output on the level-3 Menger sponge and closed blobs (reduced preset).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tests.bench.common import BenchSection
from tests.support.jobs import run_kind_job
from workers.models.lod import artifact
from workers.models.lod.evaluate import lod_tracer, timed_render
from workers.render.render import RenderSettings
from workers.scene.format.spec import (
    Camera,
    ConstantBackground,
    Diffuse,
    Material,
    Plastic,
    ProceduralShape,
    SceneObject,
    SceneSpec,
)
from workers.scene.generators.builtin import get_builtin, sun_and_sky
from workers.scene.geometry.compile import compile_scene

LEAK_SPP = 16
LEAK_SIZE = 48
# The default table and a colliding one: hash collisions are what optimal thresholds repair (Fig. 9, 10).
LEAK_TABLES = (("2^17", {}), ("2^8", {"visibility": {"grid": {"log2_table_size": 8}}}))


def menger_level_4():
    scene = get_builtin("menger_sponge")
    sponge = scene.objects[-1]
    shape = ProceduralShape(generator="menger_sponge", params={**sponge.shape.params, "level": 4})
    objects = [*scene.objects[:-1], sponge.model_copy(update={"shape": shape})]
    return scene.model_copy(update={"objects": objects})


def closed_blob(material: Material) -> SceneSpec:
    """Like the scanned asset of issue 12: a closed, smooth 56k-triangle mesh (a noise-displaced sphere)
    under a sun and a constant sky."""
    lights, _ = sun_and_sky(45.0, 120.0)
    shape = ProceduralShape(
        generator="displaced_sphere", params={"seed": 2, "resolution": 167, "amplitude": 0.15, "octaves": 3}
    )
    return SceneSpec(
        name="closed_blob",
        materials={"blob": material},
        objects=[SceneObject(name="blob", shape=shape, material="blob")],
        lights=lights,
        environment=ConstantBackground(radiance=(0.6, 0.6, 0.6)),
        camera=Camera(position=(0.0, 1.2, 4.0), target=(0.0, 0.0, 0.0), fov=40.0, width=256, height=256),
    )


def grey_blob(albedo: float):
    return lambda: closed_blob(Diffuse(reflectance=(albedo, albedo, albedo)))


ASSETS = (
    ("dense_foliage", lambda: get_builtin("dense_foliage"), None),
    ("menger_sponge L4", menger_level_4, None),
    ("thin_walls", lambda: get_builtin("thin_walls"), None),
    ("dark closed blob", grey_blob(0.15), None),  # throughput targets ~0.012, 0 for half of them
)
# The measurement behind `LodConfig.appearance_output`'s comment: the default preset at 32^3 to 8^3, 500
# steps, 64 threshold samples, 16 spp against 256.
OUTPUT_ASSETS = (
    ("Menger L3", lambda: get_builtin("menger_sponge")),
    ("blob 0.5", grey_blob(0.5)),
    ("blob 0.15", grey_blob(0.15)),
    ("blob 0.03", grey_blob(0.03)),
    ("blob glossy", lambda: closed_blob(Plastic(diffuse=(0.55, 0.3, 0.2), roughness=0.15))),
)
OUTPUT_OVERRIDES = {
    "finest_resolution": 32,
    "train": {"steps": 500, "schedule": {"lr": 0.005}, "checkpoint_every": 250, "progress_every": 50},
    "threshold_samples": 64,
    "evaluation_spp": 16,
    "reference_spp": 256,
    "evaluation_max_height": 96,
}


def run_lod_job(scene, folder: Path, overrides: dict | None = None) -> tuple[dict, dict]:
    _, outcome = run_kind_job("lod", scene, folder, {"samplers": 0, **(overrides or {})}, preset="default")
    if outcome.state != "succeeded":
        raise RuntimeError(outcome.error)
    return json.loads((folder / "out" / "report.json").read_text()), outcome.metrics


def run() -> Iterator[BenchSection]:
    """The leak test, then one section per asset, each as soon as it is measured (the whole run takes
    tens of minutes)."""
    yield leak_section()
    for name, make_scene, overrides in ASSETS:
        yield asset_section(name, make_scene(), overrides)
    yield appearance_output_section()


def asset_section(name: str, scene, overrides: dict | None) -> BenchSection:
    section = BenchSection(
        f"lod on {name}: per LoD, FLIP at voxel ~ pixel, time at LoD 0's size and equal spp"
    )
    with tempfile.TemporaryDirectory() as folder:
        report, _ = run_lod_job(scene, Path(folder), overrides)
    m = report["method_metrics"]
    levels = sorted({int(k.split(".")[0][3:]) for k in m if k.startswith("lod")})
    for level in levels:
        f = {k.split(".", 1)[1]: v for k, v in m.items() if k.startswith(f"lod{level}.")}
        section.add(
            lod=level,
            voxels=f"{int(f['resolution'])}^3",
            image=f"{int(f['width'])}x{int(f['height'])}",
            occupancy=f["occupancy"],
            flip=f["flip"],
            flip_no_nee=f["flip_without_light_sampling"],
            seconds=f["seconds"],
            speedup_vs_lod0=f["speedup_over_lod0"],
            speedup_vs_pt=f["path_tracing_seconds"] / f["seconds"],
            path_length=f["mean_path_length"],
            pt_path_length=f["path_tracing_mean_path_length"],
        )
    section.notes += [
        f"storage: networks {m['network_bytes'] / 1e6:.2f} MB + grid {m['grid_bytes'] / 1e6:.2f} MB against "
        f"the mesh's {m['asset_mesh_bytes'] / 1e6:.2f} MB: saving {m['storage_saving']:.1%} "
        "(target >= 70% on the dense assets)",
        f"training {report['training_seconds']:.0f} s in all; per network (forward + backward x steps): "
        f"visibility {m['training_seconds_visibility']:.0f} s, "
        f"appearance {m['training_seconds_appearance']:.0f} s; "
        f"optimal thresholds raise the visibility accuracy by {m['threshold_accuracy_gain']:.3f}",
        "flip: with light sampling from voxels (MIS, beyond the paper); flip_no_nee: the paper's estimator, "
        "which never reaches delta lights (the sun) from a voxel. Targets: FLIP within the paper's 0.03-0.2; "
        "coarsest LoD >= 3x faster than LoD 0",
    ]
    return section


def appearance_output_section() -> BenchSection:
    """The paper learns phi directly; its reference code learns it in log space. Both on a bright fractal
    and on closed blobs from grey to nearly black."""
    section = BenchSection("appearance output: linear phi against exp(output)")
    for name, make_scene in OUTPUT_ASSETS:
        for output in ("linear", "log"):
            with tempfile.TemporaryDirectory() as folder:
                overrides = {**OUTPUT_OVERRIDES, "appearance_output": output}
                report, _ = run_lod_job(make_scene(), Path(folder), overrides)
            m = report["method_metrics"]
            levels = sorted({int(k.split(".")[0][3:]) for k in m if k.startswith("lod")})
            section.add(
                asset=name,
                output=output,
                **{f"flip_lod{level}": m[f"lod{level}.flip"] for level in levels},
                lod0_relative_mse=report["model"]["error"]["relative_mse"],
            )
    return section


def leak_section() -> BenchSection:
    section = BenchSection("closed_box light leaks: mean radiance seen inside (truth 0)")
    scene = get_builtin("closed_box")
    compiled = compile_scene(scene)
    settings = RenderSettings(spp=LEAK_SPP, width=LEAK_SIZE, height=LEAK_SIZE, max_depth=64)
    camera = np.asarray(scene.camera.position)
    for table, overrides in LEAK_TABLES:
        with tempfile.TemporaryDirectory() as folder:
            run_lod_job(scene, Path(folder), {"objects": ["box"], **overrides})
            asset = artifact.load(Path(folder) / "out")
        for level in range(asset.grid.levels):
            grid = asset.grid.level_grid(level)
            cell = np.floor((camera - grid.lo) / grid.size).astype(int)
            if grid.occupied[tuple(cell)]:
                section.notes.append(
                    f"{table}: LoD {level} skipped, the camera lies inside an occupied voxel (the wall)"
                )
                continue
            optimal = timed_render(lod_tracer(compiled, asset, level), settings).image.mean()
            fixed = timed_render(lod_tracer(compiled, asset, level, optimal_thresholds=False), settings)
            section.add(
                visibility_table=table,
                lod=level,
                voxels=f"{asset.grid.resolutions[level]}^3",
                optimal_thresholds=float(optimal),
                fixed_threshold_05=float(fixed.image.mean()),
            )
    section.notes.append("environment radiance (6, 4, 2) as in the paper's Fig. 10; its mean is 4")
    return section


if __name__ == "__main__":
    for s in run():
        print(s.table())
