"""How arrays travel: base64 inside JSON for small requests, or a binary body for large ones.

Binary (`application/octet-stream`): one line of compact JSON (the header, ending in `\\n`), then the
arrays' raw bytes back to back, in the header's order, each little-endian and C-ordered:

    {"params": {...}, "arrays": {"origins": {"dtype": "float32", "shape": [4096, 3]}, ...}}\\n<bytes>...

JSON (`application/json`): the same header with each array's bytes in `data` as base64. Answers use the
format of the request (or the `Accept` header), with `artifact_id`, `kind` and `meta` in the header.
"""

from __future__ import annotations

import base64
import json
import math
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, Field

from services.inference.errors import MalformedBody

OCTET_STREAM = "application/octet-stream"
BITS = (8, 16, 32, 64)
DTYPES = frozenset(
    {"bool", *(f"int{b}" for b in BITS), *(f"uint{b}" for b in BITS), "float16", "float32", "float64"}
)


MAX_DIMENSIONS = 8
# strict: `1e30` is not a length; a dimension is counted in an int32 (no array of this service is larger)
Dimension = Annotated[int, Field(ge=0, le=2**31 - 1, strict=True)]


class ArrayHeader(BaseModel):
    dtype: str = Field(description=f"one of {', '.join(sorted(DTYPES))}; little-endian")
    shape: list[Dimension] = Field(max_length=MAX_DIMENSIONS, description="dimensions, C order")


class EncodedArray(ArrayHeader):
    data: str = Field(description="the array's bytes, base64")


class QueryBody(BaseModel):
    """A JSON query: the operation's parameters and its input arrays."""

    params: dict[str, Any] = Field(default_factory=dict, description="the kind's typed parameters")
    arrays: dict[str, EncodedArray] = Field(default_factory=dict)


class QueryResult(BaseModel):
    """A JSON answer: the output arrays and metadata such as the names that indices refer to."""

    artifact_id: str
    kind: str
    meta: dict[str, Any] = Field(default_factory=dict)
    arrays: dict[str, EncodedArray]


def self_contained_schema(model: type[BaseModel]) -> dict[str, Any]:
    """`model`'s JSON schema with its `$defs` inlined: inside an OpenAPI document, `#/$defs/...` would
    resolve from the document's root, where there are none."""
    schema = model.model_json_schema()
    definitions = schema.pop("$defs", {})

    def inline(node: Any) -> Any:
        if isinstance(node, dict):
            if "$ref" in node:
                return inline(definitions[node["$ref"].rsplit("/", 1)[1]])
            return {key: inline(value) for key, value in node.items()}
        return [inline(item) for item in node] if isinstance(node, list) else node

    return inline(schema)


def _nbytes(name: str, header: ArrayHeader) -> int:
    if header.dtype not in DTYPES:
        raise MalformedBody(f"dtype {header.dtype!r} is not one of {', '.join(sorted(DTYPES))}", name)
    if any(d < 0 for d in header.shape):
        raise MalformedBody(f"shape {header.shape} has a negative dimension", name)
    return math.prod(header.shape) * np.dtype(header.dtype).itemsize


def decode_array(name: str, header: ArrayHeader, data: bytes) -> np.ndarray:
    expected = _nbytes(name, header)
    if len(data) != expected:
        raise MalformedBody(
            f"shape {header.shape} of {header.dtype} needs {expected} bytes, got {len(data)}", name
        )
    little = np.dtype(header.dtype).newbyteorder("<")
    return np.frombuffer(data, little).reshape(header.shape).astype(little.newbyteorder("="), copy=False)


def decode_json(body: QueryBody) -> dict[str, np.ndarray]:
    arrays = {}
    for name, encoded in body.arrays.items():
        try:
            data = base64.b64decode(encoded.data, validate=True)
        except ValueError:  # binascii.Error, or a character outside ASCII
            raise MalformedBody("data is not valid base64", f"arrays.{name}.data") from None
        arrays[name] = decode_array(f"arrays.{name}", encoded, data)
    return arrays


def decode_binary(body: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(params, arrays) of a binary body."""
    line, newline, rest = body.partition(b"\n")
    if not newline:
        raise MalformedBody("a binary body starts with one line of JSON (the header) ending in a newline")
    try:
        header = json.loads(line)
        params = header.get("params", {})
        described = {name: ArrayHeader.model_validate(h) for name, h in header.get("arrays", {}).items()}
    except (ValueError, AttributeError) as error:
        raise MalformedBody(f"the header line is not a valid header: {error}") from None
    if not isinstance(params, dict):
        raise MalformedBody("params must be an object", "params")
    arrays, offset = {}, 0
    for name, array_header in described.items():
        size = (
            math.prod(array_header.shape) * np.dtype(array_header.dtype).itemsize
            if array_header.dtype in DTYPES
            else 0
        )
        arrays[name] = decode_array(f"arrays.{name}", array_header, rest[offset : offset + size])
        offset += size
    if offset != len(rest):
        raise MalformedBody(f"{len(rest) - offset} bytes follow the arrays the header describes")
    return params, arrays


def _header(array: np.ndarray) -> dict[str, Any]:
    return {"dtype": array.dtype.name, "shape": list(array.shape)}


def array_bytes(array: np.ndarray) -> bytes:
    return np.ascontiguousarray(array, array.dtype.newbyteorder("<")).tobytes()


def encode_json(head: dict[str, Any], arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    encoded = {
        n: {**_header(a), "data": base64.b64encode(array_bytes(a)).decode()} for n, a in arrays.items()
    }
    return {**head, "arrays": encoded}


def encode_binary(head: dict[str, Any], arrays: dict[str, np.ndarray]) -> bytes:
    header = json.dumps({**head, "arrays": {n: _header(a) for n, a in arrays.items()}}, separators=(",", ":"))
    return b"".join([header.encode(), b"\n", *(array_bytes(a) for a in arrays.values())])
