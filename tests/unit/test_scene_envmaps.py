"""Environment maps: the lat-long convention, procedural maps, built-in HDRIs and rejected inputs."""

import numpy as np
import pytest

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.generators.envmaps import (
    builtin_environment_names,
    check_environment,
    direction_to_uv,
    load_environment,
    sun_direction,
    texel_directions,
    texel_solid_angles,
    uv_to_direction,
)
from workers.scene.importers.image_io import write_exr

BUILTIN_HDRIS = ["city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset"]


def test_convention_matches_mitsuba():
    d = np.array([[0, 0, -1], [1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=np.float64)
    uv = direction_to_uv(d)
    np.testing.assert_allclose(uv[:4], [[0.0, 0.5], [0.25, 0.5], [0.5, 0.5], [0.75, 0.5]], atol=1e-15)
    np.testing.assert_allclose(uv[4:, 1], [0.0, 1.0])


def test_direction_uv_round_trip_is_exact_to_rounding():
    rng = np.random.default_rng(0)
    d = rng.standard_normal((100_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    uv = direction_to_uv(d)
    assert ((uv >= 0) & (uv < 1) | (uv[:, 1:] == 1.0)).all()
    np.testing.assert_allclose(uv_to_direction(uv[:, 0], uv[:, 1]), d, atol=1e-12)
    u = rng.uniform(0, 1, 10_000)
    v = rng.uniform(1e-6, 1 - 1e-6, 10_000)
    np.testing.assert_allclose(direction_to_uv(uv_to_direction(u, v)), np.stack([u, v], 1), atol=1e-10)


def test_seam_and_unnormalised_inputs_stay_in_range():
    just_left_of_seam = np.array([[-1e-18, 0.0, -1.0], [-5.0, 0.0, -1e-300], [0.0, 0.0, 0.0]])
    uv = direction_to_uv(just_left_of_seam)
    assert np.isfinite(uv).all() and (uv[:, 0] < 1.0).all() and (uv[:, 0] >= 0.0).all()


def test_texel_solid_angles_cover_the_sphere():
    assert texel_solid_angles(64, 128).sum() * 128 == pytest.approx(4 * np.pi)
    d = texel_directions(4, 8)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    np.testing.assert_allclose(direction_to_uv(d)[0, 0], [0.5 / 8, 0.5 / 4])


def test_sky_puts_a_sun_of_the_requested_irradiance_where_asked():
    params = {
        "sun_elevation": 30.0,
        "sun_azimuth": 120.0,
        "sun_irradiance": 50.0,
        "width": 256,
        "height": 128,
    }
    image = load_environment(spec.EnvironmentMap(procedural="sky", params=params), "environment", None)
    assert image.shape == (128, 256, 3) and image.dtype == np.float32
    row, column = np.unravel_index(np.argmax(image.sum(axis=2)), image.shape[:2])
    texel = uv_to_direction((column + 0.5) / 256, (row + 0.5) / 128)
    assert texel @ sun_direction(30.0, 120.0) > np.cos(np.radians(2.0))
    no_sun = load_environment(
        spec.EnvironmentMap(procedural="sky", params=params | {"sun_irradiance": 0.0}), "environment", None
    )
    sun = (image - no_sun).mean(axis=2) / np.mean([1.0, 0.92, 0.8])
    assert (sun * texel_solid_angles(128, 256)[:, None]).sum() == pytest.approx(50.0, rel=1e-5)
    assert no_sun[: 64 - 1].min() > 0.1  # the sky above the horizon is lit


def test_studio_is_seeded_dim_with_bright_softboxes():
    def studio(seed):
        return load_environment(spec.EnvironmentMap(procedural="studio", params={"seed": seed}), "env", None)

    a, b = studio(4), studio(5)
    np.testing.assert_array_equal(a, studio(4))
    assert not np.array_equal(a, b)
    assert a.shape == (256, 512, 3)
    assert np.median(a) < 0.1 and a.max() > 3.0
    assert ((a.max(axis=2) > 1.0).mean()) < 0.25  # lights are a small part of the sphere


@pytest.mark.parametrize("name", BUILTIN_HDRIS)
def test_builtin_hdris_load_clean(name):
    image = load_environment(spec.EnvironmentMap(builtin=name), "environment", None)
    assert image.shape == (512, 1024, 3) and image.dtype == np.float32
    assert np.isfinite(image).all() and image.min() >= 0.0 and image.max() > 1.0


def test_builtin_list_is_the_shipped_files():
    assert builtin_environment_names() == BUILTIN_HDRIS


def test_exr_path_resolves_against_the_scene_folder(tmp_path):
    image = np.random.default_rng(0).random((8, 16, 3)).astype(np.float32)
    write_exr(tmp_path / "env.exr", image)
    loaded = load_environment(spec.EnvironmentMap(path="env.exr"), "environment", tmp_path)
    np.testing.assert_array_equal(loaded, image)


def _error(env, base_dir=None) -> SceneError:
    with pytest.raises(SceneError) as caught:
        load_environment(env, "environment", base_dir)
    return caught.value


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_texels_are_rejected(tmp_path, bad):
    image = np.ones((8, 16, 3), dtype=np.float32)
    image[3, 5, 1] = bad
    write_exr(tmp_path / "bad.exr", image)
    error = _error(spec.EnvironmentMap(path="bad.exr"), tmp_path)
    assert error.field == "environment.path"
    assert "NaN/Inf texels" in error.problem and "row 3, column 5" in error.problem


def test_negative_texels_are_rejected_but_compression_ringing_is_clamped(tmp_path):
    image = np.ones((8, 16, 3), dtype=np.float32)
    image[1, 2, 0] = -0.5
    write_exr(tmp_path / "neg.exr", image)
    assert "negative" in _error(spec.EnvironmentMap(path="neg.exr"), tmp_path).problem
    image[1, 2, 0] = -0.001
    write_exr(tmp_path / "ring.exr", image)
    assert load_environment(spec.EnvironmentMap(path="ring.exr"), "environment", tmp_path).min() == 0.0


def test_other_bad_sources_name_their_field(tmp_path):
    (tmp_path / "junk.exr").write_bytes(b"junk")
    cases = [
        (spec.EnvironmentMap(path="missing.exr"), "environment.path", "not found"),
        (spec.EnvironmentMap(path="junk.exr"), "environment.path", "OpenEXR"),
        (spec.EnvironmentMap(builtin="moon"), "environment.builtin", "unknown built-in map 'moon'"),
        (spec.EnvironmentMap(procedural="aurora"), "environment.procedural", "unknown procedural map"),
        (spec.EnvironmentMap(procedural="sky", params={"width": 1}), "environment.params.width", "greater"),
        (spec.EnvironmentMap(procedural="sky", params={"sun": 1}), "environment.params.sun", "Extra inputs"),
        (
            spec.EnvironmentMap(builtin="night", params={"seed": 1}),
            "environment.params",
            "only to procedural",
        ),
    ]
    for env, field, problem in cases:
        error = _error(env, tmp_path)
        assert (error.field, problem in error.problem) == (field, True), error


def test_wrong_shape_is_rejected(tmp_path):
    write_exr(tmp_path / "grey.exr", np.ones((4, 8), dtype=np.float32))  # grey is fine: read as RGB
    assert load_environment(spec.EnvironmentMap(path="grey.exr"), "e", tmp_path).shape == (4, 8, 3)
    with pytest.raises(SceneError, match="shape"):
        check_environment(np.ones((4, 8, 4)), "environment.path")
