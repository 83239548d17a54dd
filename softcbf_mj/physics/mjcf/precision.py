"""Numbers as MuJoCo's XML keeps them: 6 significant digits.

Every number goes into the generated spec rounded to 6 significant digits, the precision MuJoCo's
XML writer keeps, so the model compiled from the spec and the model compiled from the written files
are identical (models/softcbf_arm/README.md: a test compares them).
"""

from __future__ import annotations

from typing import Any


def r6(x: float) -> float:
    """x rounded to 6 significant digits (MuJoCo's XML precision)."""
    return float(f"{float(x):.6g}")


def r6v(values: Any) -> list[float]:
    """Each of `values` rounded by `r6`."""
    return [r6(v) for v in values]
