"""Training state as checkpoint files without pickle: safetensors for tensors, JSON for everything else.

Each phase's optimizer has its own pair of files: its state dict flattened into tensors named
`state.<param>.<key>` plus a JSON sidecar with the parameter groups and any non-tensor per-parameter
values; loading rebuilds the exact dict, so Adam's moments and step counts survive a resume unchanged.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import safetensors.torch
import torch
from pydantic import BaseModel

MODEL_FILE = "model.safetensors"
LOOP_FILE = "loop.json"


def optimizer_files(phase: str) -> tuple[str, str]:
    """The names of the tensors file and the JSON sidecar of the named phase's optimizer."""
    return f"optimizer-{phase}.safetensors", f"optimizer-{phase}.json"


class LoopState(BaseModel):
    """Where the loop is: the next step, the next batch index, the best loss so far, each phase's latest
    loss (a phase that skips the next step still counts in its loss) and the RNG states."""

    step: int = 0
    batch_position: int = 0
    best_loss: float | None = None
    losses: dict[str, float] = {}
    torch_rng: list[int] = []
    cuda_rng: list[list[int]] = []

    @classmethod
    def capture(
        cls, step: int, batch_position: int, best_loss: float | None, losses: dict[str, float]
    ) -> LoopState:
        cuda = [s.tolist() for s in torch.cuda.get_rng_state_all()] if torch.cuda.is_available() else []
        return cls(
            step=step,
            batch_position=batch_position,
            best_loss=best_loss,
            losses=losses,
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


def encode_optimizer(phase: str, optimizer: torch.optim.Optimizer) -> dict[str, bytes]:
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
    tensors_file, json_file = optimizer_files(phase)
    return {tensors_file: safetensors.torch.save(tensors), json_file: json.dumps(sidecar).encode()}


def decode_optimizer(files: dict[str, bytes], phase: str, optimizer: torch.optim.Optimizer) -> None:
    tensors_file, json_file = optimizer_files(phase)
    if json_file not in files:
        raise ValueError(f"the checkpoint has no optimizer of phase {phase}: its files are {sorted(files)}")
    sidecar = json.loads(files[json_file])
    state: dict[int, dict[str, Any]] = {}
    for name, tensor in safetensors.torch.load(files[tensors_file]).items():
        _, param_id, key = name.split(".", 2)
        state.setdefault(int(param_id), {})[key] = tensor
    for param_id, values in sidecar["non_tensor_state"].items():
        state.setdefault(int(param_id), {}).update(values)
    optimizer.load_state_dict({"state": state, "param_groups": sidecar["param_groups"]})


def encode(
    model: torch.nn.Module,
    optimizers: Mapping[str, torch.optim.Optimizer],
    scalers: Mapping[str, torch.amp.GradScaler],
    loop: LoopState,
) -> dict[str, bytes]:
    """The files of one checkpoint; `optimizers` and `scalers` are by phase name."""
    weights = {name: _independent(t) for name, t in model.state_dict().items()}
    grad_scalers = {phase: scaler.state_dict() for phase, scaler in scalers.items()}
    loop_json = {"loop": loop.model_dump(), "grad_scalers": grad_scalers}
    optimizer_states: dict[str, bytes] = {}
    for phase, optimizer in optimizers.items():
        optimizer_states |= encode_optimizer(phase, optimizer)
    return {
        MODEL_FILE: safetensors.torch.save(weights),
        **optimizer_states,
        LOOP_FILE: json.dumps(loop_json).encode(),
    }


def decode(
    files: dict[str, bytes],
    model: torch.nn.Module,
    optimizers: Mapping[str, torch.optim.Optimizer],
    scalers: Mapping[str, torch.amp.GradScaler],
) -> LoopState:
    """Load a checkpoint's files into the given objects (in place) and return the loop state."""
    model.load_state_dict(safetensors.torch.load(files[MODEL_FILE]))
    for phase, optimizer in optimizers.items():
        decode_optimizer(files, phase, optimizer)
    loop_json = json.loads(files[LOOP_FILE])
    for phase, scaler in scalers.items():
        if state := loop_json["grad_scalers"].get(phase):  # empty when the scaler was disabled
            scaler.load_state_dict(state)
    return LoopState.model_validate(loop_json["loop"])
