"""Array headers an attacker writes: absurd or non-integer dimensions are a 400 naming the array, never a
ValueError from NumPy (which the service answered as 500 / gRPC INTERNAL)."""

import pytest

from services.inference.errors import MalformedBody
from services.inference.wire import decode_binary


@pytest.mark.parametrize(
    "shape",
    ["[0, 1e30]", "[0, 1000000000000000000000000000000]", "[1.5]", "[-1]", "[true]", "[1,1,1,1,1,1,1,1,1]"],
)
def test_absurd_dimensions_are_malformed_bodies(shape):
    header = '{"params": {}, "arrays": {"x": {"dtype": "float32", "shape": ' + shape + "}}}\n"
    with pytest.raises(MalformedBody):
        decode_binary(header.encode())


def test_a_zero_sized_array_still_decodes():
    header = b'{"params": {}, "arrays": {"x": {"dtype": "float32", "shape": [0, 3]}}}\n'
    assert decode_binary(header)[1]["x"].shape == (0, 3)
