"""A `lod` artifact: the sparse grid with its thresholds and both networks in one safetensors file (the
networks in float16, as the paper stores them), a JSON manifest (config, objects, LoDs) and the scene
around the asset (`workers.scene.portability.portable`: the asset's objects as stand-ins, whose place the
LoD takes).

`load` rebuilds everything exactly, and `aggregate` hands the path tracer the asset at any built LoD.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import safetensors.numpy
import torch

from workers.models.lod.config import LodConfig
from workers.models.lod.grid import LodGrid
from workers.models.lod.networks import LodNetworks
from workers.models.lod.plan import octaves
from workers.models.lod.traversal import LodAggregate
from workers.scene.geometry.compile import CompiledScene
from workers.scene.portability.portable import portable_scene, save_scene

MANIFEST = "lod.json"
WEIGHTS = "lod.safetensors"
SAFETENSORS = "application/vnd.neuralbake.safetensors"
JSON = "application/json"
STORAGE_DTYPE = torch.float16


@dataclass
class LodAsset:
    config: LodConfig
    objects: list[str]
    grid: LodGrid
    networks: LodNetworks

    def aggregate(self, level: int, optimal_thresholds: bool = True, stochastic: bool | None = None):
        stochastic = self.config.stochastic_traversal if stochastic is None else stochastic
        return LodAggregate(
            self.grid, self.networks, level, optimal_thresholds, stochastic, self.config.survival_floor_at_512
        )

    def network_bytes(self) -> int:
        return sum(p.numel() * STORAGE_DTYPE.itemsize for p in self.networks.state_dict().values())


def build_networks(config: LodConfig, grid: LodGrid) -> LodNetworks:
    return LodNetworks(config, octaves(grid.resolutions), grid.resolutions[-1])


def save(folder: Path, asset: LodAsset, scene: CompiledScene) -> dict[str, tuple[str, str]]:
    """Write the artifact of `asset`, prefiltered from `scene`; artifact name -> (path, media type)."""
    folder.mkdir(parents=True, exist_ok=True)
    tensors = dict(asset.grid.arrays())
    tensors.update(
        {
            f"net.{k}": v.detach().to(STORAGE_DTYPE).cpu().numpy()
            for k, v in asset.networks.state_dict().items()
        }
    )
    safetensors.numpy.save_file(tensors, str(folder / WEIGHTS))
    manifest = {"kind": "lod", "config": asset.config.model_dump(mode="json"), "objects": asset.objects}
    manifest["resolutions"] = asset.grid.resolutions
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=2))
    local_bounds = {
        g.name: np.stack([g.mesh.vertices.min(0), g.mesh.vertices.max(0)])
        for g in scene.objects
        if g.name in asset.objects
    }
    files = save_scene(folder, portable_scene(scene.spec, local_bounds, scene.base_dir))
    return {WEIGHTS: (str(folder / WEIGHTS), SAFETENSORS), MANIFEST: (str(folder / MANIFEST), JSON), **files}


def load(folder: Path) -> LodAsset:
    manifest = json.loads((Path(folder) / MANIFEST).read_text())
    config = LodConfig.model_validate(manifest["config"])
    tensors = safetensors.numpy.load_file(str(Path(folder) / WEIGHTS))
    grid = LodGrid.from_arrays(tensors)
    networks = build_networks(config, grid)
    state = {
        k.removeprefix("net."): torch.from_numpy(v).float() for k, v in tensors.items() if k[:4] == "net."
    }
    networks.load_state_dict(state)
    return LodAsset(config, manifest["objects"], grid, networks.eval())
