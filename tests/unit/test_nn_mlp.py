"""MLP and skip-connection generator: shapes, initialisation, input routing."""

from __future__ import annotations

import pytest
import torch

from workers.nn.mlp import MLP, SkipGenerator


def test_mlp_shapes_activations_and_kaiming_init():
    net = MLP(8, 3, width=32, depth=3, activation="relu", output_activation="sigmoid")
    linears = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    assert [layer.in_features for layer in linears] == [8, 32, 32, 32]
    assert all(torch.all(layer.bias == 0) for layer in linears)
    out = net(torch.randn(10, 4, 8))
    assert out.shape == (10, 4, 3) and torch.all((out >= 0) & (out <= 1))
    with pytest.raises(ValueError):
        MLP(8, 3, activation="swishy")


def test_kaiming_init_preserves_activation_scale_through_depth():
    torch.manual_seed(0)
    net = MLP(256, 256, width=256, depth=8, activation="relu")
    x = torch.randn(4096, 256)
    hidden = net.layers[:-2](x)  # after the last hidden ReLU
    # He init keeps E[h^2] close to E[x^2] = 1 (to within sampling noise) instead of shrinking by 2^-8.
    assert 0.4 < hidden.pow(2).mean().item() * 2 < 2.5


def test_mlp_runs_in_float64_and_trains():
    torch.manual_seed(0)
    net = MLP(2, 1, width=32, depth=2).double()
    x = torch.rand(256, 2, dtype=torch.float64)
    y = (x[:, :1] * 3).sin()
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-2)
    first = None
    for _ in range(200):
        loss = ((net(x) - y) ** 2).mean()
        first = first if first is not None else loss.item()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    assert loss.item() < first / 20


def test_skip_generator_first_layer_sees_only_position():
    torch.manual_seed(0)
    net = SkipGenerator(7, 3, width=16, depth=4, first_layer_inputs=3).double()
    assert net.first.in_features == 3
    assert all(layer.in_features == 16 + 7 for layer in net.hidden) and net.output.in_features == 16 + 7
    x = torch.randn(5, 7, dtype=torch.float64, requires_grad=True)
    out = net(x)
    assert out.shape == (5, 3)
    # Every input reaches the output; the non-position inputs only through the skip connections.
    assert torch.all(torch.autograd.grad(out.sum(), x)[0] != 0)
    assert torch.autograd.gradcheck(net, (x,))


def test_skip_generator_rejects_bad_first_layer_inputs():
    with pytest.raises(ValueError):
        SkipGenerator(4, 3, first_layer_inputs=5)
    with pytest.raises(ValueError):
        SkipGenerator(4, 3, depth=0)
