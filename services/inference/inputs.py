"""Checking a request against the operation the kind declares, before any model sees it: parameters
validate, arrays have the declared names and shapes, convert to the declared dtype without loss of kind,
hold no NaN or Inf, and stay within the per-request row limit. Every refusal names the field at fault."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ValidationError

from services.inference.errors import InvalidQuery, RequestTooLarge
from workers.models.registry import ArraySpec, Operation


def checked_params(operation: Operation, params: dict[str, Any]) -> BaseModel:
    try:
        return operation.params.model_validate(params)
    except ValidationError as error:
        first = error.errors()[0]
        field = ".".join(["params", *(str(p) for p in first["loc"])])
        raise InvalidQuery(first["msg"], field) from None


def _shape_text(spec: ArraySpec) -> str:
    return "(" + ", ".join("N" if d is None else str(d) for d in spec.shape) + ")"


def _checked_array(name: str, array: np.ndarray, spec: ArraySpec) -> np.ndarray:
    field = f"arrays.{name}"
    fits = array.ndim == len(spec.shape) and all(
        want is None or want == got for want, got in zip(spec.shape, array.shape, strict=True)
    )
    if not fits:
        raise InvalidQuery(f"shape {list(array.shape)} does not fit {_shape_text(spec)}", field)
    if not np.can_cast(array.dtype, spec.dtype, "same_kind"):
        raise InvalidQuery(f"dtype {array.dtype.name} cannot become {spec.dtype}", field)
    converted = array.astype(spec.dtype, copy=False)
    if converted.dtype.kind == "f" and not np.isfinite(converted).all():
        row = int(np.flatnonzero(~np.isfinite(converted.reshape(len(converted), -1)).all(1))[0])
        raise InvalidQuery(f"holds NaN or Inf (first at row {row})", field)
    return converted


def checked_arrays(
    operation: Operation, arrays: dict[str, np.ndarray], max_rows: int
) -> dict[str, np.ndarray]:
    unknown = sorted(set(arrays) - set(operation.inputs))
    if unknown:
        takes = ", ".join(f"{n} {_shape_text(s)}" for n, s in operation.inputs.items()) or "no arrays"
        raise InvalidQuery(f"unknown array; this operation takes {takes}", f"arrays.{unknown[0]}")
    checked = {}
    for name, spec in operation.inputs.items():
        if name in arrays:
            checked[name] = _checked_array(name, arrays[name], spec)
        elif spec.required:
            raise InvalidQuery(f"missing: this operation needs {name} {_shape_text(spec)}", f"arrays.{name}")
    rows = {len(a) for name, a in checked.items() if operation.inputs[name].rows}
    if len(rows) > 1:
        raise InvalidQuery(f"the arrays disagree on their number of rows ({sorted(rows)})", "arrays")
    if rows and rows.pop() > max_rows:
        raise RequestTooLarge(f"at most {max_rows} rows per request; split it", "arrays")
    return checked
