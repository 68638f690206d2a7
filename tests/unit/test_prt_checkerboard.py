"""Checkerboard shading of `prt` frames (`workers.models.prt.checkerboard`): which pixels the network
shades, and how the others are filled from their neighbours on the same surface."""

from __future__ import annotations

import numpy as np
import torch

from workers.models.prt.checkerboard import checkerboard
from workers.models.prt.gbuffer import SurfaceInputs

H, W = 6, 7


def _plane(object_id: np.ndarray | None = None, normal: np.ndarray | None = None) -> SurfaceInputs:
    """An H x W G-buffer of one flat object facing the camera (object 0), with `object_id` and `normal`
    overriding per pixel."""
    n = H * W
    object_id = np.zeros(n, int) if object_id is None else object_id.ravel()
    normal = np.tile([0.0, 0.0, 1.0], (n, 1)) if normal is None else normal.reshape(n, 3)
    return SurfaceInputs(
        hit=object_id >= 0, position=np.zeros((n, 3)), normal=normal, reflected=normal.copy(),
        kd=np.full((n, 3), 0.5), ks=np.zeros((n, 3)), roughness=np.ones(n), object_id=object_id,
    )  # fmt: skip


def _even() -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W]
    return ((y + x) % 2 == 0).ravel()


def test_one_surface_is_shaded_on_the_checkerboard_and_a_linear_ramp_is_filled_exactly():
    inputs = _plane()
    modelled = inputs.modelled(np.array([0]))
    board = checkerboard(inputs, modelled, H, W)
    shaded = board.shaded
    np.testing.assert_array_equal(shaded, _even())
    y, x = np.mgrid[0:H, 0:W]
    ramp = np.stack([x, y, x + 2 * y], axis=-1).reshape(-1, 3).astype(np.float32)
    filled = board.fill(np.where(shaded[:, None], ramp, np.nan))
    interior = ((x > 0) & (x < W - 1) & (y > 0) & (y < H - 1)).ravel()
    np.testing.assert_allclose(filled[interior], ramp[interior], atol=1e-6)  # the mean of 4 neighbours
    assert np.isfinite(filled).all()  # border pixels take the neighbours they have


def test_a_pixel_takes_no_value_from_another_object_or_a_turned_surface_and_an_orphan_is_shaded():
    object_id = np.zeros((H, W), int)
    object_id[:, 4:] = 1  # a second object on the right
    object_id[2, 3] = 2  # a one-pixel object off the checkerboard
    normal = np.tile([0.0, 0.0, 1.0], (H, W, 1))
    normal[4:, :4] = [0.0, 1.0, 0.0]  # a floor below the wall, the same object
    inputs = _plane(object_id, normal)
    modelled = inputs.modelled(np.array([0, 1, 2]))
    board = checkerboard(inputs, modelled, H, W)
    shaded = board.shaded
    assert shaded.reshape(H, W)[2, 3] and not _even().reshape(H, W)[2, 3]  # no neighbour: shaded itself
    surface = (object_id + 10 * (normal[..., 1] > 0)).ravel().astype(np.float32)  # a value per surface
    values = np.repeat(np.where(shaded, surface, np.nan)[:, None], 3, axis=1)  # unshaded: never read
    filled = board.fill(values)[:, 0]
    np.testing.assert_array_equal(filled, surface)  # each pixel only ever averages its own surface


def test_pixels_not_modelled_are_neither_shaded_nor_filled():
    object_id = np.zeros((H, W), int)
    object_id[:, :3] = -1  # the environment, seen directly
    object_id[:, 5:] = 1  # an object left to direct light
    inputs = _plane(object_id)
    modelled = inputs.modelled(np.array([0]))
    board = checkerboard(inputs, modelled, H, W)
    shaded = board.shaded
    assert not shaded[~modelled].any()
    values = np.where(shaded[:, None], 1.0, 0.0).astype(np.float32)
    filled = board.fill(values)
    assert (filled[~modelled] == 0).all() and (filled[modelled] == 1).all()


def test_a_checkerboard_frame_is_the_network_at_its_shaded_pixels_and_their_mean_between():
    from workers.models.prt.config import PRESETS, PrtConfig
    from workers.models.prt.frame import predict_indirect
    from workers.models.prt.network import PrtNetwork
    from workers.runtime.contract import resolve_preset

    torch.manual_seed(0)
    model = PrtNetwork(resolve_preset(PrtConfig, PRESETS, "quick", {}))
    torch.nn.init.normal_(model.f.layers[-2].weight)  # a network that predicts something everywhere
    rng = np.random.default_rng(0)
    inputs = _plane()
    inputs.kd = rng.uniform(0, 1, (H * W, 3))  # a different value at every pixel
    box, objects, cube = np.array([[-1.0] * 3, [1.0] * 3]), np.array([0]), rng.uniform(0, 1, (6, 4, 4, 3))
    every, pairs = predict_indirect(model, inputs, box, objects, cube, 8, "area")
    half, half_pairs = predict_indirect(model, inputs, box, objects, cube, 8, "area", (H, W))
    shaded = _even()
    np.testing.assert_allclose(half[shaded], every[shaded], rtol=1e-5, atol=1e-7)
    board = checkerboard(inputs, inputs.modelled(objects), H, W)
    expected = board.fill(np.where(shaded[:, None], every, 0))
    np.testing.assert_allclose(half, expected, rtol=1e-5, atol=1e-7)
    assert not np.allclose(half[~shaded], every[~shaded])  # filled, not evaluated
    assert (pairs, half_pairs) == (8 * H * W, 8 * int(board.shaded.sum()))  # the frame's counted cost
