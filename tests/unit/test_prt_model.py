"""`prt` lighting and network: Haar on cube maps of several sizes, texel conventions, selection, linearity of
B in L, the roughness map, and bad uploaded maps (issue 15's hard cases)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from workers.models.prt import network
from workers.models.prt.config import PRESETS, CamerasConfig, PrtConfig
from workers.models.prt.lighting import (
    CubeMapLight,
    cube_directions,
    cube_of,
    latlong_of,
    sampling_latlong,
    texels_of,
)
from workers.models.prt.network import PrtNetwork, roughness_feature
from workers.models.prt.selection import (
    ranked_wavelets,
    run_time_selection,
    training_selection,
    wavelets_of,
)
from workers.models.prt.views import trajectory_cameras
from workers.nn.cubemap import cubemap_solid_angles, direction_to_texel
from workers.nn.haar import cubemap_from_wavelets
from workers.render.environment import EnvironmentMapLight
from workers.runtime.contract import resolve_preset
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Camera, EnvironmentMap, euler_xyz
from workers.scene.generators.envmaps import texel_directions

SIZES = [1, 2, 4, 8, 16, 32]


@pytest.mark.parametrize("size", SIZES)
def test_cube_haar_is_orthonormal_and_reconstructs_exactly(size):
    cube = torch.rand(6, size, size, 3, dtype=torch.float64) ** 3
    coefficients = wavelets_of(cube.numpy())
    assert torch.allclose(cubemap_from_wavelets(coefficients), cube, atol=1e-12)
    assert (coefficients**2).sum().item() == pytest.approx((cube**2).sum().item(), rel=1e-12)
    n = 6 * size * size
    basis = torch.eye(n, dtype=torch.float64).reshape(n, 6, size, size, 1)
    matrix = torch.stack([wavelets_of(b.numpy()).reshape(-1) for b in basis[: min(n, 96)]])
    assert torch.allclose(matrix @ matrix.T, torch.eye(len(matrix), dtype=torch.float64), atol=1e-12)


@pytest.mark.parametrize("size", SIZES)
def test_a_constant_map_has_exactly_six_nonzero_coefficients(size):
    coefficients = wavelets_of(np.full((6, size, size, 3), 2.5)).reshape(-1, 3)
    nonzero = np.flatnonzero(coefficients.abs().amax(1).numpy() > 1e-12)
    assert list(nonzero) == [face * size * size for face in range(6)]
    np.testing.assert_allclose(coefficients[nonzero].numpy(), 2.5 * size)


@pytest.mark.parametrize("size", [2, 4, 8, 16, 64])
def test_texel_directions_round_trip_and_solid_angles_cover_the_sphere(size):
    assert np.array_equal(texels_of(cube_directions(size), size), np.arange(6 * size * size))
    assert cubemap_solid_angles(size, torch.float64).sum().item() == pytest.approx(4 * math.pi, rel=1e-12)


@pytest.mark.parametrize("size", [1, 8, 64])
def test_compiled_texel_lookup_is_the_torch_one(size):
    """Ties between components (cube edges and corners) go to the first largest one, as torch's argmax."""
    rng = np.random.default_rng(0)
    directions = np.concatenate(
        [rng.normal(size=(20000, 3)), np.round(rng.normal(size=(2000, 3))), np.eye(3), -np.eye(3)]
    )
    expected = direction_to_texel(torch.from_numpy(directions), size).numpy()
    assert np.array_equal(texels_of(directions, size), expected)


def test_a_rotated_map_resamples_to_the_texels_the_path_tracer_reads():
    height, width = 64, 128
    d = texel_directions(height, width)
    latlong = np.stack([1 + d[..., 0], 1 + d[..., 1] ** 2, 1 + 0.5 * d[..., 2]], axis=-1)  # smooth
    rotation = euler_xyz((20.0, 75.0, -10.0))
    cube = cube_of(latlong, rotation, 16)
    traced = EnvironmentMapLight(latlong, rotation).radiance(cube_directions(16))
    np.testing.assert_allclose(cube.reshape(-1, 3), traced, atol=0.02)


def test_cube_map_light_reads_its_nearest_texel_and_samples_everywhere():
    cube = np.zeros((6, 4, 4, 3))
    cube[3, 2, 1] = 7.0
    light = CubeMapLight(cube, EnvironmentMapLight(sampling_latlong(cube), np.eye(3)))
    directions = cube_directions(4)
    np.testing.assert_array_equal(light.radiance(directions), cube.reshape(-1, 3))
    sampled, pdf = light.sample(np.random.default_rng(0).random((4096, 2)))
    assert (pdf > 0).all()
    assert (light.radiance(sampled).max(1) > 0).mean() > 0.5  # importance sampling follows the lit texel


def test_selection_is_invariant_to_scaling_the_map():
    cube = np.random.default_rng(0).random((6, 8, 8, 3)) ** 4
    chosen, scaled = run_time_selection(cube, 20), run_time_selection(37.5 * cube, 20)
    assert torch.equal(chosen.indices, scaled.indices)
    assert torch.allclose(scaled.values, 37.5 * chosen.values)
    area = run_time_selection(cube, 6, "area")
    assert (area.face_row_col()[:, 1:] == 0).all()  # the face averages cover the most area


def test_training_selection_takes_the_largest_and_distinct_others():
    cube = np.random.default_rng(1).random((6, 4, 4, 3)) ** 4
    chosen = training_selection(ranked_wavelets(cube), 10, 20, np.random.default_rng(2))
    largest = torch.topk(wavelets_of(cube).reshape(-1, 3).norm(dim=-1), 10).indices
    assert set(largest.tolist()) <= set(chosen.indices.tolist())
    assert len(set(chosen.indices.tolist())) == 30


def _surface_inputs(n: int) -> dict[str, torch.Tensor]:
    """Random float64 network inputs of `n` pixels."""
    return {
        "position": torch.rand(n, 3, dtype=torch.float64),
        "normal": torch.nn.functional.normalize(torch.randn(n, 3, dtype=torch.float64), dim=-1),
        "reflected": torch.nn.functional.normalize(torch.randn(n, 3, dtype=torch.float64), dim=-1),
        "kd": torch.rand(n, 3, dtype=torch.float64),
        "ks": torch.rand(n, 3, dtype=torch.float64),
        "roughness": torch.rand(n, 1, dtype=torch.float64),
    }


def test_b_is_linear_in_the_lighting_for_a_fixed_selection():
    config = resolve_preset(PrtConfig, PRESETS, "quick", {})
    torch.manual_seed(0)
    model = PrtNetwork(config).double()
    inputs = _surface_inputs(16)
    wavelets = torch.tensor([0, 3, 17, 40, 95])
    l1, l2 = torch.randn(5, 3, dtype=torch.float64), torch.randn(5, 3, dtype=torch.float64)
    with torch.no_grad():
        combined = model(inputs, wavelets, 2.0 * l1 - 0.5 * l2)
        separate = 2.0 * model(inputs, wavelets, l1) - 0.5 * model(inputs, wavelets, l2)
        sun = model(inputs, wavelets, 1e5 * l1)  # a sun-sized coefficient stays finite and linear
    assert torch.allclose(combined, separate, rtol=1e-10, atol=1e-12)
    assert torch.isfinite(sun).all() and torch.allclose(sun, 1e5 * model(inputs, wavelets, l1), rtol=1e-9)


def test_the_roughness_map_spreads_near_mirror_roughness():
    sigma = torch.tensor([0.0, 1e-4, 0.05, 0.5, 1.0, 1.0 + 1e-6])
    mapped = roughness_feature(sigma)
    assert mapped[0] == 0 and mapped[4] == pytest.approx(1.0) and mapped[5] == pytest.approx(1.0)
    assert (mapped.diff() >= 0).all() and mapped[2] > 0.24  # 0.05 maps to a quarter of the range


def test_an_uploaded_map_with_nan_or_inf_is_refused_naming_the_field():
    image = np.ones((8, 16, 3), np.float32)
    image[3, 5, 1] = np.nan
    with pytest.raises(SceneError, match=r"lighting\.path: 1 NaN/Inf texels \(first at row 3, column 5\)"):
        latlong_of(EnvironmentMap(path="upload.exr"), 64, "lighting", image)
    with pytest.raises(SceneError, match=r"lighting\.builtin: unknown built-in map 'moon'"):
        latlong_of(EnvironmentMap(builtin="moon"), 64)


def test_the_split_first_layer_equals_f_of_the_cp_features():
    config = resolve_preset(PrtConfig, PRESETS, "quick", {})
    torch.manual_seed(1)
    model = PrtNetwork(config).double()
    spatial, rest = torch.randn(5, 8, dtype=torch.float64), torch.randn(5, 19, dtype=torch.float64)
    wavelets = torch.tensor([1, 7, 30])
    h = model.mix(spatial[:, None, :] * model.wavelet_factors[wavelets][None])  # Eq. 7 as written
    explicit = model.f(torch.cat([h, rest[:, None, :].expand(-1, 3, -1)], dim=-1))
    assert torch.allclose(model.transport(spatial, rest, wavelets), explicit, atol=1e-12)


def test_training_transport_of_pixel_groups_in_chunks_is_each_pixel_s_cp_features_through_f(monkeypatch):
    """Groups of 3 and 2 pixels, each with its own wavelets, through f 2 pixels at a time (a chunk never
    spans two groups): each pixel's T equals Eq. 7 as written through its group's wavelets."""
    monkeypatch.setattr(network, "CPU_CHUNK_BYTES", 2 * 3 * 32 * 8)  # 2 pixels x 3 wavelets of quick's f
    config = resolve_preset(PrtConfig, PRESETS, "quick", {})
    torch.manual_seed(4)
    model = PrtNetwork(config).double()
    torch.nn.init.normal_(model.f.layers[-2].weight)
    spatial, rest = torch.randn(5, 8, dtype=torch.float64), torch.randn(5, 19, dtype=torch.float64)
    groups = torch.tensor([[1, 7, 30], [0, 2, 50]])
    transport = model.transport(spatial, rest, groups, [3, 2])
    for p, group in enumerate([0, 0, 0, 1, 1]):
        h = model.mix(spatial[p] * model.wavelet_factors[groups[group]])
        explicit = model.f(torch.cat([h, rest[p].expand(3, -1)], dim=-1))
        assert torch.allclose(transport[p], explicit, atol=1e-12)


def test_b_in_chunks_of_pixels_equals_eq_3_over_all_pixels_at_once(monkeypatch):
    # 16 pairs of quick f's 32 float64s a chunk: 3 pixels, so 6 chunks, the last short
    monkeypatch.setattr(network, "CPU_CHUNK_BYTES", 16 * 32 * 8)
    config = resolve_preset(PrtConfig, PRESETS, "quick", {})
    torch.manual_seed(2)
    model = PrtNetwork(config).double()
    torch.nn.init.normal_(model.f.layers[-2].weight)  # not the zero start: T must differ per pixel
    inputs = _surface_inputs(16)
    wavelets, coefficients = torch.tensor([2, 9, 33, 60, 77]), torch.randn(5, 3, dtype=torch.float64)
    with torch.no_grad():
        spatial, rest = model.pixel_features(inputs)
        whole = torch.einsum("pkc,kc->pc", model.transport(spatial, rest, wavelets), coefficients)
        chunked = model(inputs, wavelets, coefficients)
    assert whole.abs().min() > 0 and torch.allclose(chunked, whole, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("native", [False, True])
def test_bfloat16_products_stay_within_a_fraction_of_a_percent_and_only_where_native(monkeypatch, native):
    monkeypatch.setattr(network, "native_bfloat16", lambda device: native)
    config = resolve_preset(PrtConfig, PRESETS, "default", {})
    torch.manual_seed(3)
    model = PrtNetwork(config)
    torch.nn.init.normal_(model.f.layers[-2].weight, std=0.1)
    inputs = {name: value.float() for name, value in _surface_inputs(300).items()}
    wavelets, coefficients = torch.arange(0, 320, 5), torch.randn(64, 3)
    with torch.no_grad():
        model.bfloat16 = False
        exact = model(inputs, wavelets, coefficients)
        model.bfloat16 = True
        fast = model(inputs, wavelets, coefficients)
    error = float((fast - exact).norm() / exact.norm())
    assert (0 < error < 5e-3) if native else error == 0


def test_pixels_that_see_the_environment_get_no_indirect_light():
    from workers.models.prt.frame import predict_indirect
    from workers.models.prt.gbuffer import SurfaceInputs

    config = resolve_preset(PrtConfig, PRESETS, "quick", {})
    model = PrtNetwork(config)
    torch.nn.init.normal_(model.f.layers[-2].weight)  # a network that predicts something everywhere
    n = 6
    inputs = SurfaceInputs(
        hit=np.array([True, False, True, False, True, True]), position=np.zeros((n, 3)),
        normal=np.tile([0.0, 1.0, 0.0], (n, 1)), reflected=np.tile([0.0, 1.0, 0.0], (n, 1)),
        kd=np.full((n, 3), 0.5), ks=np.zeros((n, 3)), roughness=np.ones(n),
        object_id=np.array([0, -1, 0, -1, 1, 0]),
    )  # fmt: skip
    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    out, _ = predict_indirect(model, inputs, box, np.array([0]), np.ones((6, 4, 4, 3)), 8, "area")
    assert (out[[1, 3]] == 0).all()  # the environment, seen directly: masked
    assert (out[4] == 0).all()  # an object left to direct light
    assert (out[[0, 2, 5]] != 0).any(axis=1).all()


def test_the_targets_haar_coefficients_dotted_with_the_lighting_s_equal_the_rows_dotted_with_it(monkeypatch):
    """Training reads targets and per-wavelet transport off the rows' Haar coefficients, computed once a
    chunk at a time (3 rows here, the last chunk short) in float64 and kept in float32."""
    from workers.models.prt import data

    monkeypatch.setattr(data, "MAP_CHUNK", 3)
    rng = np.random.default_rng(3)
    rows, cube = rng.random((7, 6 * 4 * 4, 3)).astype(np.float32), rng.random((6, 4, 4, 3)) ** 3
    per_wavelet = data._row_wavelets(rows, 4, out=None)
    assert per_wavelet.dtype == np.float32 and per_wavelet.shape == rows.shape
    lighting = wavelets_of(cube).reshape(-1, 3).numpy()
    np.testing.assert_allclose(  # Eq. 3 with every wavelet against the row's dot product in texels
        np.einsum("pkc,kc->pc", per_wavelet.astype(np.float64), lighting),
        np.einsum("pjc,jc->pc", rows.astype(np.float64), cube.reshape(-1, 3)),
        rtol=1e-6,
    )
    for row, coefficients in zip(rows, per_wavelet, strict=True):  # each row's own transform, face by face
        np.testing.assert_allclose(
            coefficients, wavelets_of(row.reshape(6, 4, 4, 3)).reshape(-1, 3), rtol=1e-6, atol=1e-7
        )
    in_place = rows.copy()
    assert data._row_wavelets(in_place, 4, out=in_place) is in_place
    assert np.array_equal(in_place, per_wavelet)


def _points_on_a_line(n: int):
    from workers.models.prt.gbuffer import SurfaceInputs

    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    position = np.zeros((n, 3))
    position[:, 0] = 0.1 * np.arange(n)
    inputs = SurfaceInputs(
        hit=np.ones(n, bool), position=position, normal=up, reflected=up, kd=np.full((n, 3), 0.5),
        ks=np.zeros((n, 3)), roughness=np.ones(n), object_id=np.arange(n) % 2,
    )  # fmt: skip
    return inputs, np.array([[0.0, -1.0, -1.0], [0.1 * n, 1.0, 1.0]])


def test_nearest_rows_are_on_the_row_s_own_object():
    from workers.models.prt.neighbours import nearest_rows

    inputs, box = _points_on_a_line(12)  # two objects, alternating along the line
    found = nearest_rows(inputs, inputs, box, np.array([0, 1]), 3)
    assert [len(pixels) for pixels, _ in found] == [6, 6]
    for pixels, nearest in found:
        assert nearest.shape == (6, 3)
        assert (inputs.object_id[nearest] == inputs.object_id[pixels, None]).all()
        for i, row in zip(pixels, nearest, strict=True):
            if 2 <= i < 10:  # away from the ends: the row and the next ones of its object on either side
                assert set(row) == {i - 2, i, i + 2}
    # an object with fewer rows than k: every row of it
    lonely = nearest_rows(inputs, inputs, box, np.array([0]), 8)
    assert [set(row) for row in lonely[0][1]] == [set(range(0, 12, 2))] * 6


def test_training_targets_are_the_mean_of_each_object_s_chosen_nearest_rows():
    from workers.models.prt.data import TrainingSet, _row_wavelets
    from workers.models.prt.neighbours import smoothed_rows

    inputs, box = _points_on_a_line(12)
    rows = np.random.default_rng(4).random((12, 6 * 2 * 2, 3)).astype(np.float32)
    maps = {"uniform": np.ones(12)}
    picked = np.array([3, 3, 8, 11])
    choices = {0: (3, 0.03), 1: (3, 0.03)}
    smoothed = smoothed_rows(inputs, rows, box, choices)
    targets = TrainingSet(inputs, rows, box, maps, _row_wavelets(smoothed, 2, None), choices).targets(picked)
    assert targets.shape == (4, 24, 3) and targets.dtype == np.float64
    nearest = {3: [1, 3, 5], 8: [6, 8, 10], 11: [7, 9, 11]}  # on the row's object, along the line
    for target, i in zip(targets, picked, strict=True):  # as Haar coefficients
        mean = wavelets_of(rows[nearest[i]].mean(0).reshape(6, 2, 2, 3)).reshape(-1, 3).numpy()
        np.testing.assert_allclose(target, mean, rtol=1e-6, atol=1e-7)
    mixed = smoothed_rows(inputs, rows, box, {0: (1, 0.03), 1: (3, 0.03)})  # object 0 (even rows): itself
    assert (mixed[8] == rows[8]).all()
    np.testing.assert_allclose(mixed[3], rows[[1, 3, 5]].mean(0), rtol=1e-6)
    assert smoothed_rows(inputs, rows, box, {0: (1, 0.0), 1: (1, 0.0)}) is rows  # k = 1: the traced rows


def test_leave_one_out_averages_noise_widely_and_sharp_transport_narrowly():
    """Object 0's rows are one transport plus noise (no blur bias: the most rows win); object 1's change
    quickly along the line without noise (any blur is error: the fewest rows win)."""
    from workers.models.prt.neighbours import CANDIDATE_NEIGHBOURS, smoothing_choices

    inputs, box = _points_on_a_line(400)
    rng = np.random.default_rng(6)
    x = inputs.position[:, :1, None]
    rows = np.where(
        (inputs.object_id == 0)[:, None, None],
        0.02 + 0.01 * rng.standard_normal((400, 24, 3)),
        0.02 * (1 + np.sin(2.0 * x)) * np.ones((1, 24, 3)),
    ).astype(np.float32)
    cubes = rng.uniform(0.2, 1.0, (4, 24, 3))
    choices = smoothing_choices(inputs, rows, box, 128, cubes, rng)
    assert choices[0][0] == 128 and choices[1][0] == CANDIDATE_NEIGHBOURS[0]
    assert smoothing_choices(inputs, rows, box, 32, cubes, rng)[0][0] == 32  # at most `most` rows


def test_a_batch_of_several_lightings_lights_each_pixel_group_through_its_own_wavelets():
    from workers.models.prt.train import prt_loss
    from workers.nn.losses import mu_law_l2

    config = resolve_preset(PrtConfig, PRESETS, "quick", {})
    torch.manual_seed(2)
    model = PrtNetwork(config)
    for parameter in model.parameters():  # a network whose every wavelet gives a different transport
        torch.nn.init.normal_(parameter, std=0.5)
    n = 5  # pixels: 3 in the first group (it takes the remainder), 2 in the second
    batch = {
        "position": torch.rand(n, 3), "normal": torch.tensor([[0.0, 1.0, 0.0]]).repeat(n, 1),
        "reflected": torch.nn.functional.normalize(torch.randn(n, 3), dim=-1), "kd": torch.rand(n, 3),
        "ks": torch.rand(n, 3), "roughness": torch.rand(n, 1),
        "wavelets": torch.tensor([[0, 3, 9], [1, 20, 40]]), "coefficients": torch.randn(2, 3, 3),
        "target": torch.rand(n, 3),
    }  # fmt: skip
    with torch.no_grad():
        spatial, rest = model.pixel_features(batch)
        first = model.transport(spatial[:3], rest[:3], batch["wavelets"][0])
        second = model.transport(spatial[3:], rest[3:], batch["wavelets"][1])
        expected = mu_law_l2(
            torch.cat(
                [
                    torch.einsum("pkc,kc->pc", first, batch["coefficients"][0]),
                    torch.einsum("pkc,kc->pc", second, batch["coefficients"][1]),
                ]
            ),
            batch["target"],
        )
        assert torch.allclose(prt_loss(model, batch), expected, rtol=1e-6)


def test_a_pooled_batch_lights_each_group_by_one_lighting_of_a_pool_built_once():
    from workers.models.prt.source import PrtSource, PrtSourceConfig, lighting_pool
    from workers.scene.generators.builtin import get_builtin
    from workers.scene.portability.reference import SceneRef

    config = resolve_preset(PrtConfig, PRESETS, "quick", {"lighting_pool": 3, "lightings_per_step": 4})
    source = PrtSource(PrtSourceConfig(SceneRef(get_builtin("env_lit_objects")), config), seed=0)
    assert lighting_pool(config, 0) is source.pool  # built once per process
    batch = source.batch(5)
    for wavelets, coefficients in zip(batch["wavelets"], batch["coefficients"], strict=True):
        assert any(torch.allclose(p.coefficients[wavelets].float(), coefficients) for p in source.pool)


@pytest.mark.parametrize(("sampler", "most"), [("independent", 0.5), ("stratified", 0.95)])
def test_the_denoised_direct_light_is_closer_to_a_converged_one(monkeypatch, sampler, most):
    """The frame's direct light at 8 spp, filtered, against 512 spp: at most half the raw squared error where
    the filter acts (away from silhouettes) with independent samples; stratified raw light under this
    uniform lighting is far less noisy (its error was 0.00097, the filtered one 0.00088), and the filter
    still lowers it. Pixels that see the environment are not filtered."""
    from workers.models.prt import frame
    from workers.models.prt.frame import direct_light
    from workers.models.prt.gbuffer import surface_inputs
    from workers.models.prt.lighting import relit_tracer, uniform_cube
    from workers.models.prt.views import pixel_rays
    from workers.render.denoise import interior
    from workers.scene.generators.builtin import get_builtin
    from workers.scene.geometry.compile import compile_scene

    monkeypatch.setattr(frame, "SAMPLER", sampler)
    spec = get_builtin("env_lit_objects")
    tracer = relit_tracer(compile_scene(spec), uniform_cube(4))
    camera = spec.camera.model_copy(update={"width": 24, "height": 24})
    inputs = surface_inputs(tracer, *pixel_rays(camera))
    raw, denoised = (direct_light(tracer, camera, inputs, 8, 0, 1, d)[0] for d in (False, True))
    reference, _ = direct_light(tracer, camera, inputs, 512, 1, 1, False)
    hit = inputs.hit.reshape(24, 24)
    filtered = interior(hit, inputs.object_id.reshape(24, 24))
    error = lambda image: float(((image - reference)[filtered] ** 2).mean())  # noqa: E731
    assert error(denoised) < most * error(raw)
    escaped = ~hit
    assert escaped.any()
    np.testing.assert_allclose(denoised[escaped], reference[escaped], rtol=1e-5)


def test_training_views_spread_over_the_band_towards_the_far_helix_without_moving_test_views():
    base = Camera(position=(0.0, 1.0, 5.0), target=(0.0, 0.0, 0.0), width=8, height=8)
    helix = trajectory_cameras(base, CamerasConfig(train_band=0.0), 8)
    band = trajectory_cameras(base, CamerasConfig(train_band=1.0), 8)

    def distances(cameras):
        return np.array([np.linalg.norm(c.position) for c in cameras])

    d = np.linalg.norm(base.position)
    assert np.allclose(distances(helix["train"]), d)
    spread = distances(band["train"])
    assert spread.max() == pytest.approx(d) and spread.min() < 0.85 * d  # reaches towards 0.8 d
    assert np.all(spread >= 0.8 * d - 1e-9)
    for split in ("near", "far"):
        assert [c.position for c in band[split]] == [c.position for c in helix[split]]
