"""Running an `lsnif` job: train one network per planned object, export the artifact, measure it.

Objects train one after another in the driver, their batches generated in process; each object has its
own checkpoint folder, so a restarted job resumes the object it was training and skips finished ones.
"""

from __future__ import annotations

import json

import numpy as np
import torch

from workers.models.lsnif import artifact
from workers.models.lsnif.config import LsnifConfig
from workers.models.lsnif.evaluate import (
    bvh_bytes_estimate,
    bvh_bytes_paper_table1,
    compare_images,
    held_out,
)
from workers.models.lsnif.network import LsnifObject
from workers.models.lsnif.plan import LSNIF, choose_objects
from workers.models.lsnif.sampling import ObjectRaySource, ObjectSourceConfig
from workers.models.lsnif.train import train_object
from workers.models.registry import JobContext, RunOutput
from workers.render.image_io import write_png
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import SourceSpec
from workers.scene.compile import compile_scene

REPORT = "report.json"


def run(ctx: JobContext) -> RunOutput:
    config: LsnifConfig = ctx.config
    compiled = compile_scene(ctx.scene, ctx.scene_dir)
    chosen = [c for c in choose_objects(ctx.scene, config, ctx.scene_dir) if c.choice == LSNIF]
    scene_dir = None if ctx.scene_dir is None else str(ctx.scene_dir)
    total = config.train.steps * len(chosen)
    models, placements, per_object = {}, {}, {}
    for number, choice in enumerate(chosen):
        ctx.raise_if_cancelled()
        geometry = compiled.objects[choice.index]
        ctx.log(f"training {choice.name}: {choice.reason}")
        source_config = ObjectSourceConfig(
            scene=ctx.scene.model_dump(mode="json"),
            scene_dir=scene_dir,
            object_index=choice.index,
            lsnif=config,
        )
        source = ObjectRaySource(source_config, ctx.seed)
        torch.manual_seed(ctx.seed)
        model = LsnifObject(source.prepared.grid, len(source.prepared.material_names), config)
        done = number * config.train.steps

        def progress(p, done=done):
            ctx.raise_if_cancelled()
            ctx.progress(done + p.step, total, loss=p.loss, samples_per_s=p.samples_per_s, eta_s=p.eta_s)

        store = CheckpointStore(f"{ctx.checkpoints.root}/{choice.name}", keep=2)
        with InProcessBatches(SourceSpec(ObjectRaySource, source_config, ctx.seed)) as batches:
            result = train_object(model, batches, config.train, store, progress)
        model.eval()
        models[choice.name] = model
        placements[choice.name] = {
            "materials": source.prepared.material_names,
            "instances": [m.tolist() for m in geometry.instance_matrices],
        }
        scores = held_out(model, source.prepared, config.evaluation_rays)
        size = model.size_bytes()
        bvh = bvh_bytes_estimate(geometry.mesh.num_triangles)
        per_object[choice.name] = {
            "triangles": geometry.mesh.num_triangles,
            "instances": len(geometry.instance_matrices),
            "occupied_voxels": int(source.prepared.grid.occupied.sum()),
            "training_seconds": result.seconds,
            "final_loss": result.final_loss,
            "model_bytes": size,
            "bvh_bytes_estimate": bvh,
            "bvh_to_model": bvh / size,
            "bvh_bytes_paper_table1": bvh_bytes_paper_table1(geometry.mesh.num_triangles),
            **scores.__dict__,
        }
    files = artifact.save(ctx.output_dir, config, models, placements)
    report = {
        "kind": "lsnif",
        "plan": [c.__dict__ for c in choose_objects(ctx.scene, config, ctx.scene_dir)],
        "objects": per_object,
    }
    metrics = {}
    if models:
        loaded = artifact.load(ctx.output_dir)
        images = compare_images(
            compiled, loaded.intersector(compiled), config.preview_size, config.preview_spp
        )
        write_png(
            ctx.output_dir / "preview.png", np.concatenate([images.embree_image, images.lsnif_image], 1)
        )
        files["preview.png"] = (str(ctx.output_dir / "preview.png"), "image/png")
        report["image"] = {
            "flip": images.flip,
            "flip_noise_floor": images.flip_noise_floor,
            "size": config.preview_size,
            "spp": config.preview_spp,
            "lsnif_seconds": images.lsnif_seconds,
            "embree_seconds": images.embree_seconds,
        }
        metrics["flip"] = images.flip
        metrics["occlusion_accuracy"] = float(np.mean([o["occlusion_accuracy"] for o in per_object.values()]))
        metrics["model_bytes"] = float(sum(o["model_bytes"] for o in per_object.values()))
    metrics["networks"] = float(len(models))
    (ctx.output_dir / REPORT).write_text(json.dumps(report, indent=2, default=float))
    files[REPORT] = (str(ctx.output_dir / REPORT), "application/json")
    return RunOutput(files=files, metrics=metrics)
