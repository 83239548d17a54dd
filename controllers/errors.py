"""Exceptions raised by the controller's public entry points, and the check that raises them.

All are `ValueError`s, so callers that only expect bad-input errors need not know
the hierarchy; the subclasses let a control loop tell a corrupted state estimate
(NaN/inf in q or q̇) from a corrupted command.
"""

from __future__ import annotations

import math

import numpy as np


class ControllerInputError(ValueError):
    """An input to the controller has the wrong shape, type or value."""


class NonFiniteStateError(ControllerInputError):
    """The state q or q̇ contains NaN or ±inf."""


class NonFiniteCommandError(ControllerInputError):
    """The command u contains NaN or ±inf."""


def as_vector(name: str, value, n: int | None, nonfinite: type[ControllerInputError]) -> np.ndarray:
    """`value` as a float array of shape (n,) (any length if n is None).

    Raises ControllerInputError for a wrong type or shape and `nonfinite` for NaN/inf.
    Costs well under a microsecond for valid input (it runs every control step).
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ControllerInputError(f"{name} must be an array of numbers, got {value!r}") from exc
    if arr.ndim != 1 or (n is not None and arr.shape[0] != n):
        want = f"({n},)" if n is not None else "(N,)"
        raise ControllerInputError(f"{name} must have shape {want}, got {arr.shape}")
    # A Python float sum is NaN/inf iff an entry is (or, harmlessly, if it overflows).
    if not math.isfinite(sum(arr.tolist())) and not np.isfinite(arr).all():
        raise nonfinite(f"{name} must be finite, got {arr}")
    return arr
