"""What c-erg's gain samples against the plate can tell, read from recorded runs (controllers.governors.gain_estimate, "in contact").

For every run folder under the given folders (a `softcbf run` folder, or a `softcbf bench` / study folder that holds
them), the rows of its time series where c-erg would take a rest sample against the plate:

- the estimate at rest, every |q̂̇_i| ≤ --rest-rad-s (c-erg's `gain_rest_rad_s`), and every one before it over the
  last --rest-s (c-erg's `gain_rest_s`; 0: this one alone); every such row is read, a superset of the samples
  c-erg takes (with gain_rest_s > 0 it takes one per gain_rest_s among them);
- the pressure settled: p, the first-order lag (the run's τ_p) of the recorded valve command u_applied, within
  --settle-rad of the command's rest shape (|λ_i/k_i (p_i − u_i)|), and its rest shape λ_i/k_i p_i within
  STEADY_RAD over the last HOLD_S (so the pressure at the estimate's capture, up to HOLD_S earlier, is the
  same to STEADY_RAD);
- the model's tip r(q̂) within --clearance-m of a facet plane (c-erg's `gain_clearance_m`).

At each: x = K⁻¹Λp (the model's rest shape), x̃ = x projected K-orthogonally off K⁻¹J_r(q̂)ᵀn̂_j of those facets
(`GainEstimator.free_part`), θ the K-angle between x and that span (for one facet), the sample's own bound
e = Δ Σk_i|x̃_i| / |x̃|²_K for Δ = --noise-rad, and the deviation that Δ must bound there,
|x̃ᵀK(y − g x)| / Σk_i|x̃_i| with y = q̂ + K⁻¹D q̂̇ and g the run's true gain (`true_gain_scale`). Reading the
recorded rows, not the governor's calls: the pressure is reconstructed and the estimate's capture time is
not recorded, hence the steadiness condition; figures close to, not identical with, the governor's own samples.

--replay instead runs each run's configuration again (`softcbf run --config`, into a temporary folder) and reads
the c-erg governor's own inputs at every call (`controllers.governors.energy_governor.steps`'s `update_gain` wrapped: the estimate, its capture
time, the predictor's pressure and command there): the rows are then exactly the calls at which c-erg would offer
a rest sample against the plate (the same three conditions, the pressure settled to --settle-rad as c-erg's
`gain_noise_rad` asks), while the arm is still settling too. It needs the run's filter to be c-erg with
`gain_estimate=true` (else update_gain is never called) and takes a run's simulated time again.

    PYTHONPATH=. python tools/gain_contact_samples.py BENCH_OR_RUN_DIR ... [--rest-rad-s 0.003] [--noise-rad 1e-3]
    PYTHONPATH=. python tools/gain_contact_samples.py RUN_DIR ... --replay --settle-rad 1e-3

Prints one line per run with rows, θ, |x̃|_K, e and the deviation (max, median), then one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from controllers.governors.energy_governor import steps as governor_steps
from controllers.governors.gain_estimate import GainEstimator
from controllers.model.pcc import tip_jacobian, tip_position
from scenarios.common import load_environment, load_robot, scale_damping

HOLD_S = 0.2
"""Rows count only when the pressure has been steady for this long (s): longer than the camera loop's capture
latency (≈ 0.07 s mean, 0.11 s max on camera_loop), so the pressure at the estimate's capture is the row's."""

STEADY_RAD = 1e-4
"""How steady (rad of rest shape, λ_i/k_i p_i) the pressure must have been over HOLD_S."""


def run_folders(roots: list[Path]) -> list[Path]:
    """Every folder under `roots` with a config.json and a timeseries/ (a run folder), sorted."""
    return sorted({config.parent for root in roots for config in root.rglob("config.json")
                   if (config.parent / "timeseries").is_dir()})


def recorded_states(folder: Path, estimator: GainEstimator, tau: float, settle_rad: float):
    """(t, q̂, q̂̇, p, settled) at every recorded row, settled where the pressure is settled and steady (module
    docstring)."""
    series = next(p for p in sorted((folder / "timeseries").glob("*.npz")) if not p.stem.endswith("__frames"))
    data = np.load(series)
    t, q, qd, u = data["t"], data["q_est"], data["qd_est"], data["u_applied"]
    p = np.zeros_like(u)
    for i in range(1, len(t)):  # the exact first-order lag over each recorded interval (u held in it)
        decay = math.exp(-(t[i] - t[i - 1]) / tau) if tau > 0.0 else 0.0
        p[i] = u[i - 1] + (p[i - 1] - u[i - 1]) * decay
    shape = estimator.a * p  # (T, N) rad
    for i in range(len(t)):
        window = shape[(t >= t[i] - HOLD_S) & (t <= t[i])]
        settled = bool(t[i] - t[0] >= HOLD_S and np.max(np.abs(window - shape[i])) <= STEADY_RAD
                       and np.max(np.abs(estimator.a * (p[i] - u[i]))) <= settle_rad)
        yield float(t[i]), q[i], qd[i], p[i], settled


def replayed_states(folder: Path, estimator: GainEstimator, settle_rad: float):
    """(t_capture, q̂, q̂̇, p, settled) at every c-erg call of the run replayed, settled where the predictor's pressure
    is (module docstring)."""
    from softcbf.cli import main as cli

    calls = []
    offer = governor_steps.update_gain

    def recorded(model, state, q, qd, t_capture):
        calls.append((float(t_capture), np.array(q, dtype=float), np.array(qd, dtype=float),
                      state.predictor.pressure_at(t_capture), state.predictor.command_at(t_capture)))
        return offer(model, state, q, qd, t_capture)

    governor_steps.update_gain = recorded
    try:
        with tempfile.TemporaryDirectory() as out:
            cli(["run", "--config", str(folder / "config.json"), "--out", str(Path(out) / "run"), "--progress", "false"])
    finally:
        governor_steps.update_gain = offer
    if not calls:
        raise SystemExit(f"{folder}: c-erg's update_gain was never called (the run's filter needs gain_estimate=true)")
    for t_capture, q, qd, p, u in calls:
        yield t_capture, q, qd, p, bool(np.max(np.abs(estimator.a * (p - u))) <= settle_rad)


def contact_samples(folder: Path, rest_rad_s: float, rest_s: float, settle_rad: float, clearance_m: float,
                    noise_rad: float, replay: bool) -> dict:
    """The run's rest samples against the plate (module docstring): θ (deg), |x̃|_K (rad), e (1), the deviation (rad)."""
    params = json.loads((folder / "config.json").read_text(encoding="utf-8"))["params"]
    robot = scale_damping(load_robot(params.get("robot", "reference")), params.get("damping_scale", 1.0))
    environment = load_environment(params.get("environment", "paper"))
    gain, tau = float(params.get("true_gain_scale", 1.0)), float(params.get("tau_p", 0.0))
    k, lengths = robot.array("stiffness"), robot.array("lengths")
    estimator = GainEstimator(k, robot.array("gains") / k, robot.array("damping"), (0.9, 1.1), noise_rad)
    states: Iterable = (replayed_states(folder, estimator, settle_rad) if replay
                        else recorded_states(folder, estimator, tau, settle_rad))
    rows, rest_since = [], None
    for t, q, qd, p, settled in states:
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))) or np.max(np.abs(qd)) > rest_rad_s:
            rest_since = None  # c-erg's rule (`gain_rest_s`): at rest for rest_s without a break
            continue
        rest_since = t if rest_since is None else rest_since
        if not settled or t - rest_since < rest_s:
            continue
        tip = tip_position(q, lengths)
        near = environment.normals[environment.normals @ tip - environment.offsets > -clearance_m]
        if not len(near):
            continue
        x = estimator.a * p
        free = estimator.free_part(x, tip_jacobian(q, lengths).T @ near.T)  # off K⁻¹J_r(q̂)ᵀn̂_j
        xx, w = float(np.sum(k * free * free)), float(np.sum(k * np.abs(free)))
        if xx == 0.0:
            continue
        sine = math.sqrt(xx / float(np.sum(k * x * x)))
        deviation = abs(float(np.sum(k * free * (estimator.rest_residual(q, qd) - gain * x)))) / w
        rows.append((math.degrees(math.asin(min(1.0, sine))), math.sqrt(xx), noise_rad * w / xx, deviation))
    figures = np.array(rows).reshape(-1, 4)
    summary = {"run": str(folder), "true_gain": gain, "rows": len(rows)}
    if rows:
        summary.update(theta_deg_median=float(np.median(figures[:, 0])), free_norm_median=float(np.median(figures[:, 1])),
                       bound_min=float(figures[:, 2].min()), bound_median=float(np.median(figures[:, 2])),
                       deviation_max_rad=float(figures[:, 3].max()), deviation_median_rad=float(np.median(figures[:, 3])))
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="run, bench or study folders (searched recursively)")
    parser.add_argument("--rest-rad-s", type=float, default=0.02, help="largest |q̂̇_i| of a rest sample (rad/s)")
    parser.add_argument("--rest-s", type=float, default=0.0, help="how long at rest before a sample (s; c-erg's gain_rest_s)")
    parser.add_argument("--settle-rad", type=float, default=1e-3, help="largest |λ_i/k_i (p_i − u_i)| (rad)")
    parser.add_argument("--clearance-m", type=float, default=5e-3, help="facet planes within this of the tip (m)")
    parser.add_argument("--noise-rad", type=float, default=5e-3, help="Δ for the sample's bound e (rad)")
    parser.add_argument("--replay", action="store_true", help="run each configuration again, reading c-erg's inputs")
    args = parser.parse_args()
    folders = run_folders(args.folders)
    if not folders:
        raise SystemExit(f"no run folder (config.json and timeseries/) under {', '.join(map(str, args.folders))}")
    runs = [contact_samples(f, args.rest_rad_s, args.rest_s, args.settle_rad, args.clearance_m, args.noise_rad, args.replay)
            for f in folders]
    for run in runs:
        figures = "" if not run["rows"] else (
            f" θ {run['theta_deg_median']:.1f}° |x̃|_K {run['free_norm_median']:.3f} rad e min {run['bound_min']:.4f}"
            f" deviation max {run['deviation_max_rad']:.2e} median {run['deviation_median_rad']:.2e} rad")
        print(f"{run['run']}: g {run['true_gain']:.4f}, {run['rows']} rows{figures}")
    deviations = [run["deviation_max_rad"] for run in runs if run["rows"]]
    print(json.dumps({"runs": len(runs), "runs_with_rows": len(deviations), "replay": args.replay, "rest_rad_s": args.rest_rad_s,
                      "rest_s": args.rest_s, "noise_rad": args.noise_rad, "deviation_max_rad": max(deviations) if deviations else None}))


if __name__ == "__main__":
    main()
