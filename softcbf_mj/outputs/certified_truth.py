"""Does the truth lie inside what the filter says it has certified?

A filter that learns online (c-erg's gain and plate estimates) reports, at every call, the intervals its
certificate holds for: the rest-shape ratio r = g/c of the actuator gain to the arm stiffness (`gain_lo`,
`gain_hi`), the plate's stiffness as a multiple of the assumed one (`plate_lo`, `plate_hi`) and the plate's offset
along its normal (`plate_offset_lo_m`, `plate_offset_hi_m`, m). Its guarantee assumes the truth lies inside them. A
run can keep its force below F_max with an interval that excludes the truth (the certificate's other slack, or luck):
that run is no evidence for the filter, and the testbed, which knows the truth, says so.

The truth of each coordinate (`CertifiedTruth`, built by the scenario from its ground truth):

- gain: r_i = (λ_i/λ̂_i)/(k_i/k̂_i) of every segment i (the true arm's gain and stiffness against the controller's
  model; the rest shape q_u = K⁻¹Λu depends on the gains through this ratio alone, which is what the estimate
  measures and the interval bounds; with no arm-stiffness interval certified the filter takes c = 1 and its
  interval is one of g, which is r then);
- plate: the true plate stiffness / the assumed one (the ideal slide-spring plate only: a clamped sheet's local
  stiffness varies along it, and the certificate then bounds it by its own law, not by one number);
- plate_offset: the facets' move along their normals, m (the ideal plate, untilted: a tilted facet's offset varies
  along it).

Figures (`certified_truth_figures`), over the rows where the filter reported the interval (NaN rows, before a first
call or after a fault, are skipped): `certified_truth_outside_s`, the time (rows × control period) in which some
reported interval excluded its truth (every segment's r for the gain), and `certified_truth_outside`, the
coordinates that did, comma-separated ("" when none). A relative tolerance `REL_TOL` absorbs the rounding of
ratios such as 0.9/1.1. A log without any of the columns gives no figures (a filter that certifies nothing online).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

INTERVAL_COLUMNS: dict[str, tuple[str, str]] = {
    "gain": ("gain_lo", "gain_hi"),
    "plate": ("plate_lo", "plate_hi"),
    "plate_offset": ("plate_offset_lo_m", "plate_offset_hi_m"),
}
"""coordinate → the diagnostic columns of its certified interval [lo, hi]."""
REL_TOL = 1e-9


@dataclass(frozen=True)
class CertifiedTruth:
    """The true values of the certified coordinates (module docstring): gain, the ratios r_i (N,); plate, the
    stiffness ratio; plate_offset, m. None: the coordinate has no single true value in this ground truth."""

    gain: tuple[float, ...]
    plate: float | None
    plate_offset: float | None

    def values(self, coordinate: str) -> np.ndarray | None:
        value = getattr(self, coordinate)
        return None if value is None else np.atleast_1d(np.asarray(value, dtype=float))


def outside_rows(lo: np.ndarray, hi: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Rows (T,) whose interval [lo, hi] (T,) excludes some value of `truth` (K,), within `REL_TOL`; NaN rows False."""
    lo, hi = np.asarray(lo, dtype=float)[:, None], np.asarray(hi, dtype=float)[:, None]
    slack = REL_TOL * np.maximum(1.0, np.abs(truth))[None, :]
    return np.any((truth[None, :] < lo - slack) | (truth[None, :] > hi + slack), axis=1)


def certified_truth_figures(log: Mapping[str, np.ndarray], truth: CertifiedTruth, control_dt: float) -> dict:
    """The module docstring's figures of a run's log (its rows `control_dt` s apart); {} when the log holds none of
    `INTERVAL_COLUMNS`."""
    present = [c for c, (lo, hi) in INTERVAL_COLUMNS.items() if lo in log and hi in log]
    if not present:
        return {}
    outside = np.zeros(len(log[INTERVAL_COLUMNS[present[0]][0]]), dtype=bool)
    names = []
    for coordinate in present:
        values = truth.values(coordinate)
        if values is None:
            continue
        rows = outside_rows(log[INTERVAL_COLUMNS[coordinate][0]], log[INTERVAL_COLUMNS[coordinate][1]], values)
        if rows.any():
            names.append(coordinate)
            outside |= rows
    return {"certified_truth_outside_s": float(np.count_nonzero(outside) * control_dt),
            "certified_truth_outside": ",".join(names)}
