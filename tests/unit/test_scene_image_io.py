"""EXR and PNG I/O: exact float32 round trips, channel layouts, the documented sRGB tonemap."""

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from workers.scene.importers.image_io import (
    linear_to_srgb,
    read_exr,
    read_exr_channels,
    srgb_to_linear,
    tonemap,
    write_exr,
    write_png,
)


def test_rgb_exr_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    image = (rng.standard_normal((7, 11, 3)) * 1e3).astype(np.float32)
    image[0, 0] = [0.0, 65504.0 * 8, 1e-30]
    write_exr(tmp_path / "a.exr", image)
    back = read_exr(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == image.shape
    np.testing.assert_array_equal(back, image)


def test_grey_and_extra_layers_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    grey = rng.random((5, 4)).astype(np.float32)
    normal = rng.random((5, 4, 3)).astype(np.float32)
    depth = rng.random((5, 4, 1)).astype(np.float32)
    write_exr(tmp_path / "g.exr", grey, channels={"normal": normal, "depth": depth})
    layers = read_exr_channels(tmp_path / "g.exr")
    np.testing.assert_array_equal(layers["Y"], grey)
    np.testing.assert_array_equal(layers["normal"], normal)
    np.testing.assert_array_equal(layers["depth"], depth[..., 0])
    np.testing.assert_array_equal(read_exr(tmp_path / "g.exr"), np.repeat(grey[..., None], 3, axis=2))


def test_half_float_rgba_is_read_as_float32_rgb(tmp_path):
    rgba = np.random.default_rng(2).random((3, 6, 4)).astype(np.float16)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGBA": rgba}).write(str(tmp_path / "h.exr"))
    back = read_exr(tmp_path / "h.exr")
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, rgba[..., :3].astype(np.float32))


def test_bad_inputs_raise_clear_errors(tmp_path):
    (tmp_path / "bad.exr").write_bytes(b"not an exr at all")
    with pytest.raises(ValueError, match="OpenEXR"):
        read_exr(tmp_path / "bad.exr")
    with pytest.raises(FileNotFoundError):
        read_exr(tmp_path / "missing.exr")
    with pytest.raises(ValueError, match="shape"):
        write_exr(tmp_path / "x.exr", np.zeros((4, 4, 2)))
    with pytest.raises(ValueError, match="reserved"):
        write_exr(tmp_path / "x.exr", np.zeros((4, 4, 3)), channels={"RGB": np.zeros((4, 4, 3))})
    with pytest.raises(ValueError, match="is \\(2, 2\\)"):
        write_exr(tmp_path / "x.exr", np.zeros((4, 4, 3)), channels={"depth": np.zeros((2, 2))})


def test_tonemap_known_values():
    linear = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0, 4.0, -1.0])
    expected = [0, 10, 118, 188, 255, 255, 0]  # round(255 * sRGB OETF(clamp(x)))
    np.testing.assert_array_equal(tonemap(linear), expected)
    np.testing.assert_array_equal(tonemap(np.array([0.25]), exposure=1.0), tonemap(np.array([0.5])))
    np.testing.assert_array_equal(tonemap(np.array([np.nan, np.inf, -np.inf])), [0, 255, 0])


def test_srgb_transfer_functions_invert():
    x = np.linspace(0.0, 1.0, 1001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)


def test_png_is_8_bit_srgb(tmp_path):
    image = np.zeros((2, 3, 3), dtype=np.float32)
    image[0, 0] = [0.5, 0.18, 1.0]
    write_png(tmp_path / "p.png", image)
    with Image.open(tmp_path / "p.png") as png:
        assert png.mode == "RGB" and png.size == (3, 2)
        np.testing.assert_array_equal(np.asarray(png)[0, 0], [188, 118, 255])
    write_png(tmp_path / "grey.png", np.full((2, 2), 0.5))
    with Image.open(tmp_path / "grey.png") as png:
        assert png.mode == "L" and np.asarray(png)[0, 0] == 188
