"""Shared test cases for the controller maths: configurations and central differences."""

from __future__ import annotations

import numpy as np

# Angles where PCC formulas are delicate: exactly straight, the series branch, its switch, large bends.
SPECIAL_ANGLES = (0.0, 1e-8, -1e-8, 1e-4, -1e-4, 0.5, -0.5, 2.0, 2.5, -2.5)
SEGMENT_COUNTS = (1, 2, 3, 4)


def configurations(n: int) -> list[np.ndarray]:
    """Configurations q (n,): straight, all-tiny, mixtures of SPECIAL_ANGLES, and random ones."""
    rng = np.random.default_rng(100 + n)
    cases = [np.zeros(n), np.full(n, 1e-8), np.full(n, -1e-4)]
    cases += [np.roll(SPECIAL_ANGLES, -3 * k)[:n] for k in range(3)]
    cases += [rng.choice(SPECIAL_ANGLES, n) for _ in range(2)]
    cases.append(rng.uniform(-2.5, 2.5, n))
    return [np.array(c, dtype=float) for c in cases]


def lengths(n: int) -> np.ndarray:
    """Unequal segment lengths (m), so that swapped indices show up."""
    return np.random.default_rng(200 + n).uniform(0.08, 0.2, n)


def central_difference(func, x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """∂func/∂x by central differences, the derivative index as the LAST axis."""
    columns = []
    for k in range(x.shape[0]):
        dx = np.zeros_like(x)
        dx[k] = step
        columns.append((np.asarray(func(x + dx)) - np.asarray(func(x - dx))) / (2.0 * step))
    return np.stack(columns, axis=-1)
