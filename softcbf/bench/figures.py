"""The figures of one bench case from its run folders (`pooled_figures`; the row fields: softcbf.bench.schema).

Per (filter, case): ρ_meas min, t_violation, F max from the scenario's summary row (the emulator: F max and
t_violation from its 1 kHz ground truth, ρ_meas at the control cycles); u_dev_rms_hPa, blocked_s,
switches_per_s, filter_us_median and filter_us_p99 from `controllers.contract.filter_metrics.governor_figures` over the
filter's call rows of the run's time series (u: the command sent).

Nominal acceptance: the fraction of the filter's calls whose command u equals the nominal u_nom in every
segment, |u_i − u_nom,i| ≤ `ACCEPT_TOL_HPA` for all i (how often the filter stays out of the way; 1: it never
changed a command, 0: it changed every one). The tolerance, 1e-3 hPa, lies far below any valve's resolution
and far above the rounding of a filter that returns u_nom through arithmetic; a command clipped to the
pressure limits counts as changed (u_nom is the nominal's command as given to the filter).

Cases of several runs (step, camera_mismatch, the push draws) pool them: ρ_meas min and F max over the runs,
t_violation_s and blocked_s summed, u_dev_rms the RMS over every run's calls, switches_per_s the mean over runs, the compute time
quantiles and the nominal acceptance over every call; violation_probability = k/n runs with ρ_meas < 0 and its
95 % Wilson interval (`softcbf.study.analysis`), violations = k, violation_cp95_upper its exact one-sided 95 %
Clopper–Pearson upper bound on P(violation) (1 − 0.05^(1/n) at k = 0: "none in 100 draws" states P < 3.0 %),
draws = n; single runs have null there.

Draws of a push (the push-draw cases, `draw_figures`): the pooled figures and the delivered force (`steady_force`
of each draw) over F_max, its minimum and median over the draws that ran to the end (a faulted draw has no steady
force: it counts among the violations instead; both null when every draw faulted).

A fault is never a pass (docs/studies.md#faulted-samples). A run whose filter (or nominal) faulted stops at the
vent after its fault, so its figures cover only the rows before it (a filter that raises at its first call
leaves ρ_meas min 1.0 and t_violation 0 over a few milliseconds). A case's figures say how many of its runs
faulted (`faulted`, 0: none) and the first run's fault (`fault`: {type, message, where}, null: none); with a
fault there is no verdict: rho_min_meas and t_violation_s are null, violation_probability counts each faulted
run as a violation, and the figures of the filter's calls (u_dev_rms_hPa, blocked_s, switches_per_s: null when
no run made two calls; filter_us_* and nominal_acceptance: null when none made one) and F max cover the rows up
to the fault; a contact task's force_delivered_N and force_delivered_ratio are null (no steady push).

Contact tasks. "Asking for F" means the unfiltered plant's steady measured force is F (`steady_force`: the
mean over the last third of the push of the largest facet force per sample).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.contract.filter_metrics import governor_figures
from softcbf.study.analysis import clean, clopper_pearson_upper, wilson_interval
from softcbf.study.store import StudyStore, fault_of, faulted
from softcbf_mj.outputs.push_force import steady_force_of_folder
from softcbf_mj.outputs.runio import load_timeseries, read_run_folder

ACCEPT_TOL_HPA = 1e-3  # hPa: |u_i − u_nom,i| at most this in every segment is an accepted nominal (module docstring)
CALL_SERIES = ("t", "u", "u_nom", "filter_us")

RunFigures = tuple[Mapping[str, Any], Mapping[str, np.ndarray]]
"""(a run's summary row, its call rows {t, u, u_nom, filter_us})."""


def call_rows(path: Path) -> dict[str, np.ndarray]:
    """A run's time series restricted to the filter's call rows (`CALL_SERIES`: t, u, u_nom, filter_us)."""
    series, _ = load_timeseries(path)
    calls = np.isfinite(series["filter_us"])
    return {k: np.asarray(series[k])[calls] for k in CALL_SERIES}


def run_figures(folder: Path) -> list[RunFigures]:
    """(summary row, call rows) of every run in a run folder."""
    run_folder = read_run_folder(folder)
    return [(row, call_rows(folder / row["timeseries"])) for row in run_folder.runs]


def f_max_of(folder: Path) -> float:
    """The force limit F_max (N) of a scenario's run folder (its parameters' f_max)."""
    return float(read_run_folder(folder).summary["params"]["f_max"])


def accepted_calls(u: np.ndarray, u_nom: np.ndarray, tol_hPa: float = ACCEPT_TOL_HPA) -> int:
    """How many calls (rows of u, u_nom: (T, N) hPa) returned the nominal: max_i |u_i − u_nom,i| ≤ `tol_hPa`."""
    u, u_nom = np.asarray(u, dtype=float), np.asarray(u_nom, dtype=float)
    if u.shape != u_nom.shape:
        raise ValueError(f"u and u_nom must have one shape, got {u.shape} and {u_nom.shape}")
    if u.size == 0:
        return 0
    return int(np.count_nonzero(np.max(np.abs(u - u_nom).reshape(len(u), -1), axis=1) <= tol_hPa))


def nominal_acceptance(runs: Sequence[RunFigures]) -> float | None:
    """The fraction of every run's calls that returned u_nom (`accepted_calls`); None when no run made a call."""
    calls = sum(len(c["t"]) for _, c in runs)
    return sum(accepted_calls(c["u"], c["u_nom"]) for _, c in runs) / calls if calls else None


def call_figures(runs: Sequence[RunFigures]) -> dict[str, float | None]:
    """The figures of the filter's calls pooled over `runs` (module docstring)."""
    timed = [c for _, c in runs if c["t"].size >= 2]  # a run that faulted early may have made fewer calls
    per_run = [governor_figures(c["t"], c["u"], c["u_nom"], c["filter_us"]) for c in timed]
    calls = np.concatenate([np.asarray(c["filter_us"], dtype=float) for _, c in runs])
    weights = np.array([c["t"].size for c in timed], dtype=float)
    return {
        "u_dev_rms_hPa": float(math.sqrt(np.average([f["u_dev_rms_hPa"] ** 2 for f in per_run], weights=weights)))
        if per_run else None,
        "blocked_s": float(sum(f["blocked_s"] for f in per_run)) if per_run else None,
        "switches_per_s": float(np.mean([f["switches_per_s"] for f in per_run])) if per_run else None,
        "filter_us_median": float(np.median(calls)) if calls.size else None,
        "filter_us_p99": float(np.percentile(calls, 99)) if calls.size else None,
        "nominal_acceptance": nominal_acceptance(runs),
    }


def pooled_figures(runs: Sequence[RunFigures], f_max: float, force_key: str = "force_max_N",
                   violation_key: str = "t_violation_s") -> dict[str, Any]:
    """The figures of one case from its runs' summary rows and call rows (module docstring: pooling and faults);
    `f_max` (N): the case's force limit (force_budget_used = F max / f_max)."""
    if not runs:
        raise ValueError("a case needs at least one run")
    rho = [float(r["rho_min_meas"]) for r, _ in runs]
    faults = [fault_of(r) for r, _ in runs if faulted(r)]
    force_max = max(float(r[force_key]) for r, _ in runs)
    out = {
        "rho_min_meas": None if faults else min(rho),
        "t_violation_s": None if faults else float(sum(float(r[violation_key]) for r, _ in runs)),
        "force_max_N": force_max, "f_max_N": f_max, "force_budget_used": force_max / f_max,
        "violation_probability": None, "violation_ci95": None, "draws": None, "violations": None,
        "violation_cp95_upper": None,
        **call_figures(runs),
        "faulted": len(faults), "fault": faults[0] if faults else None,
    }
    if len(runs) > 1:
        violations = sum(faulted(r) or float(r["rho_min_meas"]) < 0 for r, _ in runs)
        out.update(violation_probability=violations / len(runs), violation_ci95=list(wilson_interval(violations, len(runs))),
                   draws=len(runs), violations=violations, violation_cp95_upper=clopper_pearson_upper(violations, len(runs)))
    return out


def study_runs(folder: Path) -> list[tuple[Mapping[str, Any], Path]]:
    """A study folder run with keep_runs → (its row, its run folder) of every sample that ran (ok or faulted: a fault
    is never a pass, module docstring); RuntimeError when none did."""
    store = StudyStore.open(folder)
    rows = [r for r in store.load_rows() if clean(r) or faulted(r)]
    if not rows:
        raise RuntimeError(f"study {folder} has no finished sample")
    return [(row, store.run_dir(int(row["sample"]))) for row in rows]


def study_figures(folder: Path) -> dict[str, Any]:
    """A mismatch study folder (run with keep_runs) → the case's figures pooled over its samples (`study_runs`)."""
    samples = study_runs(folder)
    runs = [run for _, run_dir in samples for run in run_figures(run_dir)]
    return pooled_figures(runs, f_max_of(samples[0][1]))


def study_draws(folder: Path) -> tuple[list[RunFigures], list[float | None], float]:
    """A push-draw study folder (run with keep_runs) → `draw_figures`' arguments: every draw's run figures, its
    delivered force (`steady_force_of_folder`; None for a faulted draw) and F_max."""
    samples = study_runs(folder)
    runs, delivered = [], []
    for row, run_dir in samples:
        runs += run_figures(run_dir)
        delivered.append(None if faulted(row) else steady_force_of_folder(run_dir))
    return runs, delivered, f_max_of(samples[0][1])


def draw_figures(runs: Sequence[RunFigures], delivered_N: Sequence[float | None], f_max: float) -> dict[str, Any]:
    """The figures of a push under draws (module docstring): `pooled_figures` of the draws' `runs` and the delivered
    force's minimum and median / `f_max` over the draws' `delivered_N` (N; None: a faulted draw, left out)."""
    if len(delivered_N) != len(runs):
        raise ValueError(f"one delivered force per draw: {len(delivered_N)} for {len(runs)} draws")
    ratios = [d / f_max for d in delivered_N if d is not None]
    return {**pooled_figures(runs, f_max),
            "force_delivered_min_ratio": min(ratios) if ratios else None,
            "force_delivered_median_ratio": float(np.median(ratios)) if ratios else None}
