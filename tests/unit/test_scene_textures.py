"""Textures: sRGB-decoded 8-bit images, linear EXR, bilinear repeat lookups, procedural checkers."""

import numpy as np
import pytest
from PIL import Image

from tests.support.hostile_inputs import png_header
from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.importers import textures
from workers.scene.importers.image_io import srgb_to_linear, write_exr
from workers.scene.importers.textures import (
    MAX_TEXTURE_PIXELS,
    check_texture_size,
    evaluate_texture,
    load_image_texture,
)


def test_png_is_decoded_from_srgb_to_linear(tmp_path):
    pixels = np.array([[[0, 128, 255], [188, 10, 50]]], dtype=np.uint8)
    Image.fromarray(pixels).save(tmp_path / "t.png")
    image = load_image_texture(spec.ImageTexture(path="t.png"), "materials.m.reflectance", tmp_path)
    assert image.dtype == np.float32 and image.shape == (1, 2, 3)
    np.testing.assert_allclose(image, srgb_to_linear(pixels / 255.0), rtol=1e-6)
    assert image[0, 1, 0] == pytest.approx(0.5, abs=3e-3)


def test_exr_texture_is_linear(tmp_path):
    data = np.random.default_rng(0).random((3, 5, 3)).astype(np.float32)
    write_exr(tmp_path / "t.exr", data)
    np.testing.assert_array_equal(load_image_texture(spec.ImageTexture(path="t.exr"), "f", tmp_path), data)


def test_missing_or_unreadable_texture_names_the_path_field(tmp_path):
    with pytest.raises(SceneError, match="not found") as caught:
        load_image_texture(spec.ImageTexture(path="no.png"), "materials.wood.reflectance", tmp_path)
    assert caught.value.field == "materials.wood.reflectance.path"
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(SceneError, match="cannot read texture"):
        load_image_texture(spec.ImageTexture(path="bad.png"), "m", tmp_path)


def test_bilinear_lookup_hits_texel_centres_and_interpolates_between_them():
    image = np.arange(2 * 4 * 3, dtype=np.float32).reshape(2, 4, 3)
    tex = spec.ImageTexture(path="unused.png")
    centres = np.array([[(0 + 0.5) / 4, (0 + 0.5) / 2], [(3 + 0.5) / 4, (1 + 0.5) / 2]])
    np.testing.assert_allclose(evaluate_texture(tex, image, centres), [image[0, 0], image[1, 3]])
    between = evaluate_texture(tex, image, np.array([[1.0 / 4, 0.25]]))  # halfway between columns 0 and 1
    np.testing.assert_allclose(between[0], (image[0, 0] + image[0, 1]) / 2)


def test_lookup_repeats_and_survives_non_finite_uvs():
    image = np.random.default_rng(1).random((5, 7, 3)).astype(np.float32)
    tex = spec.ImageTexture(path="unused.png")
    uv = np.random.default_rng(2).random((100, 2))
    base = evaluate_texture(tex, image, uv)
    np.testing.assert_allclose(evaluate_texture(tex, image, uv + np.array([3.0, -2.0])), base, atol=1e-5)
    # across the wrap, u = 0 blends the first and last columns
    edge = evaluate_texture(tex, image, np.array([[0.0, 0.5 / 5]]))
    np.testing.assert_allclose(edge[0], (image[0, 0] + image[0, -1]) / 2, rtol=1e-6)
    weird = evaluate_texture(tex, image, np.array([[np.nan, 0.5], [np.inf, 1e300]]))
    assert np.isfinite(weird).all()


def test_checker_and_constant_colours():
    checker = spec.CheckerTexture(color0=(1, 0, 0), color1=(0, 0, 1), scale=2.0)
    uv = np.array([[0.1, 0.1], [0.6, 0.1], [0.6, 0.6], [-0.1, 0.1], [1e20, 0.1]])
    got = evaluate_texture(checker, None, uv)
    np.testing.assert_array_equal(got[:4], [[1, 0, 0], [0, 0, 1], [1, 0, 0], [0, 0, 1]])
    assert np.isin(got[4], [0.0, 1.0]).all()
    constant = evaluate_texture((0.2, 0.3, 0.4), None, uv)
    assert constant.shape == (5, 3) and np.allclose(constant, [0.2, 0.3, 0.4])


def test_clamp_and_mirror_wrap_as_gltf_samplers_do():
    image = np.arange(4 * 3, dtype=np.float32).reshape(1, 4, 3)
    centre = lambda column: (column + 0.5) / 4  # noqa: E731
    v = 0.5
    clamp = spec.ImageTexture(path="unused.png", wrap_u="clamp")
    uv = np.array([[-3.0, v], [0.0, v], [1.0, v], [7.5, v], [centre(1), v]])
    np.testing.assert_allclose(evaluate_texture(clamp, image, uv), image[0, [0, 0, 3, 3, 1]])
    mirror = spec.ImageTexture(path="unused.png", wrap_u="mirror")
    # mirrored repeat: [1, 2) reads the image backwards, [2, 3) forwards again; -u reads as u
    np.testing.assert_allclose(evaluate_texture(mirror, image, np.array([[1 + centre(0), v]])), [image[0, 3]])
    np.testing.assert_allclose(evaluate_texture(mirror, image, np.array([[2 + centre(1), v]])), [image[0, 1]])
    np.testing.assert_allclose(evaluate_texture(mirror, image, np.array([[-centre(2), v]])), [image[0, 2]])
    # at the mirror's seam the edge texel is its own neighbour: no blend with the far edge (repeat blends)
    np.testing.assert_allclose(evaluate_texture(mirror, image, np.array([[1.0, v]])), [image[0, 3]])
    repeat = spec.ImageTexture(path="unused.png")
    np.testing.assert_allclose(
        evaluate_texture(repeat, image, np.array([[1.0, v]])), [(image[0, 0] + image[0, 3]) / 2]
    )


@pytest.mark.parametrize("color_space", ["srgb", "linear"])
def test_declared_colour_space_decides_the_decoding(tmp_path, color_space):
    pixels = np.array([[[0, 128, 255]]], dtype=np.uint8)
    Image.fromarray(pixels).save(tmp_path / "t.png")
    image = load_image_texture(spec.ImageTexture(path="t.png", color_space=color_space), "m", tmp_path)
    expected = pixels / 255.0 if color_space == "linear" else srgb_to_linear(pixels / 255.0)
    np.testing.assert_allclose(image, expected, rtol=1e-6)


def test_a_texture_declaring_too_many_pixels_is_refused_before_it_is_decoded(tmp_path):
    (tmp_path / "big.png").write_bytes(png_header(100_000, 100_000))
    texture = spec.ImageTexture(path="big.png")
    for check in (load_image_texture, check_texture_size):
        with pytest.raises(
            SceneError, match=f"big.png is over the limit of {MAX_TEXTURE_PIXELS:,} pixels"
        ) as caught:
            check(texture, "materials.m.reflectance", tmp_path)
        assert caught.value.field == "materials.m.reflectance.path"


def test_an_exr_is_refused_from_its_header_before_it_is_read(tmp_path, monkeypatch):
    write_exr(tmp_path / "wide.exr", np.zeros((1, 8, 3), np.float32))
    monkeypatch.setattr(textures, "MAX_TEXTURE_PIXELS", 7)
    with pytest.raises(SceneError, match=r"wide\.exr is 8 x 1 pixels, over the limit") as caught:
        load_image_texture(spec.ImageTexture(path="wide.exr"), "materials.m.reflectance", tmp_path)
    assert caught.value.field == "materials.m.reflectance.path"
