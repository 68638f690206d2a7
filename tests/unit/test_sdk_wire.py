"""The SDK's side of the inference service's formats against the server's: binary bodies encoded by one
are decoded by the other to the same arrays, and the SDK's NumPy-only EXR reader gives back what the
server's OpenEXR writer wrote (RGB and single-channel, compressible and not)."""

from __future__ import annotations

import numpy as np
import pytest
from neuralbake_client.answers import EXR, PNG, RenderedImage, frame_time
from neuralbake_client.arrays import decode_binary, encode_binary
from neuralbake_client.client import default_inference_url, json_value
from neuralbake_client.errors import NeuralbakeError

from services.inference import images, wire

ARRAYS = {
    "origins": np.arange(12, dtype=np.float64).reshape(4, 3) / 7,
    "pixels": np.array([[0, 1], [31, 23]], np.int64),
    "hit": np.array([True, False, True]),
    "half": np.array([0.5, -2.0], np.float16),
    "big_endian": np.array([1.5, 2.5], ">f4"),
    "empty": np.zeros((0, 3), np.float32),
}


def test_sdk_request_bodies_decode_on_the_server():
    params, arrays = wire.decode_binary(encode_binary({"params": {"layers": ["image"]}}, ARRAYS))
    assert params == {"layers": ["image"]} and list(arrays) == list(ARRAYS)
    for name, array in ARRAYS.items():
        assert arrays[name].dtype == array.dtype.newbyteorder("=") and arrays[name].shape == array.shape
        np.testing.assert_array_equal(arrays[name], array)


def test_server_answers_decode_in_the_sdk():
    head, arrays = decode_binary(
        wire.encode_binary({"artifact_id": "a", "kind": "lsnif", "meta": {}}, ARRAYS)
    )
    assert head == {"artifact_id": "a", "kind": "lsnif", "meta": {}}
    for name, array in ARRAYS.items():
        np.testing.assert_array_equal(arrays[name], array)
        arrays[name][...] = 0  # the SDK's arrays are the caller's to change
    with pytest.raises(NeuralbakeError, match="fewer bytes"):
        decode_binary(wire.encode_binary({}, {"x": np.zeros(4)})[:-1])


@pytest.mark.parametrize(
    "image",
    [
        np.random.default_rng(1).random((37, 50, 3), np.float32),  # noise: ZIP chunks stored raw
        np.tile(np.linspace(0, 4, 64, dtype=np.float32)[None, :, None], (33, 1, 3)),  # compresses well
        np.random.default_rng(2).random((9, 7, 1), np.float32),  # one channel, written as Y
    ],
)
def test_exr_reader_reads_what_the_server_writes(image):
    rendered = RenderedImage("sha256:x", EXR, images.encode(image, images.EXR))
    np.testing.assert_array_equal(rendered.pixels(), image)
    with pytest.raises(NeuralbakeError, match="decodes image/x-exr"):
        RenderedImage("sha256:x", PNG, images.encode(image, images.PNG)).pixels()


def test_frame_time_inference_url_and_json_params():
    assert frame_time("db;dur=3, frame;dur=12.5;desc=render") == pytest.approx(0.0125)
    assert frame_time(None) is None and frame_time("frame") is None
    assert default_inference_url("http://10.0.0.2:8080/") == "http://10.0.0.2:8090"
    assert default_inference_url("grpcs://[::1]:50051") == "grpcs://[::1]:50052"
    camera = {"position": np.array([0.0, 1.0, 4.0]), "fov": np.float32(40), "width": 64}
    assert json_value(camera) == {"position": [0.0, 1.0, 4.0], "fov": 40.0, "width": 64}
