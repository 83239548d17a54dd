"""Robot parameters of a planar N-segment PCC soft arm (docs/model.md#rppr-dynamics).

One frozen, validated object holds everything the controller's model needs. Every
per-segment field is a tuple of N floats in SI units, pressures in hPa (reference values:
docs/model.md#reference-robot):

| field      | unit        | reference value                               | source  |
|------------|-------------|-----------------------------------------------|---------|
| lengths    | m           | 0.122                                         | paper   |
| masses     | kg          | 0.13                                          | paper   |
| inertias   | kg·m²       | m L² / 12 (rod about its centre)              | chosen  |
| stiffness  | N·m/rad     | 1.0                                           | chosen  |
| damping    | N·m·s/rad   | 0.07                                          | chosen  |
| gains (λ)  | N·m/hPa     | k · 25° / 80 hPa ≈ 5.454e-3                   | chosen  |
| u_min      | hPa         | −150                                          | chosen  |
| u_max      | hPa         | +150                                          | chosen  |

Valid ranges (checked at construction, so that the model's products — M's determinant,
M⁻¹Λ, K⁻¹Λ — stay inside the float range): lengths, masses, inertias, stiffness and gains
in [1e-30, 1e30] (SI), damping in [0, 1e30], u_min < u_max with |u| ≤ 1e30 hPa. The mass
matrix must also be well-conditioned for every q: its condition number is bounded by

    κ(M) ≤ (N (Σ L)² Σ m + N Σ I) / (min I · σ_min(A)²)

(M = Σ m_i J_ciᵀ J_ci + Aᵀ diag(I) A with |∂c_i/∂q_j| ≤ Σ L and A = ∂φ/∂q, A_ij = 1 for
j < i, ½ for j = i), and that bound must not exceed MAX_MASS_CONDITION = 1e12 (the
closed-form 2 × 2 inverse then keeps ≥ 4 significant digits).

The pressure limits live here and nowhere else: the simulations and the hardware
mode read them from this object (or from the model's `ctrlrange`, which the model
generator writes from it).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

REFERENCE_LENGTH_M = 0.122
REFERENCE_MASS_KG = 0.13
REFERENCE_STIFFNESS = 1.0
REFERENCE_DAMPING = 0.07
REFERENCE_BEND_RAD_AT_80HPA = math.radians(25.0)
REFERENCE_PRESSURE_HPA = 80.0
REFERENCE_U_LIMIT_HPA = 150.0

VALUE_MIN, VALUE_MAX = 1e-30, 1e30
MAX_MASS_CONDITION = 1e12

_PER_SEGMENT = ("lengths", "masses", "inertias", "stiffness", "damping", "gains", "u_min", "u_max")


def _as_tuple(name: str, value: Any, n: int | None) -> tuple[float, ...]:
    try:
        arr = np.atleast_1d(np.asarray(value))
        if arr.dtype.kind == "c":
            raise TypeError("complex")
        values = tuple(arr.astype(float).ravel().tolist())
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f"{name} must be a sequence of numbers (real), got {value!r}") from exc
    if n is not None and len(values) != n:
        raise ValueError(f"{name} must have one value per segment ({n}), got {len(values)}: {values}")
    for i, v in enumerate(values):
        if not math.isfinite(v):
            raise ValueError(f"{name}[{i}] must be finite, got {v}")
    return values


def _require_range(name: str, values: tuple[float, ...], lo: float, unit: str) -> None:
    for i, v in enumerate(values):
        if lo == 0.0 and v < 0.0:
            raise ValueError(f"{name}[{i}] must be >= 0, got {v}")
        if lo > 0.0 and not v > 0.0:
            raise ValueError(f"{name}[{i}] must be > 0, got {v}")
        if not lo <= v <= VALUE_MAX:
            raise ValueError(f"{name}[{i}] must be in [{lo:g}, {VALUE_MAX:g}] {unit}, got {v}")


def mass_condition_bound(params: "RobotParams") -> float:
    """An upper bound on the condition number of M(q) over all q (module docstring)."""
    n = params.n_segments
    a = np.tril(np.ones((n, n))) - 0.5 * np.eye(n)  # A = ∂φ/∂q
    sigma_min = float(np.linalg.svd(a, compute_uv=False)[-1])
    total_length = sum(params.lengths)
    largest = n * total_length**2 * sum(params.masses) + n * sum(params.inertias)
    return largest / (min(params.inertias) * sigma_min**2)


@dataclass(frozen=True)
class RobotParams:
    """Parameters of an N-segment planar PCC arm; see the module table for units.

    `inertias` defaults to m_i L_i² / 12. Values are checked at construction (ValueError
    naming the field, its range and the value): the ranges and the mass-matrix condition
    bound of the module docstring.
    """

    lengths: tuple[float, ...]
    masses: tuple[float, ...]
    stiffness: tuple[float, ...]
    damping: tuple[float, ...]
    gains: tuple[float, ...]
    u_min: tuple[float, ...]
    u_max: tuple[float, ...]
    inertias: tuple[float, ...] | None = field(default=None)

    def __post_init__(self) -> None:
        lengths = _as_tuple("lengths", self.lengths, None)
        n = len(lengths)
        if n < 1:
            raise ValueError("lengths must hold at least one segment, got 0")
        object.__setattr__(self, "lengths", lengths)
        for name in ("masses", "stiffness", "damping", "gains", "u_min", "u_max"):
            object.__setattr__(self, name, _as_tuple(name, getattr(self, name), n))
        if self.inertias is None:
            inertias = tuple(m * L * L / 12.0 for m, L in zip(self.masses, self.lengths))
        else:
            inertias = _as_tuple("inertias", self.inertias, n)
        object.__setattr__(self, "inertias", inertias)
        units = {"lengths": "m", "masses": "kg", "inertias": "kg·m²", "stiffness": "N·m/rad", "gains": "N·m/hPa"}
        for name, unit in units.items():
            _require_range(name, getattr(self, name), VALUE_MIN, unit)
        _require_range("damping", self.damping, 0.0, "N·m·s/rad")
        for i, (lo, hi) in enumerate(zip(self.u_min, self.u_max)):
            if not lo < hi:
                raise ValueError(f"u_min[{i}] must be < u_max[{i}], got u_min={lo}, u_max={hi}")
            if not (-VALUE_MAX <= lo and hi <= VALUE_MAX):
                raise ValueError(f"u_min[{i}] and u_max[{i}] must be within ±{VALUE_MAX:g} hPa, got u_min={lo}, u_max={hi}")
        condition = mass_condition_bound(self)
        if not condition <= MAX_MASS_CONDITION:
            raise ValueError(f"the mass matrix's condition number may reach {condition:.3g} (bound over all q), above "
                             f"{MAX_MASS_CONDITION:g}: masses, lengths and inertias differ too much between segments")

    @property
    def n_segments(self) -> int:
        return len(self.lengths)

    def array(self, name: str) -> np.ndarray:
        """A per-segment field as a float array of shape (N,)."""
        if name not in _PER_SEGMENT:
            raise KeyError(f"unknown per-segment field {name!r}; valid: {', '.join(_PER_SEGMENT)}")
        return np.array(getattr(self, name), dtype=float)

    def to_dict(self) -> dict[str, list[float]]:
        return {k: list(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "RobotParams":
        unknown = set(data) - set(_PER_SEGMENT)
        if unknown:
            raise ValueError(f"unknown robot parameter(s) {sorted(unknown)}; valid: {', '.join(_PER_SEGMENT)}")
        missing = set(_PER_SEGMENT) - {"inertias"} - set(data)
        if missing:
            raise ValueError(f"missing robot parameter(s) {sorted(missing)}")
        return cls(**data)

    def save(self, path: str | Path) -> None:
        """Write the parameters as JSON (the format `load` and the calibration tool use)."""
        Path(path).write_text(json.dumps({"robot": self.to_dict()}, indent=2) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path) -> "RobotParams":
        """Read parameters written by `save` (or by the calibration tool)."""
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        if "robot" not in data:
            raise ValueError(f"{path}: expected a JSON object with key 'robot'")
        return cls.from_dict(data["robot"])

    def replace(self, **changes: Any) -> "RobotParams":
        """A copy with some fields changed (inertias recomputed unless given)."""
        data = asdict(self)
        if "inertias" not in changes and ("masses" in changes or "lengths" in changes):
            data["inertias"] = None
        data.update(changes)
        return RobotParams(**data)


def uniform_robot(
    n_segments: int = 2,
    length: float = REFERENCE_LENGTH_M,
    mass: float = REFERENCE_MASS_KG,
    stiffness: float = REFERENCE_STIFFNESS,
    damping: float = REFERENCE_DAMPING,
    gain: float | None = None,
    u_limit: float = REFERENCE_U_LIMIT_HPA,
) -> RobotParams:
    """An arm of `n_segments` identical segments; `gain` defaults to k·25°/80 hPa."""
    if int(n_segments) != n_segments or n_segments < 1:
        raise ValueError(f"n_segments must be an integer >= 1, got {n_segments}")
    if not u_limit > 0:
        raise ValueError(f"u_limit must be > 0, got {u_limit}")
    if gain is None:
        gain = stiffness * REFERENCE_BEND_RAD_AT_80HPA / REFERENCE_PRESSURE_HPA
    n = int(n_segments)
    return RobotParams(
        lengths=(length,) * n,
        masses=(mass,) * n,
        stiffness=(stiffness,) * n,
        damping=(damping,) * n,
        gains=(gain,) * n,
        u_min=(-u_limit,) * n,
        u_max=(u_limit,) * n,
    )


def reference_robot() -> RobotParams:
    """The two-segment reference arm of docs/model.md#rppr-dynamics."""
    return uniform_robot(2)


def per_segment(values: float | Sequence[float], n: int, name: str) -> np.ndarray:
    """Broadcast a scalar or an N-sequence to an array of shape (n,), naming `name` on error."""
    arr = np.atleast_1d(np.asarray(values, dtype=float))
    if arr.shape == (1,):
        arr = np.full(n, arr[0])
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have {n} values, got shape {arr.shape}")
    return arr
