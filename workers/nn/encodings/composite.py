"""Recurrent composite encoding (Weier et al. 2023, Sec. 4.3): one encoding shared by several inputs.

The `lod` visibility network encodes two points with the same hash grid, so swapping them is free and the
grid's parameters are halved; gradients from every input accumulate in the one shared table.
"""

from __future__ import annotations

from torch import Tensor, nn


class SharedInputsEncoding(nn.Module):
    """Encode `n_inputs` points packed as x [..., n_inputs * d] with one encoding; concatenate the results."""

    def __init__(self, encoding: nn.Module, n_inputs: int) -> None:
        super().__init__()
        if n_inputs < 1:
            raise ValueError(f"n_inputs must be positive, got {n_inputs}")
        self.encoding = encoding
        self.n_inputs = n_inputs

    @property
    def n_input_dims(self) -> int:
        return self.n_inputs * self.encoding.n_input_dims

    @property
    def n_output_dims(self) -> int:
        return self.n_inputs * self.encoding.n_output_dims

    def forward(self, x: Tensor) -> Tensor:
        # One call over all inputs: a single gather and a single scatter for the shared table.
        points = x.unflatten(-1, (self.n_inputs, self.encoding.n_input_dims))
        return self.encoding(points).flatten(-2)
