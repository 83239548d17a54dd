"""Per-run figures from a closed-loop time series (SPEC §8 summary fields, MuJoCo contact
figures) and their table."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from controllers.safe_set import ForceSafeSet

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


def switches_per_s(u: np.ndarray, u_nom: np.ndarray, duration: float) -> float:
    """On/off switches per second of the filter's correction: steps where "some segment's
    |u − u_nom| > CHATTER_THRESHOLD_HPA" changes value. Catches the chatter `chatter_per_s`
    misses: a correction that keeps its sign but turns off and on (u = u_nom between)."""
    on = np.any(np.abs(u - u_nom) > CHATTER_THRESHOLD_HPA, axis=1)
    return int(np.count_nonzero(on[1:] != on[:-1])) / duration


def run_figures(log: Mapping[str, np.ndarray], control_dt: float, filtered: bool, wall_s: float) -> dict[str, Any]:
    """The SPEC §8 run fields plus extras, from a `LoopRecorder` log whose rows are `control_dt` s apart.

    Filter times are taken over the rows with a controller call (finite `filter_us`).
    `recovery_steps` and `active_steps` count the paper filter's diagnostics `recovery`
    and `active` when the log has them (0 and None for a filter without them).
    """
    n_steps = len(log["t"])
    sim_s = n_steps * control_dt
    filter_us = log["filter_us"][np.isfinite(log["filter_us"])]  # NaN: no controller call at that step
    filtered = filtered and filter_us.size > 0
    rho_pred = log["rho_pred"][np.isfinite(log["rho_pred"])]  # NaN: no estimate yet (camera loop start-up)
    return {
        "rho_min_pred": float(np.nanmin(rho_pred)) if rho_pred.size else None,
        "rho_min_meas": float(np.min(log["rho_meas"])),
        "force_max_N": float(np.max(log["contact_force"])),
        "t_violation_s": float(np.count_nonzero(log["rho_meas"] < 0.0) * control_dt),
        "infeasible_steps": int(np.count_nonzero(log["infeasible"])),
        "recovery_steps": int(np.count_nonzero(log["recovery"])) if "recovery" in log else 0,
        "filter_us_median": float(np.median(filter_us)) if filtered else None,
        "filter_us_p99": float(np.percentile(filter_us, 99)) if filtered else None,
        "wall_s": float(wall_s),
        "sim_s": float(sim_s),
        "u_peak_abs_hPa": float(np.max(np.abs(log["u"]))),
        "active_steps": int(np.count_nonzero(np.any(log["active"], axis=1))) if "active" in log else None,
        "chatter_per_s": chatter_per_s(log["u"], log["u_nom"], sim_s),
        "switches_per_s": switches_per_s(log["u"], log["u_nom"], sim_s),
        "realtime_factor": float(sim_s / wall_s) if wall_s > 0 else None,
    }


def contact_figures(log: Mapping[str, np.ndarray], safe_set: ForceSafeSet, control_dt: float) -> dict[str, Any]:
    """Predicted vs measured contact of a MuJoCo run (`log` with the plant extras
    `plate_displacement_m` and `force_solver_N`, (T, P) each); `safe_set` is the controller's.

    Per facet i and step k (m, N):
    - predicted penetration n̂_pred = max(0, n_max − b_i/‖H'_i‖), from the filter's barrier
      b_i = h'_i − H'_i r(q̂) of the Lemma row (the controller's estimate q̂ and model),
      i.e. max(0, n̂_i·r(q̂) − d_i); predicted force ψ(n̂_pred) with the controller's ψ;
    - measured penetration max(0, Δ_i), the plate's displacement; measured force
      `contact_force` (the plate's spring);
    - in contact: MuJoCo's solver applies a normal force between the arm and plate i
      (`force_solver_max_N` its peak: impacts on the 10 g plate spike it far above the
      spring force; `contact_switches_per_s` counts the arm touching / leaving any plate).
    Force error F_pred − F_meas over the steps where either is > 0 (RMS, max |·|, N);
    penetration bias n̂_pred − n_meas over the steps in contact (mean, max; m and % of the
    controller's n_max), None when there is no such step. Steps whose barrier is NaN (no
    estimate yet) have no prediction and are left out of both; a filter that records no
    barrier `b` (a diagnostic of the paper's filter) has no prediction at all: those
    figures are None.
    """
    p = safe_set.n_facets
    rows = np.asarray(safe_set.H_prime[:p], dtype=float)
    barrier = log["b"] if "b" in log else np.full((len(log["t"]), p), np.nan)
    predicted = np.all(np.isfinite(barrier[:, :p]), axis=1)  # rows with a prediction (camera loop: not before the first estimate)
    b = np.where(predicted[:, None], barrier[:, :p], np.inf)
    n_pred = np.maximum(safe_set.n_max - b / np.hypot(rows[:, 0], rows[:, 1]), 0.0)
    n_meas = np.maximum(log["plate_displacement_m"], 0.0)
    f_pred, f_meas = safe_set.stiffness.force(n_pred), log["contact_force"]
    either = ((f_pred > 0) | (f_meas > 0)) & predicted[:, None]
    f_err = (f_pred - f_meas)[either]
    contact = log["force_solver_N"] > 0
    touching = np.any(contact, axis=1)
    bias = (n_pred - n_meas)[contact & predicted[:, None]]
    n_max = safe_set.n_max
    out: dict[str, Any] = {
        "force_solver_max_N": float(np.max(log["force_solver_N"], initial=0.0)),
        "t_contact_s": float(np.count_nonzero(touching) * control_dt),
        "contact_switches_per_s": float(np.count_nonzero(touching[1:] != touching[:-1]) / (len(touching) * control_dt)),
        "force_pred_max_N": float(np.max(f_pred, initial=0.0)),
        "force_err_rms_N": float(np.sqrt(np.mean(f_err**2))) if f_err.size else None,
        "force_err_max_N": float(np.max(np.abs(f_err))) if f_err.size else None,
        "penetration_bias_mean_m": float(np.mean(bias)) if bias.size else None,
        "penetration_bias_max_m": float(np.max(bias)) if bias.size else None,
    }
    for key in ("mean", "max"):
        value = out[f"penetration_bias_{key}_m"]
        out[f"penetration_bias_{key}_pct"] = None if value is None else 100.0 * value / n_max
    return out


def _cell(value: Any, fmt: str, scale: float = 1.0) -> str:
    if value is None:
        return "-"
    if scale != 1.0:
        value = value * scale
    return format(value, fmt) if fmt else str(value)


def format_table(runs: Sequence[Mapping[str, Any]], columns: Sequence[tuple], markdown: bool = False) -> str:
    """A plain-text (or, with `markdown`, a Markdown) table: columns are (header, key, format spec)
    or (header, key, format spec, scale)."""
    rows = [[c[0] for c in columns]] + [[_cell(r.get(c[1]), *c[2:]) for c in columns] for r in runs]
    if markdown:
        lines = ["| " + " | ".join(row) + " |" for row in rows]
        lines.insert(1, "|" + "---|" * len(columns))
        return "\n".join(lines)
    widths = [max(len(row[i]) for row in rows) for i in range(len(columns))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(row, widths)) for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
