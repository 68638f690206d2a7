"""A mesogan artifact: the generator's mapping, synthesis and decoder weights (safetensors, float16 as
trained and measured; the discriminator is training-only), a JSON manifest with the config, and the
scene it was trained for (`workers.scene.portability.portable`), so the inference service can render it there.
"""

from __future__ import annotations

import json
from pathlib import Path

import safetensors.torch
import torch

from workers.models.mesogan.config import MesoganConfig
from workers.models.mesogan.networks import MesoGAN
from workers.scene.format.spec import SceneSpec
from workers.scene.portability.portable import portable_scene, save_scene

MANIFEST = "mesogan.json"
WEIGHTS = "mesogan.safetensors"
SAFETENSORS = "application/vnd.neuralbake.safetensors"
JSON = "application/json"
STORAGE_DTYPE = torch.float16
SHIPPED = ("mapping.", "synthesis.", "decoder.")


def save(
    folder: Path, config: MesoganConfig, model: MesoGAN, spec: SceneSpec, scene_folder: Path | None = None
) -> dict[str, tuple[str, str]]:
    folder.mkdir(parents=True, exist_ok=True)
    tensors = {
        k: v.detach().to(STORAGE_DTYPE).cpu().contiguous()
        for k, v in model.state_dict().items()
        if k.startswith(SHIPPED)
    }
    safetensors.torch.save_file(tensors, str(folder / WEIGHTS))
    (folder / MANIFEST).write_text(json.dumps({"config": config.model_dump(mode="json")}, indent=1))
    files = {WEIGHTS: (str(folder / WEIGHTS), SAFETENSORS), MANIFEST: (str(folder / MANIFEST), JSON)}
    files.update(save_scene(folder, portable_scene(spec, {}, scene_folder)))
    return files


def load(folder: Path, device: str = "cpu") -> tuple[MesoganConfig, MesoGAN]:
    manifest = json.loads((folder / MANIFEST).read_text())
    config = MesoganConfig.model_validate(manifest["config"])
    model = MesoGAN(config)
    tensors = safetensors.torch.load_file(str(folder / WEIGHTS))
    missing = model.load_state_dict({k: v.float() for k, v in tensors.items()}, strict=False).missing_keys
    if unexpected := [k for k in missing if k.startswith(SHIPPED)]:
        raise ValueError(f"{folder / WEIGHTS} lacks {unexpected[:3]}: not a mesogan artifact of this config")
    return config, model.to(device).eval()


def shipped_bytes(model: MesoGAN) -> int:
    """Bytes of what the artifact stores (the generator and decoder at float16)."""
    return sum(v.numel() * 2 for k, v in model.state_dict().items() if k.startswith(SHIPPED))
