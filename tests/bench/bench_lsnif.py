"""LSNIF against Embree on three assets, and its speed-against-error curve (issue 6, "What to report").

Per asset (`high_poly`'s sphere, `dense_foliage`'s leaves, `fur_patch`'s strands), one network trained
at the `default` preset (the paper's sizes; its budget, steps x batch, is far below the paper's
2000 x 2^18): held-out occlusion accuracy (all rays, and the rays that meet a voxel) and normal error,
model bytes (as stored: float16) against the paper's 4-wide BVH (`evaluate`), LSNIF rays/s against
Embree rays/s on the same rays in the same run, and the FLIP of a path-traced image whose secondary and
shadow rays use LSNIF against pure Embree at the same spp and seed (camera rays on Embree). The curve
trains `high_poly` at the paper's low (H 10, width 64) and high (H 18, width 128) quality configurations
and two table sizes, on a shorter budget (`CURVE_STEPS`) so the bench stays within minutes.
"""

from __future__ import annotations

import torch

from tests.bench.common import BenchSection
from workers.models.lsnif import KIND
from workers.models.lsnif.artifact import LsnifArtifact
from workers.models.lsnif.config import LsnifConfig
from workers.models.lsnif.evaluate import (
    bvh_bytes_estimate,
    bvh_bytes_paper_table1,
    compare_images,
    held_out,
)
from workers.models.lsnif.network import STORAGE_DTYPE, LsnifObject
from workers.models.lsnif.sampling import ObjectRaySource, ObjectSourceConfig
from workers.models.lsnif.train import lsnif_loss
from workers.render.render import RenderSettings
from workers.runtime.pipeline import round_to_storage
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import SourceSpec
from workers.runtime.training import train
from workers.runtime.view import PathTracedView
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.reference import SceneRef

CURVE_STEPS = 300
IMAGE_SIZE = 64
IMAGE_SPP = 64
HELD_OUT_RAYS = 1 << 15
ASSETS = (("high_poly", "displaced_sphere"), ("dense_foliage", "leaves"), ("fur_patch", None))
CURVE = (
    ("paper low (H 10, width 64)", {"max_points": 10, "mlp": {"width": 64}}),
    ("paper high (H 18, width 128)", {}),
    ("high, table 2^14", {"grid": {"log2_table_size": 14}}),
    ("H 6, width 32", {"max_points": 6, "mlp": {"width": 32}}),
)


def config(steps: int | None = None, overrides: dict | None = None) -> LsnifConfig:
    """The `default` preset, with `steps` training steps (default: the preset's) and size overrides."""
    train = {"train": {"steps": steps}} if steps else {}
    return KIND.resolve_config("default", {**train, **(overrides or {})})


def trained(scene, index: int, cfg: LsnifConfig) -> tuple[LsnifObject, ObjectRaySource, float]:
    source_config = ObjectSourceConfig(scene=SceneRef(scene), object_index=index, lsnif=cfg)
    source = ObjectRaySource(source_config, 0)
    torch.manual_seed(0)
    model = LsnifObject(source.prepared.grid, len(source.prepared.material_names), cfg)
    with InProcessBatches(SourceSpec(ObjectRaySource, source_config, 0)) as batches:
        result = train(model, lsnif_loss, batches, cfg.train)
        round_to_storage(model, STORAGE_DTYPE)
    return model.eval(), source, result.seconds


def run() -> list[BenchSection]:
    torch.set_num_threads(2)
    preset = config()
    budget = f"{preset.train.steps} steps x {preset.batch_size} rays"
    assets = BenchSection(f"LSNIF vs Embree per asset (default preset: {budget}, V 32, H 18, M 2^17)")
    for scene_name, object_name in ASSETS:
        scene = get_builtin(scene_name)
        compiled = compile_scene(scene)
        geometry = (
            next(o for o in compiled.objects if o.name == object_name)
            if object_name
            else max(compiled.objects, key=lambda o: o.mesh.num_triangles)
        )
        model, source, seconds = trained(scene, geometry.index, preset)
        scores = held_out(model, source.prepared, HELD_OUT_RAYS)
        bundle = LsnifArtifact(
            preset, {geometry.name: model}, {geometry.name: source.prepared.material_names}, {}
        )
        view = PathTracedView(
            compiled,
            RenderSettings(spp=IMAGE_SPP, width=IMAGE_SIZE, height=IMAGE_SIZE, threads=1),
            4 * IMAGE_SPP,
        )
        image = compare_images(view, bundle.intersector(compiled))
        bvh = bvh_bytes_estimate(geometry.mesh.num_triangles)
        bvh_table1 = bvh_bytes_paper_table1(geometry.mesh.num_triangles)
        assets.add(
            asset=f"{scene_name}/{geometry.name}",
            triangles=geometry.mesh.num_triangles,
            train_s=seconds,
            occlusion_acc=scores.occlusion_accuracy,
            acc_in_voxels=scores.occlusion_accuracy_in_voxels,
            normal_err_deg=scores.normal_error_deg,
            dist_err=scores.distance_error,
            model_MB=model.size_bytes() / 1e6,
            bvh_MB=bvh / 1e6,
            bvh_over_model=bvh / model.size_bytes(),
            bvh_table1_over_model=bvh_table1 / model.size_bytes(),
            lsnif_Mrays_s=scores.lsnif_rays_per_s / 1e6,
            embree_Mrays_s=scores.embree_rays_per_s / 1e6,
            lsnif_over_embree=scores.lsnif_rays_per_s / scores.embree_rays_per_s,
            flip=image.flip,
            flip_noise_floor=image.flip_noise_floor,
            frame_s_lsnif=image.lsnif_seconds,
            frame_s_embree=image.embree_seconds,
        )
    assets.notes += [
        "BVH: the paper's uncompressed 4-wide BVH A, triangles not counted. bvh_MB: its layout with full "
        "leaves (ceil(T/2) 128-byte leaves + ceil((leaves-1)/3) 128-byte internal nodes, a lower bound); "
        "bvh_table1: 140 bytes/triangle, what the paper's Table 1 figures imply",
        "model bytes: packed voxel bits + box + float16 feature table and MLP (the artifact's payload)",
        f"FLIP: {IMAGE_SIZE}x{IMAGE_SIZE} at {IMAGE_SPP} spp, same seed; LSNIF for secondary + shadow rays; "
        "flip_noise_floor: Embree against Embree with another seed (Monte Carlo noise alone)",
        "rays/s: the same held-out rays; LSNIF = DDA + encoder + MLP in torch on this CPU",
    ]

    curve = BenchSection(f"Speed against error on high_poly ({CURVE_STEPS} steps x {preset.batch_size} rays)")
    scene = get_builtin("high_poly")
    compiled = compile_scene(scene)
    for label, overrides in CURVE:
        model, source, _ = trained(scene, 0, config(CURVE_STEPS, overrides))
        scores = held_out(model, source.prepared, HELD_OUT_RAYS)
        curve.add(
            setting=label,
            model_MB=model.size_bytes() / 1e6,
            lsnif_Mrays_s=scores.lsnif_rays_per_s / 1e6,
            occlusion_acc=scores.occlusion_accuracy,
            acc_in_voxels=scores.occlusion_accuracy_in_voxels,
            normal_err_deg=scores.normal_error_deg,
            dist_err=scores.distance_error,
        )
    curve.notes.append(f"{compiled.num_triangles} triangles; held-out rays {HELD_OUT_RAYS}")
    return [assets, curve]


if __name__ == "__main__":
    for section in run():
        print(section.table())
