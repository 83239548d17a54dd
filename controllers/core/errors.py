"""Exceptions raised by the controller's public entry points, and the check that raises them.

All are `ValueError`s, so callers that only expect bad-input errors need not know
the hierarchy; the subclasses let a control loop tell a corrupted state estimate
(NaN/inf in q or q̇) from a corrupted command.
"""

from __future__ import annotations

import math
import numbers

import numpy as np


class ControllerInputError(ValueError):
    """An input to the controller has the wrong shape, type or value."""


class NonFiniteStateError(ControllerInputError):
    """The state q or q̇ contains NaN or ±inf."""


class NonFiniteCommandError(ControllerInputError):
    """The command u contains NaN or ±inf."""


_FLOAT64 = np.dtype(np.float64)


def as_vector(name: str, value, n: int | None, nonfinite: type[ControllerInputError]) -> np.ndarray:
    """`value` as a float array of shape (n,) (any length if n is None).

    Raises ControllerInputError for a wrong type or shape (complex numbers, strings, and
    integers beyond the float range such as 10**400 included) and `nonfinite` for NaN/inf.
    Costs well under a microsecond for valid input (it runs every control step).
    """
    try:
        arr = np.asarray(value)
        if arr.dtype is not _FLOAT64:  # identity: the cheapest test (float64 arrays share the dtype)
            if arr.dtype.kind == "c":
                raise TypeError("complex")
            arr = arr.astype(float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ControllerInputError(f"{name} must be an array of numbers (real, within the float range), got {value!r}") from exc
    if arr.ndim != 1 or (n is not None and arr.shape[0] != n):
        want = f"({n},)" if n is not None else "(N,)"
        raise ControllerInputError(f"{name} must have shape {want}, got {arr.shape}")
    # A Python float sum is NaN/inf iff an entry is (or, harmlessly, if it overflows).
    if not math.isfinite(sum(arr.tolist())) and not np.isfinite(arr).all():
        raise nonfinite(f"{name} must be finite, got {arr}")
    return arr


def as_real(name: str, value, unit: str = "") -> float:
    """`value` as a Python float, or ControllerInputError naming `name` (NaN and ±inf pass: range checks follow).

    Accepts real numbers (numpy scalars included); refuses bool, complex, strings and integers
    beyond the float range (10**400) with the documented error instead of TypeError/OverflowError.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise ControllerInputError(f"{name} must be a real number{unit and ' [' + unit + ']'}, got {value!r}")
    try:
        return float(value)
    except OverflowError as exc:
        raise ControllerInputError(f"{name} must be a finite real number, got an integer of {len(str(abs(int(value))))} digits") from exc
