"""The `lsnif` method on the shared pipeline: one network per planned object, exported and measured.

Each object trains from its own checkpoint sub-store, so a restarted job resumes the object it was
training and skips finished ones. The report's model frame path-traces the view with LSNIF for secondary
and shadow rays (camera rays on Embree, as the paper rasterises them). `method_metrics` hold each
object's figures as `<object>.<figure>`, the FLIP of LSNIF against Embree at the same spp and seed, and
that FLIP's noise floor; the preview shows Embree at the same spp between the reference and LSNIF.
"""

from __future__ import annotations

import numpy as np
import torch

from workers.models.lsnif import artifact
from workers.models.lsnif.config import LsnifConfig
from workers.models.lsnif.evaluate import bvh_bytes_estimate, bvh_bytes_paper_table1, compare_images, held_out
from workers.models.lsnif.network import STORAGE_DTYPE, LsnifObject
from workers.models.lsnif.plan import LSNIF, choose_objects
from workers.models.lsnif.sampling import ObjectRaySource, ObjectSourceConfig
from workers.models.lsnif.train import lsnif_loss
from workers.render.render import RenderSettings
from workers.runtime.contract import JobContext
from workers.runtime.pipeline import Finished, Trainable, Trained
from workers.runtime.report import TimedImage
from workers.runtime.sources import SourceSpec
from workers.runtime.training import Phase
from workers.runtime.view import PathTracedView


class LsnifMethod:
    kind = "lsnif"

    def trainables(self, ctx: JobContext[LsnifConfig]) -> list[Trainable]:
        config = ctx.config
        trainables = []
        for choice in choose_objects(ctx.scene, config):
            if choice.choice != LSNIF:
                continue
            ctx.log(f"{choice.name}: {choice.reason}")
            spec = SourceSpec(ObjectRaySource, ObjectSourceConfig(ctx.scene, choice.index, config), ctx.seed)
            prepared = spec.build().prepared
            torch.manual_seed(ctx.seed)
            model = LsnifObject(prepared.grid, len(prepared.material_names), config)
            phases = [Phase("main", lsnif_loss)]
            trainables.append(
                Trainable(model, phases, spec, config.train, name=choice.name, stored_dtype=STORAGE_DTYPE)
            )
        return trainables

    def finish(self, ctx: JobContext[LsnifConfig], trained: list[Trained]) -> Finished:
        config = ctx.config
        scene = ctx.scene.compiled()
        models, placements, method_metrics = {}, {}, {}
        for done in trained:
            name = done.trainable.name
            source: ObjectRaySource = done.trainable.source.build()
            geometry = scene.objects[source.config.object_index]
            model: LsnifObject = done.model
            models[name] = model
            placements[name] = {
                "materials": source.prepared.material_names,
                "instances": [m.tolist() for m in geometry.instance_matrices],
            }
            method_metrics.update(
                {f"{name}.{k}": float(v) for k, v in _object_figures(model, source, geometry, done).items()}
            )
        files = artifact.save(
            ctx.output_dir, config, models, placements, ctx.scene.spec, ctx.scene.local_folder()
        )

        ctx.raise_if_cancelled()
        view = PathTracedView(
            scene,
            RenderSettings(
                spp=config.evaluation_spp, width=config.preview_size, height=config.preview_size,
                seed=ctx.seed, threads=1,
            ),
            config.reference_spp,
        )  # fmt: skip
        ctx.log(f"rendering {config.preview_size}^2 with LSNIF at {config.evaluation_spp} spp")
        comparison = compare_images(view, artifact.load(ctx.output_dir).intersector(scene))
        model_bytes = sum(model.size_bytes() for model in models.values())
        method_metrics.update(
            {
                "networks": float(len(models)),
                "model_bytes": float(model_bytes),
                "flip_against_embree_same_spp": comparison.flip,
                "flip_noise_floor": comparison.flip_noise_floor,
            }
        )
        metrics = {"model_bytes": float(model_bytes), "networks": float(len(models))}
        if models:
            metrics["occlusion_accuracy"] = float(
                np.mean([method_metrics[f"{name}.occlusion_accuracy"] for name in models])
            )
        frame = TimedImage(f"{config.evaluation_spp} spp", comparison.lsnif_image, comparison.lsnif_seconds)
        return Finished(files, view, frame, method_metrics, metrics, preview=[comparison.embree_image])


def _object_figures(model: LsnifObject, source: ObjectRaySource, geometry, done: Trained) -> dict[str, float]:
    """One object's size, cost and held-out accuracy against Embree."""
    config: LsnifConfig = source.config.lsnif
    scores = held_out(model, source.prepared, config.evaluation_rays)
    size = model.size_bytes()
    bvh = bvh_bytes_estimate(geometry.mesh.num_triangles)
    return {
        "triangles": geometry.mesh.num_triangles,
        "instances": len(geometry.instance_matrices),
        "occupied_voxels": int(source.prepared.grid.occupied.sum()),
        "training_seconds": done.result.seconds,
        "final_loss": done.result.final_loss,
        "model_bytes": size,  # as stored: voxel bits, box, float16 table and MLP
        "bvh_bytes_estimate": bvh,
        "bvh_to_model": bvh / size,
        "bvh_bytes_paper_table1": bvh_bytes_paper_table1(geometry.mesh.num_triangles),
        **scores.__dict__,
    }
