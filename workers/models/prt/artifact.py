"""A `prt` artifact: the network (S, W, U, f) in safetensors at float16, a JSON manifest with the config
and the hash grid's box, and the scene with the files it reads (`workers.scene.portability.portable`):
relighting needs the scene's geometry for the G-buffer and the direct light."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import safetensors.torch
import torch

from workers.models.prt.config import PrtConfig
from workers.models.prt.network import PrtNetwork
from workers.scene.format.spec import SceneSpec
from workers.scene.portability.portable import StoredScene, load_scene, portable_scene, save_scene

MANIFEST = "prt.json"
WEIGHTS = "prt.safetensors"
SAFETENSORS = "application/vnd.neuralbake.safetensors"
JSON = "application/json"
STORAGE_DTYPE = torch.float16


def save(
    folder: Path,
    config: PrtConfig,
    model: PrtNetwork,
    box: np.ndarray,
    objects: tuple[int, ...],
    scene: SceneSpec,
    scene_folder: Path | None = None,
) -> dict:
    if config.evaluation_spp is None:
        raise ValueError("evaluation_spp: choose the artifact's frame (`frame_spp`) before saving it")
    folder.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().to(STORAGE_DTYPE).cpu().contiguous() for k, v in model.state_dict().items()}
    safetensors.torch.save_file(tensors, str(folder / WEIGHTS))
    manifest = {
        "config": config.model_dump(mode="json"),
        "box": np.asarray(box).tolist(),
        "objects": list(objects),
    }
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=2))
    files = {WEIGHTS: (str(folder / WEIGHTS), SAFETENSORS), MANIFEST: (str(folder / MANIFEST), JSON)}
    files.update(save_scene(folder, portable_scene(scene, {}, scene_folder)))
    return files


@dataclass
class PrtArtifact:
    config: PrtConfig
    model: PrtNetwork
    box: np.ndarray  # (2, 3)
    objects: np.ndarray  # scene object indices whose indirect light the network predicts
    scene: StoredScene


def load(folder: Path | str, device: str = "cpu") -> PrtArtifact:
    folder = Path(folder)
    manifest = json.loads((folder / MANIFEST).read_text())
    config = PrtConfig.model_validate(manifest["config"])
    model = PrtNetwork(config)
    state = {k: v.float() for k, v in safetensors.torch.load_file(str(folder / WEIGHTS)).items()}
    model.load_state_dict(state)
    return PrtArtifact(
        config,
        model.to(device).eval(),
        np.asarray(manifest["box"], np.float64),
        np.asarray(manifest["objects"], np.int64),
        load_scene(folder),
    )
