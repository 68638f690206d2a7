"""An `explore` artifact: the network's weights (safetensors, float16), a manifest (config, the scene's
dimensions by name, the box positions are normalised by) and the scene with its variables
(`workers.scene.portability.portable`), from which serving computes G-buffers at any v.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import safetensors.torch
import torch

from workers.models.explore.config import ExploreConfig
from workers.models.explore.network import PixelGenerator
from workers.scene.format.spec import SceneSpec
from workers.scene.format.variables import dimension_names
from workers.scene.portability.portable import load_scene, portable_scene, save_scene

MANIFEST = "explore.json"
WEIGHTS = "explore.safetensors"
SAFETENSORS = "application/vnd.neuralbake.safetensors"
JSON = "application/json"
STORAGE_DTYPE = torch.float16


def save(
    folder: Path,
    config: ExploreConfig,
    model: PixelGenerator,
    scene: SceneSpec,
    box: np.ndarray,
    scene_folder: Path | None = None,
) -> dict:
    """Write the weights, the manifest and the scene; artifact name -> (path, media type)."""
    folder.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to(STORAGE_DTYPE).cpu().contiguous() for k, v in model.state_dict().items()}
    safetensors.torch.save_file(state, str(folder / WEIGHTS))
    manifest = {
        "config": config.model_dump(mode="json"),
        "dimensions": dimension_names(scene),
        "box": np.asarray(box, np.float64).tolist(),
    }
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=2))
    files = {WEIGHTS: (str(folder / WEIGHTS), SAFETENSORS), MANIFEST: (str(folder / MANIFEST), JSON)}
    stored = portable_scene(scene, {}, scene_folder)
    if stored.spec is None:
        raise ValueError(f"scene: {stored.reason}; an explore artifact renders its scene, so it must keep it")
    files.update(save_scene(folder, stored))
    return files


@dataclass
class ExploreArtifact:
    config: ExploreConfig
    model: PixelGenerator
    scene: SceneSpec
    box: np.ndarray
    dimensions: list[str]
    scene_dir: Path | None  # where the scene's relative file paths resolve


def load(folder: Path | str, device: str = "cpu") -> ExploreArtifact:
    folder = Path(folder)
    manifest = json.loads((folder / MANIFEST).read_text())
    config = ExploreConfig.model_validate(manifest["config"])
    stored = load_scene(folder)
    if stored.spec is None:
        raise ValueError("the artifact keeps no scene")
    model = PixelGenerator.of(config, len(manifest["dimensions"]))
    weights = safetensors.torch.load_file(str(folder / WEIGHTS))
    model.load_state_dict({k: v.float() for k, v in weights.items()})
    return ExploreArtifact(
        config,
        model.to(device).eval(),
        stored.spec,
        np.asarray(manifest["box"]),
        manifest["dimensions"],
        stored.base_dir,
    )
