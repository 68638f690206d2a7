"""An LSNIF artifact: per trained object its voxels, feature table and MLP (safetensors, the table and the
MLP in float16 as the paper's sizes assume; see `LsnifObject.round_to_storage`), plus a JSON
manifest with the config, the material lists and the instance mapping (which scene objects use which
network, with their transforms at training time) and the materials' definitions, and the scene the
objects were trained in (`workers.scene.portability.portable`: objects read from files become stand-ins).

The grid's vertex keys are not stored: they follow from the voxels (see `encoding`). Loading rebuilds
each object exactly, and `intersector` places the networks wherever a scene puts the same-named objects,
so moved or re-instanced objects need no retraining.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import safetensors.numpy
import torch
from pydantic import TypeAdapter

from workers.models.lsnif.config import LsnifConfig
from workers.models.lsnif.intersector import NeuralInstance, NeuralIntersector
from workers.models.lsnif.network import STORAGE_DTYPE, LsnifObject
from workers.render.voxels import VoxelGrid
from workers.scene.format.spec import Material, SceneSpec
from workers.scene.geometry.compile import CompiledScene
from workers.scene.portability.portable import portable_scene, reads_file, save_scene, untextured

MANIFEST = "lsnif.json"
SAFETENSORS = "application/vnd.neuralbake.safetensors"
JSON = "application/json"


def export_object(model: LsnifObject) -> dict[str, np.ndarray]:
    grid = model.grid
    tensors = {
        "voxels.bits": np.packbits(grid.occupied.reshape(-1)),
        "voxels.lo": grid.lo,
        "voxels.size": grid.size,
        "grid.table": _stored(model.encoding.table),
    }
    tensors.update({f"mlp.{k}": _stored(v) for k, v in model.mlp.state_dict().items()})
    return tensors


def _stored(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().to(STORAGE_DTYPE).cpu().numpy()


def import_object(tensors: dict[str, np.ndarray], resolution: int, n_materials: int, config) -> LsnifObject:
    occupied = np.unpackbits(tensors["voxels.bits"], count=resolution**3).astype(bool)
    grid = VoxelGrid(tensors["voxels.lo"], tensors["voxels.size"], occupied.reshape((resolution,) * 3))
    model = LsnifObject(grid, n_materials, config)
    table = torch.from_numpy(tensors["grid.table"]).float()
    if table.shape != model.encoding.table.shape:
        raise ValueError(f"feature table of shape {tuple(table.shape)} does not fit these voxels and config")
    with torch.no_grad():
        model.encoding.table.copy_(table)
    mlp = {k.removeprefix("mlp."): torch.from_numpy(v).float() for k, v in tensors.items() if k[:4] == "mlp."}
    model.mlp.load_state_dict(mlp)
    return model.eval()


def save(
    folder: Path,
    config: LsnifConfig,
    models: dict[str, LsnifObject],
    placements: dict,
    scene: SceneSpec,
    scene_folder: Path | None = None,
) -> dict:
    """Write `objects/<name>.safetensors`, the manifest and the scene; returns artifact name -> (path,
    media type).

    `placements`: object name -> {"materials": [...], "instances": [4x4 matrices as lists]}.
    """
    (folder / "objects").mkdir(parents=True, exist_ok=True)
    files = {}
    for name, model in models.items():
        relative = f"objects/{name}.safetensors"
        safetensors.numpy.save_file(export_object(model), str(folder / relative))
        files[relative] = (str(folder / relative), SAFETENSORS)
    manifest = {
        "config": config.model_dump(mode="json"),
        "objects": {name: {"file": f"objects/{name}.safetensors", **placements[name]} for name in models},
        "materials": {
            name: untextured(scene.materials[name]).model_dump(mode="json")
            for name in sorted({m for p in placements.values() for m in p["materials"]})
        },
    }
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=2))
    files[MANIFEST] = (str(folder / MANIFEST), JSON)
    from_files = {
        o.name: models[o.name].grid.bounds for o in scene.objects if o.name in models and reads_file(o)
    }
    files.update(save_scene(folder, portable_scene(scene, from_files, scene_folder)))
    return files


@dataclass
class LsnifArtifact:
    config: LsnifConfig
    models: dict[str, LsnifObject]
    materials: dict[str, list[str]]  # object name -> material names, by the network's material index
    instances: dict[str, list[np.ndarray]]  # object name -> local-to-world matrices at training time
    # the definitions of the material names, without textures (a neutral render's materials)
    material_specs: dict[str, Material] = field(default_factory=dict)

    def intersector(self, scene: CompiledScene, robust: bool = True) -> NeuralIntersector:
        """Embree for the scene's other objects, these networks for every instance of same-named ones."""
        placed = []
        for geometry in scene.objects:
            model = self.models.get(geometry.name)
            if model is None:
                continue
            material_ids = np.array([scene.material_names.index(m) for m in self.materials[geometry.name]])
            for matrix, triangles in zip(geometry.instance_matrices, geometry.triangle_ranges, strict=True):
                placed.append(NeuralInstance(model, model.grid.bounds, matrix, triangles, material_ids))
        return NeuralIntersector(scene, placed, robust=robust)


def load(folder: Path | str) -> LsnifArtifact:
    folder = Path(folder)
    manifest = json.loads((folder / MANIFEST).read_text())
    config = LsnifConfig.model_validate(manifest["config"])
    models, materials, instances = {}, {}, {}
    for name, entry in manifest["objects"].items():
        tensors = safetensors.numpy.load_file(str(folder / entry["file"]))
        models[name] = import_object(tensors, config.voxel_resolution, len(entry["materials"]), config)
        materials[name] = entry["materials"]
        instances[name] = [np.asarray(m, np.float64) for m in entry["instances"]]
    specs = TypeAdapter(dict[str, Material]).validate_python(manifest.get("materials", {}))
    return LsnifArtifact(config, models, materials, instances, specs)
