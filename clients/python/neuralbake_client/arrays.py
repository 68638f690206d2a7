"""Arrays on the wire to and from the inference service: each array little-endian and C-ordered, named, with
its dtype and shape. Over REST a binary body is one line of compact JSON (the header), then the arrays'
bytes back to back in the header's order (the server's `services/inference/wire.py` reads and writes the
same format; a test checks that the two agree); over gRPC each array is an `Array` message.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from neuralbake_client.errors import NeuralbakeError

OCTET_STREAM = "application/octet-stream"


def little_endian(array: ArrayLike) -> np.ndarray:
    """The array as the wire carries it: little-endian, C-ordered."""
    array = np.asarray(array)
    return np.ascontiguousarray(array, array.dtype.newbyteorder("<"))


def from_bytes(dtype: str, shape: list[int], data: bytes | memoryview, offset: int = 0) -> np.ndarray:
    """A writable native-endian array of `shape` from little-endian bytes at `offset`."""
    wire = np.dtype(dtype).newbyteorder("<")
    count = math.prod(shape)
    if offset + count * wire.itemsize > len(data):
        raise NeuralbakeError(f"the answer holds fewer bytes than a {dtype} array of shape {shape} needs")
    flat = np.frombuffer(data, wire, count=count, offset=offset)
    return flat.reshape(shape).astype(wire.newbyteorder("="))


def encode_binary(head: dict[str, Any], arrays: Mapping[str, ArrayLike]) -> bytes:
    prepared = {name: little_endian(array) for name, array in arrays.items()}
    described = {name: {"dtype": a.dtype.name, "shape": list(a.shape)} for name, a in prepared.items()}
    header = json.dumps({**head, "arrays": described}, separators=(",", ":"))
    return b"".join([header.encode(), b"\n", *(a.tobytes() for a in prepared.values())])


def decode_binary(body: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(the header without `arrays`, the arrays by name) of a binary answer."""
    line, newline, rest = body.partition(b"\n")
    if not newline:
        raise NeuralbakeError("the answer does not start with a JSON header line")
    head = json.loads(line)
    arrays, offset, view = {}, 0, memoryview(rest)
    for name, described in head.pop("arrays", {}).items():
        arrays[name] = from_bytes(described["dtype"], described["shape"], view, offset)
        offset += arrays[name].nbytes
    return head, arrays
