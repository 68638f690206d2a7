"""Multilayer perceptrons: a plain fully connected network and the skip-connection PixelGenerator."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn

LEAKY_SLOPE = 0.2


class _Exponential(nn.Module):
    """exp, for positive outputs such as radiance (tiny-cuda-nn's "Exponential")."""

    def forward(self, x: Tensor) -> Tensor:
        return torch.exp(x)


ACTIVATIONS: dict[str, Callable[[], nn.Module]] = {
    "none": nn.Identity,
    "relu": nn.ReLU,
    "leaky_relu": lambda: nn.LeakyReLU(LEAKY_SLOPE),
    "silu": nn.SiLU,
    "tanh": nn.Tanh,
    "sigmoid": nn.Sigmoid,
    "softplus": nn.Softplus,
    "exponential": _Exponential,
}


def make_activation(name: str) -> nn.Module:
    try:
        return ACTIVATIONS[name]()
    except KeyError:
        raise ValueError(f"unknown activation {name!r}; choose from {sorted(ACTIVATIONS)}") from None


def make_linear(n_in: int, n_out: int, kaiming: bool, activation: str = "none") -> nn.Linear:
    """A linear layer; with `kaiming`, He-uniform weights for the activation that follows and zero bias."""
    layer = nn.Linear(n_in, n_out)
    if kaiming:
        if activation == "relu":
            nn.init.kaiming_uniform_(layer.weight, nonlinearity="relu")
        elif activation == "leaky_relu":
            nn.init.kaiming_uniform_(layer.weight, a=LEAKY_SLOPE, nonlinearity="leaky_relu")
        else:
            nn.init.kaiming_uniform_(layer.weight, nonlinearity="linear")
        nn.init.zeros_(layer.bias)
    return layer


class MLP(nn.Module):
    """`depth` hidden layers of `width` units with `activation`, then a linear output layer followed by
    `output_activation`. `kaiming` uses He initialisation instead of PyTorch's default."""

    def __init__(
        self,
        n_input_dims: int,
        n_output_dims: int,
        width: int = 64,
        depth: int = 2,
        activation: str = "relu",
        output_activation: str = "none",
        kaiming: bool = True,
    ) -> None:
        super().__init__()
        self.n_input_dims, self.n_output_dims = n_input_dims, n_output_dims
        layers: list[nn.Module] = []
        n_in = n_input_dims
        for _ in range(depth):
            layers += [make_linear(n_in, width, kaiming, activation), make_activation(activation)]
            n_in = width
        layers += [make_linear(n_in, n_output_dims, kaiming), make_activation(output_activation)]
        self.layers = nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        return self.layers(x)


class SkipGenerator(nn.Module):
    """PixelGenerator (Granskog et al. 2020; Diolatzis, thesis Ch. 5): every layer re-receives the inputs.

    The first layer sees only the leading `first_layer_inputs` features (the position G-buffer, which
    "preconditions" the network); each later hidden layer and the output layer see
    [previous hidden, all inputs].
    """

    def __init__(
        self,
        n_input_dims: int,
        n_output_dims: int,
        width: int = 512,
        depth: int = 8,
        first_layer_inputs: int | None = None,
        activation: str = "leaky_relu",
        output_activation: str = "none",
        kaiming: bool = True,
    ) -> None:
        super().__init__()
        if depth < 1:
            raise ValueError("a skip generator needs at least one hidden layer")
        self.first_layer_inputs = n_input_dims if first_layer_inputs is None else first_layer_inputs
        if not 1 <= self.first_layer_inputs <= n_input_dims:
            raise ValueError(f"first_layer_inputs must be in 1..{n_input_dims}")
        self.n_input_dims, self.n_output_dims = n_input_dims, n_output_dims
        self.first = make_linear(self.first_layer_inputs, width, kaiming, activation)
        self.hidden = nn.ModuleList(
            make_linear(width + n_input_dims, width, kaiming, activation) for _ in range(depth - 1)
        )
        self.output = make_linear(width + n_input_dims, n_output_dims, kaiming)
        self.activation = make_activation(activation)
        self.output_activation = make_activation(output_activation)

    def forward(self, x: Tensor) -> Tensor:
        h = self.activation(self.first(x[..., : self.first_layer_inputs]))
        for layer in self.hidden:
            h = self.activation(layer(torch.cat((h, x), dim=-1)))
        return self.output_activation(self.output(torch.cat((h, x), dim=-1)))
