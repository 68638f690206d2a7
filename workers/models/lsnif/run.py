"""Running an `lsnif` job: train one network per planned object, export the artifact, measure it.

Objects train one after another in the driver, their batches generated in process; each object has its
own checkpoint folder, so a restarted job resumes the object it was training and skips finished ones.

The shared report (`workers.runtime.report`) measures the frame path-traced with LSNIF for secondary and
shadow rays (camera rays on Embree) and pure Embree path tracing at several spp against a converged
Embree image of the same view (`evaluate.report_images`). Its `method_metrics` hold each object's
figures as `<object>.<figure>`, the FLIP of LSNIF against Embree at the same spp and seed, and that
FLIP's noise floor. `preview.png` shows the reference, Embree and LSNIF at the preview's spp side by side.
"""

from __future__ import annotations

import numpy as np
import torch

from workers.models.lsnif import artifact
from workers.models.lsnif.config import LsnifConfig
from workers.models.lsnif.evaluate import (
    bvh_bytes_estimate,
    bvh_bytes_paper_table1,
    held_out,
    report_images,
)
from workers.models.lsnif.network import STORAGE_DTYPE, LsnifObject
from workers.models.lsnif.plan import LSNIF, choose_objects
from workers.models.lsnif.sampling import ObjectRaySource, ObjectSourceConfig
from workers.models.lsnif.train import train_object
from workers.models.registry import JobContext, RunOutput
from workers.render.image_io import write_png
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.report import build_report
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import SourceSpec
from workers.runtime.training import TrainResult
from workers.scene.compile import compile_scene

PREVIEW = "preview.png"


def stored_weights(models: dict[str, LsnifObject]) -> torch.nn.ParameterList:
    """The feature tables and MLPs in the artifact's float16, for the report's `parameter_bytes`: the
    models hold them in float32, and their row maps are rebuilt on load, not stored."""
    return torch.nn.ParameterList(
        p.detach().to(STORAGE_DTYPE) for model in models.values() for p in model.parameters()
    )


def run(ctx: JobContext) -> RunOutput:
    config: LsnifConfig = ctx.config
    compiled = compile_scene(ctx.scene, ctx.scene_dir)
    chosen = [c for c in choose_objects(ctx.scene, config, ctx.scene_dir) if c.choice == LSNIF]
    scene_dir = None if ctx.scene_dir is None else str(ctx.scene_dir)
    total = config.train.steps * len(chosen)
    models, placements, results, method_metrics = {}, {}, [], {}
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
        results.append(result)
        placements[choice.name] = {
            "materials": source.prepared.material_names,
            "instances": [m.tolist() for m in geometry.instance_matrices],
        }
        scores = held_out(model, source.prepared, config.evaluation_rays)
        size = model.size_bytes()
        bvh = bvh_bytes_estimate(geometry.mesh.num_triangles)
        figures = {
            "triangles": geometry.mesh.num_triangles,
            "instances": len(geometry.instance_matrices),
            "occupied_voxels": int(source.prepared.grid.occupied.sum()),
            "training_seconds": result.seconds,
            "final_loss": result.final_loss,
            "model_bytes": size,  # as stored: voxel bits, box, float16 table and MLP
            "bvh_bytes_estimate": bvh,
            "bvh_to_model": bvh / size,
            "bvh_bytes_paper_table1": bvh_bytes_paper_table1(geometry.mesh.num_triangles),
            **scores.__dict__,
        }
        method_metrics.update({f"{choice.name}.{k}": float(v) for k, v in figures.items()})
    files = artifact.save(ctx.output_dir, config, models, placements)

    ctx.raise_if_cancelled()
    ctx.log(
        f"rendering {config.preview_size}^2 with LSNIF at {config.preview_spp} spp against path tracing "
        f"and a {config.reference_spp}-spp reference"
    )
    loaded = artifact.load(ctx.output_dir)
    images = report_images(
        compiled,
        loaded.intersector(compiled),
        config.preview_size,
        config.preview_spp,
        config.reference_spp,
    )
    model_bytes = float(sum(model.size_bytes() for model in models.values()))
    method_metrics.update(
        {
            "networks": float(len(models)),
            "model_bytes": model_bytes,
            "flip_against_embree_same_spp": images.comparison.flip,
            "flip_noise_floor": images.comparison.flip_noise_floor,
        }
    )
    report = build_report(
        "lsnif",
        TrainResult.combined(results),
        stored_weights(models),
        images.model,
        images.equal_time,
        images.path_tracing,
        images.reference,
        method_metrics=method_metrics,
    )
    files.update(report.write(str(ctx.output_dir)))
    write_png(
        ctx.output_dir / PREVIEW,
        np.concatenate([images.reference, images.comparison.embree_image, images.model.image], 1),
    )
    files[PREVIEW] = (str(ctx.output_dir / PREVIEW), "image/png")
    metrics = {
        "flip": report.model.error.flip,
        "flip_path_tracing_equal_time": report.path_tracing_equal_time.error.flip,
        "model_bytes": model_bytes,
        "networks": float(len(models)),
    }
    if models:
        metrics["occlusion_accuracy"] = float(
            np.mean([method_metrics[f"{name}.occlusion_accuracy"] for name in models])
        )
    return RunOutput(files=files, metrics=metrics)
