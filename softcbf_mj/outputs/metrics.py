"""Per-run figures from a closed-loop time series (docs/run-outputs.md summary fields, MuJoCo contact
figures) and their table.

How much the filter's command chatters, three ways (u, u_nom (T, N) in hPa, one row per
control step of Δt s; d = u − u_nom, "no correction" where |d_j| ≤ CHATTER_THRESHOLD_HPA):
- `chatter_per_s`: switches of the correction's ternary sign per second, summed over
  segments (on, off or reversal of each d_j);
- `switches_per_s`: on/off switches of the filter as a whole per second;
- `u_hf_fraction`: the fraction of u's variance above HF_CUTOFF_HZ (power the arm cannot
  follow, i.e. command energy the valves spend for nothing).
Plus `u_dev_rms_hPa` and `u_dev_max_hPa`, RMS and max |d| over all steps and segments.

The table a scenario prints (`write_table`) fits a terminal of TERMINAL_COLUMNS characters: its
leading columns as far as they fit (the label column always, a label cut to
`softcbf_mj.outputs.palette.LABEL_LIMIT` characters), then a line counting the columns left out and naming
the file that holds them all, TABLE_FILE in the run folder (every column, full labels).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from controllers.core.lazy_import import lazy_module
from controllers.model.safe_set import ForceSafeSet
from softcbf_mj.outputs.palette import plot_labels

figures_kernel = lazy_module("softcbf_mj.outputs.figures_kernel")  # numba loads on the first update (controllers.core.lazy_import)
_NO_CODES = np.zeros((1, 1), dtype=np.int8)  # the kernel's placeholder for action / rows when they are None

CHATTER_THRESHOLD_HPA = 0.1  # |u − u_nom| below this (hPa) counts as "no correction"
TERMINAL_COLUMNS = 120  # characters a line of a printed table (module docstring)
TABLE_FILE = "table.txt"  # the full table, in the run folder
HF_CUTOFF_HZ = 5.0  # above the reference arm's first mode (≈ 20 rad/s ≈ 3.2 Hz): power the arm cannot follow


def correction_sign(u: np.ndarray, u_nom: np.ndarray, threshold_hPa: float = CHATTER_THRESHOLD_HPA) -> np.ndarray:
    """Ternary sign of the filter's correction d = u − u_nom, (T, N) → (T, N) in {−1, 0, +1}:
    0 where |d| ≤ `threshold_hPa` (no correction), sign(d) elsewhere."""
    if not threshold_hPa >= 0:
        raise ValueError(f"threshold_hPa must be >= 0 hPa, got {threshold_hPa}")
    d = np.asarray(u, dtype=float) - np.asarray(u_nom, dtype=float)
    return np.where(np.abs(d) > threshold_hPa, np.sign(d), 0.0)


def chatter_per_s(u: np.ndarray, u_nom: np.ndarray, duration: float,
                  threshold_hPa: float = CHATTER_THRESHOLD_HPA) -> float:
    """Switches per second of the filter's correction, summed over segments.

    For each segment j, s_j(k) = correction_sign(u, u_nom)[k, j] ∈ {−1, 0, +1}; a switch is
    a step k with s_j(k) ≠ s_j(k − 1): the correction turning on (0 → ±1), turning off
    (±1 → 0) or reversing (−1 ↔ +1, one switch). A command that alternates every step
    between u_nom and a corrected value therefore scores one switch per step and segment
    it corrects (1000/s per segment at 1 kHz); a filter that is inactive, or whose
    correction turns on once and stays on, scores ≈ 0. `duration` in s; u, u_nom (T, N) hPa.
    """
    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    s = correction_sign(u, u_nom, threshold_hPa)
    return int(np.count_nonzero(s[1:] != s[:-1])) / duration


def switches_per_s(u: np.ndarray, u_nom: np.ndarray, duration: float,
                   threshold_hPa: float = CHATTER_THRESHOLD_HPA) -> float:
    """On/off switches per second of the filter as a whole: steps where "some segment's
    |u − u_nom| > `threshold_hPa`" changes value (a sign reversal with the filter on all
    along does not count; `chatter_per_s` does)."""
    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    on = np.any(correction_sign(u, u_nom, threshold_hPa) != 0, axis=1)
    return int(np.count_nonzero(on[1:] != on[:-1])) / duration


def high_frequency_fraction(u: np.ndarray, dt: float, cutoff_hz: float = HF_CUTOFF_HZ) -> float | None:
    """Fraction of the command's variance above `cutoff_hz`: u (T, N) hPa sampled every `dt` s.

    Each u_j is extended by its mirror image (u_j followed by u_j reversed, length 2T, so the
    periodic extension the DFT assumes has no jump at the ends: no spectral leakage from a
    run that ends mid-swing) and its mean removed; with U_j(f) the one-sided DFT of that
    (`numpy.fft.rfft`), the fraction is Σ_j Σ_{f > cutoff} |U_j(f)|² / Σ_j Σ_f |U_j(f)|² ∈ [0, 1].
    The paper's 0.01 Hz sinusoid over 10 s scores 1.5e-7; a command that alternates every
    step between two values scores ≈ the alternating part's share of the variance. None for
    a constant command (no variance) or a cut-off at or above the Nyquist frequency 1/(2 dt).
    """
    if not dt > 0:
        raise ValueError(f"dt must be > 0 s, got {dt}")
    if not cutoff_hz > 0:
        raise ValueError(f"cutoff_hz must be > 0 Hz, got {cutoff_hz}")
    u = np.asarray(u, dtype=float).reshape(len(u), -1)
    if len(u) < 2 or cutoff_hz >= 0.5 / dt:
        return None
    mirrored = np.concatenate((u, u[::-1]), axis=0)
    power = np.abs(np.fft.rfft(mirrored - mirrored.mean(axis=0), axis=0)) ** 2
    freq = np.fft.rfftfreq(len(mirrored), dt)
    total = float(power.sum())
    if total <= 0.0:
        return None
    return float(power[freq > cutoff_hz].sum() / total)


def rho_meas(safe_set: ForceSafeSet, contact_forces: np.ndarray) -> np.ndarray:
    """ρ_meas (1) of measured contact forces (..., P) N: min over facets of the controller's
    force-safe set's `margin_from_force` (its ψ and n_max), shape (...)."""
    return np.min(safe_set.margin_from_force(contact_forces), axis=-1)


class RunningFigures:
    """The summary figures every loop keeps, for B runs at once, updated block by block of rows
    (one control period of a batched loop, a whole serial log, an env step's periods): the one
    place that defines them. Per run b, over the rows it has been given (`rows`):

    - rho_min_pred: min of the filter's ρ_pred (NaN rows skipped; NaN while none);
    - rho_min_meas: min of ρ_meas (`rho_meas`; +inf while no row);
    - force_max_N: max over rows and facets of the contact force, N (`force_floor` while no row:
      −inf for the run figures, 0 N for the environment's statistics);
    - violations: #rows with ρ_meas < 0 (t_violation_s = control_dt · violations);
    - infeasible: #rows whose filter call said infeasible; refused: #rows the safety monitor did
      not RUN; vented: some row VENTed;
    - u_peak_abs_hPa: max |u| of the command sent (0 while no row);
    - force_excess: the sum over rows of max_i max(0, F_i − F_max)/F_max (1; with f_max given).
    Order does not matter (min, max and counts are exact), so a run's figures are the same
    whether its rows come one by one or all at once."""

    def __init__(self, n_sims: int, control_dt: float, f_max: float | None = None,
                 force_floor: float = -math.inf) -> None:
        self.n_sims, self.control_dt, self.f_max = n_sims, control_dt, f_max
        self.rows = np.zeros(n_sims, dtype=int)
        self.rho_min_pred = np.full(n_sims, math.nan)
        self.rho_min_meas = np.full(n_sims, math.inf)
        self.force_max_N = np.full(n_sims, float(force_floor))
        self.violations = np.zeros(n_sims, dtype=int)
        self.infeasible = np.zeros(n_sims, dtype=int)
        self.refused = np.zeros(n_sims, dtype=int)
        self.vented = np.zeros(n_sims, dtype=bool)
        self.u_peak_abs_hPa = np.zeros(n_sims)
        self.force_excess = np.zeros(n_sims)

    def update(self, margin: np.ndarray, contact_forces: np.ndarray, u: np.ndarray, rho_pred: np.ndarray,
               infeasible: np.ndarray, action: np.ndarray | None = None, rows: np.ndarray | None = None) -> None:
        """T rows of every run: margin ρ_meas (T, B), contact_forces (T, B, P) N, u (T, B, N) hPa
        sent, rho_pred (T, B) (NaN: none), infeasible (T, B) bool, action (T, B) the monitor's
        codes (0 RUN, 1 HOLD, 2 VENT; None: not counted); `rows` (T, B) bool: the rows that count (None: all).
        Compiled (`softcbf_mj.outputs.figures_kernel`: one pass over the block, the definitions above)."""
        margin, rho_pred, infeasible = np.asarray(margin, dtype=float), np.asarray(rho_pred, dtype=float), \
            np.asarray(infeasible)
        figures_kernel.update(margin, np.asarray(contact_forces, dtype=float), np.asarray(u, dtype=float), rho_pred,
                              infeasible, _NO_CODES if action is None else np.asarray(action),
                              _NO_CODES if rows is None else np.asarray(rows), action is not None, rows is not None,
                              math.nan if self.f_max is None else float(self.f_max), self.rows, self.rho_min_pred,
                              self.rho_min_meas, self.force_max_N, self.violations, self.infeasible, self.refused,
                              self.vented, self.u_peak_abs_hPa, self.force_excess)

    def figures(self, b: int) -> dict[str, Any]:
        """Run b's figures under the docs/run-outputs.md names (rho_min_pred None when never predicted)."""
        rho_pred = float(self.rho_min_pred[b])
        return {
            "rho_min_pred": None if math.isnan(rho_pred) else rho_pred,
            "rho_min_meas": float(self.rho_min_meas[b]),
            "force_max_N": float(self.force_max_N[b]),
            "t_violation_s": float(self.violations[b] * self.control_dt),
            "infeasible_steps": int(self.infeasible[b]),
            "u_peak_abs_hPa": float(self.u_peak_abs_hPa[b]),
        }


def run_figures(log: Mapping[str, np.ndarray], control_dt: float, filtered: bool, wall_s: float) -> dict[str, Any]:
    """The docs/run-outputs.md run fields plus extras, from a `LoopRecorder` log whose rows are `control_dt` s apart.

    Filter times are taken over the rows with a controller call (finite `filter_us`).
    `recovery_steps` and `active_steps` count the paper filter's diagnostics `recovery`
    and `active` when the log has them (0 and None for a filter without them).
    """
    n_steps = len(log["t"])
    sim_s = n_steps * control_dt
    filter_us = log["filter_us"][np.isfinite(log["filter_us"])]  # NaN: no controller call at that step
    filtered = filtered and filter_us.size > 0
    running = RunningFigures(1, control_dt)  # the rows at once; NaN rho_pred: no estimate yet (camera loop start-up)
    running.update(log["rho_meas"][:, None], log["contact_force"][:, None], log["u"][:, None], log["rho_pred"][:, None],
                   log["infeasible"][:, None])
    figures = running.figures(0)
    return {
        "rho_min_pred": figures["rho_min_pred"],
        "rho_min_meas": figures["rho_min_meas"],
        "force_max_N": figures["force_max_N"],
        "t_violation_s": figures["t_violation_s"],
        "infeasible_steps": figures["infeasible_steps"],
        "recovery_steps": int(np.count_nonzero(log["recovery"])) if "recovery" in log else 0,
        "filter_us_median": float(np.median(filter_us)) if filtered else None,
        "filter_us_p99": float(np.percentile(filter_us, 99)) if filtered else None,
        "wall_s": float(wall_s),
        "sim_s": float(sim_s),
        "u_peak_abs_hPa": figures["u_peak_abs_hPa"],
        "active_steps": int(np.count_nonzero(np.any(log["active"], axis=1))) if "active" in log else None,
        "chatter_per_s": chatter_per_s(log["u"], log["u_nom"], sim_s),
        "switches_per_s": switches_per_s(log["u"], log["u_nom"], sim_s),
        "u_hf_fraction": high_frequency_fraction(log["u"], control_dt),
        "u_dev_rms_hPa": float(np.sqrt(np.mean((log["u"] - log["u_nom"]) ** 2))),
        "u_dev_max_hPa": float(np.max(np.abs(log["u"] - log["u_nom"]))),
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


def plate_figures(log: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Friction and, for flexure plates, where and how stiff the arm met the sheet (a MuJoCo run's
    `log` with the plant extras `force_tangential_N` and, for flexures, `contact_s_m` and
    `contact_stiffness_N_per_m`, (T, P) each; `softcbf_mj.physics.mujoco_plant`).

    - `force_tangential_max_N`: the peak tangential (friction) contact force, N;
    - flexure: `contact_s_min_m`, `contact_s_max_m` (m from the clamp, over the steps in
      contact), and at the step of the largest measured (gauge) force: `contact_s_at_force_max_m`
      and `contact_stiffness_at_force_max_N_per_m` (N/m), the sheet's static stiffness there,
      with `force_true_at_force_max_N`, the arm's normal contact force at that step (the gauge
      reads the clamp reaction, not the contact force). None without contact.
    """
    out: dict[str, Any] = {"force_tangential_max_N": float(np.max(log["force_tangential_N"], initial=0.0))}
    if "contact_s_m" not in log:
        return out
    where = np.asarray(log["contact_s_m"], dtype=float)
    touching = np.isfinite(where)
    step, facet = np.unravel_index(int(np.argmax(log["contact_force"])), np.shape(log["contact_force"]))
    at_peak = bool(touching[step, facet])
    out.update({
        "contact_s_min_m": float(np.min(where[touching])) if np.any(touching) else None,
        "contact_s_max_m": float(np.max(where[touching])) if np.any(touching) else None,
        "contact_s_at_force_max_m": float(where[step, facet]) if at_peak else None,
        "contact_stiffness_at_force_max_N_per_m": float(log["contact_stiffness_N_per_m"][step, facet]) if at_peak else None,
        "force_true_at_force_max_N": float(log["force_solver_N"][step, facet]) if at_peak else None,
    })
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


def fitting_columns(runs: Sequence[Mapping[str, Any]], columns: Sequence[tuple],
                    width: int = TERMINAL_COLUMNS) -> list[tuple]:
    """The leading `columns` whose plain-text table (`format_table`: columns two spaces apart) is at most `width`
    characters a line; the first column always."""
    fitted: list[tuple] = []
    line = -2
    for column in columns:
        column_width = max(len(cell) for cell in [column[0]] + [_cell(r.get(column[1]), *column[2:]) for r in runs])
        if fitted and line + 2 + column_width > width:
            break
        fitted.append(column)
        line += 2 + column_width
    return fitted


def write_table(out_dir: Path, runs: Sequence[Mapping[str, Any]], columns: Sequence[tuple],
                width: int = TERMINAL_COLUMNS) -> str:
    """Write the full table of `runs` to out_dir/TABLE_FILE and return the text to print: the columns that fit
    `width` characters a line with the first column's labels cut (`plot_labels`), then, when columns are left out
    or labels cut, a line counting the columns left out and naming the file (module docstring)."""
    full = format_table(runs, columns)
    path = Path(out_dir) / TABLE_FILE
    path.write_text(full + "\n", encoding="utf-8")
    label = columns[0][1]
    shown_runs = [{**r, label: short} for r, short in zip(runs, plot_labels([str(r.get(label)) for r in runs]))]
    fitted = fitting_columns(shown_runs, columns, width)
    text = format_table(shown_runs, fitted)
    left_out = [c[0] for c in columns[len(fitted):]]
    if left_out or shown_runs != list(runs):
        text += f"\n{f'{len(left_out)} more columns' if left_out else 'full labels'} (every column): {path}"
    return text
