"""Per-run figures from a closed-loop time series (SPEC §8 summary fields) and their table."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

CHATTER_THRESHOLD_HPA = 1e-3


def chatter_per_s(u: np.ndarray, u_nom: np.ndarray, duration: float) -> float:
    """Sign changes per second of the filter's correction u − u_nom, summed over segments.

    Corrections smaller than CHATTER_THRESHOLD_HPA count as 'no correction' and are
    skipped, so a filter that is simply inactive scores 0.
    """
    changes = 0
    for d in (u - u_nom).T:
        signs = np.sign(d[np.abs(d) > CHATTER_THRESHOLD_HPA])
        changes += int(np.count_nonzero(signs[1:] != signs[:-1]))
    return changes / duration


def run_figures(log: Mapping[str, np.ndarray], control_dt: float, filtered: bool, wall_s: float) -> dict[str, Any]:
    """The SPEC §8 run fields plus extras, from a `run_closed_loop` log."""
    n_steps = len(log["t"])
    sim_s = n_steps * control_dt
    filter_us = log["filter_us"]
    return {
        "rho_min_pred": float(np.min(log["rho_pred"])),
        "rho_min_meas": float(np.min(log["rho_meas"])),
        "force_max_N": float(np.max(log["contact_force"])),
        "t_violation_s": float(np.count_nonzero(log["rho_meas"] < 0.0) * control_dt),
        "infeasible_steps": int(np.count_nonzero(log["infeasible"])),
        "recovery_steps": int(np.count_nonzero(log["recovery"])),
        "filter_us_median": float(np.median(filter_us)) if filtered else None,
        "filter_us_p99": float(np.percentile(filter_us, 99)) if filtered else None,
        "wall_s": float(wall_s),
        "sim_s": float(sim_s),
        "u_peak_abs_hPa": float(np.max(np.abs(log["u"]))),
        "active_steps": int(np.count_nonzero(np.any(log["active"], axis=1))),
        "chatter_per_s": chatter_per_s(log["u"], log["u_nom"], sim_s),
        "realtime_factor": float(sim_s / wall_s) if wall_s > 0 else None,
    }


def _cell(value: Any, fmt: str) -> str:
    if value is None:
        return "-"
    return format(value, fmt) if fmt else str(value)


def format_table(runs: Sequence[Mapping[str, Any]], columns: Sequence[tuple[str, str, str]]) -> str:
    """A plain-text table: columns are (header, key, format spec)."""
    rows = [[h for h, _, _ in columns]] + [[_cell(r.get(k), f) for _, k, f in columns] for r in runs]
    widths = [max(len(row[i]) for row in rows) for i in range(len(columns))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(row, widths)) for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
