"""A `google.protobuf.Struct` from a request as JSON values. A Struct's numbers are doubles, so it can hold
NaN and Infinity, which JSON (and so every REST body) cannot: they are the caller's error, naming where."""

from __future__ import annotations

import math
from typing import Any

from google.protobuf import json_format, struct_pb2

from services.platform.errors import InvalidInput


def json_values(message: struct_pb2.Struct, field: str) -> dict[str, Any]:
    """The Struct `field` of a request as JSON values; InvalidInput naming the first non-finite number."""
    _check_finite(message, field)
    return json_format.MessageToDict(message)


def _check_finite(message: struct_pb2.Struct | struct_pb2.ListValue, field: str) -> None:
    items = message.fields.items() if isinstance(message, struct_pb2.Struct) else enumerate(message.values)
    for key, value in items:
        where = f"{field}.{key}" if isinstance(key, str) else f"{field}[{key}]"
        kind = value.WhichOneof("kind")
        if kind == "number_value" and not math.isfinite(value.number_value):
            raise InvalidInput(
                f"{value.number_value} is not a finite number (JSON has no NaN or Infinity)", where
            )
        if kind in ("struct_value", "list_value"):
            _check_finite(getattr(value, kind), where)
