"""Training state as checkpoint files without pickle: safetensors for tensors, JSON for everything else.

The optimizer's state dict is flattened into tensors named `state.<param>.<key>` plus a JSON sidecar with
the parameter groups and any non-tensor per-parameter values; loading rebuilds the exact dict, so Adam's
moments and step counts survive a resume unchanged.
"""

from __future__ import annotations

import json
from typing import Any

import safetensors.torch
import torch
from pydantic import BaseModel

MODEL_FILE = "model.safetensors"
OPTIMIZER_TENSORS_FILE = "optimizer.safetensors"
OPTIMIZER_JSON_FILE = "optimizer.json"
LOOP_FILE = "loop.json"


class LoopState(BaseModel):
    """Where the loop is: the next step, the next batch index, the best loss so far and the RNG states."""

    step: int = 0
    batch_position: int = 0
    best_loss: float | None = None
    torch_rng: list[int] = []
    cuda_rng: list[list[int]] = []

    @classmethod
    def capture(cls, step: int, batch_position: int, best_loss: float | None) -> LoopState:
        cuda = [s.tolist() for s in torch.cuda.get_rng_state_all()] if torch.cuda.is_available() else []
        return cls(
            step=step,
            batch_position=batch_position,
            best_loss=best_loss,
            torch_rng=torch.get_rng_state().tolist(),
            cuda_rng=cuda,
        )

    def restore_rng(self) -> None:
        torch.set_rng_state(torch.tensor(self.torch_rng, dtype=torch.uint8))
        if self.cuda_rng and torch.cuda.is_available():
            torch.cuda.set_rng_state_all([torch.tensor(s, dtype=torch.uint8) for s in self.cuda_rng])


def _independent(tensor: torch.Tensor) -> torch.Tensor:
    """A contiguous CPU copy: safetensors refuses tensors that share storage, as tied weights do."""
    return tensor.detach().to("cpu", copy=True).contiguous()


def encode_optimizer(optimizer: torch.optim.Optimizer) -> dict[str, bytes]:
    state_dict = optimizer.state_dict()
    tensors: dict[str, torch.Tensor] = {}
    other: dict[str, dict[str, Any]] = {}
    for param_id, values in state_dict["state"].items():
        for key, value in values.items():
            if isinstance(value, torch.Tensor):
                tensors[f"state.{param_id}.{key}"] = _independent(value)
            else:
                other.setdefault(str(param_id), {})[key] = value
    sidecar = {"param_groups": state_dict["param_groups"], "non_tensor_state": other}
    return {
        OPTIMIZER_TENSORS_FILE: safetensors.torch.save(tensors),
        OPTIMIZER_JSON_FILE: json.dumps(sidecar).encode(),
    }


def decode_optimizer(files: dict[str, bytes], optimizer: torch.optim.Optimizer) -> None:
    sidecar = json.loads(files[OPTIMIZER_JSON_FILE])
    state: dict[int, dict[str, Any]] = {}
    for name, tensor in safetensors.torch.load(files[OPTIMIZER_TENSORS_FILE]).items():
        _, param_id, key = name.split(".", 2)
        state.setdefault(int(param_id), {})[key] = tensor
    for param_id, values in sidecar["non_tensor_state"].items():
        state.setdefault(int(param_id), {}).update(values)
    optimizer.load_state_dict({"state": state, "param_groups": sidecar["param_groups"]})


def encode(
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    scaler: torch.amp.GradScaler,
    loop: LoopState,
) -> dict[str, bytes]:
    """The files of one checkpoint."""
    weights = {name: _independent(t) for name, t in model.state_dict().items()}
    loop_json = {"loop": loop.model_dump(), "grad_scaler": scaler.state_dict()}
    return {
        MODEL_FILE: safetensors.torch.save(weights),
        **encode_optimizer(optimizer),
        LOOP_FILE: json.dumps(loop_json).encode(),
    }


def decode(
    files: dict[str, bytes],
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    scaler: torch.amp.GradScaler,
) -> LoopState:
    """Load a checkpoint's files into the given objects (in place) and return the loop state."""
    model.load_state_dict(safetensors.torch.load(files[MODEL_FILE]))
    decode_optimizer(files, optimizer)
    loop_json = json.loads(files[LOOP_FILE])
    if loop_json["grad_scaler"]:
        scaler.load_state_dict(loop_json["grad_scaler"])
    return LoopState.model_validate(loop_json["loop"])
