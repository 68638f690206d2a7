"""Losses: values on known inputs and finiteness (with finite gradients) on edge values."""

from __future__ import annotations

import math

import pytest
import torch

from workers.nn.losses import (
    binary_cross_entropy,
    categorical_cross_entropy,
    cosine_similarity_loss,
    dssim,
    l1_dssim,
    mae,
    mu_law_l2,
    relative_l2,
)
from workers.nn.tonemap import mu_law

EDGES = torch.tensor([0.0, -0.0, 1e-30, -1e-30, -3.0, 1e6, -1e6, 0.5], dtype=torch.float32)


def finite_with_finite_gradient(loss_fn, prediction: torch.Tensor, target: torch.Tensor) -> float:
    prediction = prediction.clone().requires_grad_()
    loss = loss_fn(prediction, target)
    (grad,) = torch.autograd.grad(loss, prediction)
    assert torch.isfinite(loss) and torch.isfinite(grad).all(), loss_fn.__name__
    return loss.item()


@pytest.mark.parametrize("loss_fn", [relative_l2, mu_law_l2, mae])
def test_regression_losses_are_finite_on_edge_values(loss_fn):
    for target in (EDGES, EDGES.flip(0), torch.zeros_like(EDGES)):
        finite_with_finite_gradient(loss_fn, EDGES, target)


def test_relative_l2_value_and_stopped_gradient_denominator():
    p, t = torch.tensor([2.0], requires_grad=True), torch.tensor([1.0])
    loss = relative_l2(p, t)
    assert loss.item() == pytest.approx(1.0 / (4.0 + 1e-2))
    (grad,) = torch.autograd.grad(loss, p)
    assert grad.item() == pytest.approx(2 * 1.0 / (4.0 + 1e-2))  # the denominator is treated as constant
    assert relative_l2(torch.zeros(1), torch.ones(1)).item() == pytest.approx(100.0)
    with pytest.raises(ValueError):
        relative_l2(p, t, eps=0.0)


def test_mu_law_is_odd_bounded_and_has_its_true_slope_at_zero():
    x = torch.tensor([0.0, 1.0, -1.0, 0.1, -0.1, 1e6], dtype=torch.float64, requires_grad=True)
    y = mu_law(x, mu=10.0)
    assert y[1].item() == pytest.approx(1.0) and y[2].item() == pytest.approx(-1.0)
    assert y[3].item() == pytest.approx(-y[4].item())
    assert y[5].item() == pytest.approx(math.log1p(1e7) / math.log1p(10.0))
    (grad,) = torch.autograd.grad(y.sum(), x)
    assert grad[0].item() == pytest.approx(10.0 / math.log(11.0))
    assert torch.autograd.gradcheck(lambda v: mu_law(v, 10.0), (x,))


def test_mu_law_l2_value():
    loss = mu_law_l2(torch.tensor([1.0]), torch.tensor([-1.0]))
    assert loss.item() == pytest.approx(4.0)


def test_binary_cross_entropy_is_finite_for_huge_logits_and_correct():
    logits = torch.tensor([1e6, -1e6, 0.0, 30.0])
    target = torch.tensor([1.0, 0.0, 1.0, 0.0])
    loss = finite_with_finite_gradient(binary_cross_entropy, logits, target)
    assert loss == pytest.approx((0 + 0 + math.log(2) + 30.0) / 4, rel=1e-5)


def test_categorical_cross_entropy_value_and_edges():
    logits = torch.tensor([[0.0, 0.0, 0.0], [1e6, -1e6, 0.0]])
    target = torch.tensor([1, 0])
    loss = finite_with_finite_gradient(categorical_cross_entropy, logits, target)
    assert loss == pytest.approx(math.log(3) / 2)


def test_cosine_similarity_loss_values_and_zero_vectors():
    a = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    b = torch.tensor([[2.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0]])
    loss = finite_with_finite_gradient(cosine_similarity_loss, a, b)
    assert loss == pytest.approx((0.0 + 2.0 + 1.0) / 3)
    finite_with_finite_gradient(cosine_similarity_loss, torch.full((2, 3), 1e6), torch.full((2, 3), -1e-30))


def test_dssim_and_l1_dssim():
    torch.manual_seed(0)
    image = torch.rand(2, 16, 16, 3)
    assert dssim(image, image).item() == pytest.approx(0.0, abs=1e-6)
    assert l1_dssim(image, image).item() == pytest.approx(0.0, abs=1e-6)
    noisy = (image + 0.2 * torch.randn_like(image)).clamp(0, 1)
    assert 0 < dssim(image, noisy).item() <= 1
    finite_with_finite_gradient(l1_dssim, torch.zeros(1, 12, 12, 3), torch.zeros(1, 12, 12, 3))
    finite_with_finite_gradient(l1_dssim, torch.full((1, 12, 12, 3), 1e6), torch.zeros(1, 12, 12, 3))
