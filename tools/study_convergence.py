"""Convergence of a study's figures in the ground truth's discretisation, on the study's own task.

    .venv/bin/python tools/study_convergence.py STUDY.toml --draws 3,46,140 [--samples 0,7]
        [--setting physics_dt=2e-4 --setting links_per_segment=5,physics_dt=5e-4 ...]
        [--reference physics_dt=5e-5] [--set KEY=VALUE ...] [--workers 2]

The model's discretisation (links per segment n, physics step dt: models/softcbf_arm/README.md,
"Convergence study") was chosen on an impact task; a study's task may be gentler (the plate-error
study: a 0.01 Hz sinusoid, quasi-static contact), where a coarser setting may keep the same
accuracy. This tool measures that on the study's samples, through the study's own machinery: each
sample is `softcbf.study.runner.run_sample` of the study file with `fixed.KEY=VALUE` settings added
(`load_study(path, settings)`), its run folder kept (summary and time series only) and read back.

Settings: the study's own (always, labelled "study"), each `--setting` (comma-separated KEY=VALUE of
scenario parameters, set in the study's [fixed]) and the `--reference` (default physics_dt=5e-5).
Every run's summary.json is checked to hold the values set (a setting that never reached the
scenario is an error). Samples: `--draws` (every tuning of each draw) and `--samples` (indices).

Per sample and setting, against the reference run of the same sample: what the study reports
(F max, ρ_meas min, t_viol: their absolute differences; the violation verdict,
`softcbf.study.analysis.violated`, and whether it flips) and over the run's time series the max
plate-force error max_t |F − F_ref| and tip error max_t ‖r − r_ref‖. A setting meets the model's
criterion when, in its worst sample, the force error ≤ 1 % of F_max and the tip error ≤ 1 % of
n_max (both read from the run's scene). Differences in a closed loop include the controller's
reaction to the changed plant, as in the study itself. A verdict that flips at a sample whose
reference ρ_meas lies within the setting's ρ error of 0 is a boundary sample: the same happens
between the reference and the study's own setting.

Prints each sample's comparison (one line of JSON) when its runs are done, then one table per setting (worst
figures, their sample) and one per sample, and ends with one JSON line; Ctrl-C or SIGTERM (`kill PID`) reports
the complete samples. CPU: one run per sample and setting; run it under `nice -n 10` on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import signal
import sys
import tempfile
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

import numpy as np

from scenarios.common import data_only
from softcbf.study.analysis import violated
from softcbf.study.definition import load_study, parse_setting
from softcbf.study.execute import exit_with_parent
from softcbf.study.runner import run_sample
from softcbf_mj.outputs.progress import Progress
from softcbf_mj.outputs.runio import SUMMARY_FILE, load_timeseries

STUDY_LABEL = "study"  # the study file's own setting
DEFAULT_REFERENCE = "physics_dt=5e-5"
CRITERION_FRACTION = 0.01  # of F_max (force) and of n_max (tip): the model's criterion


def parse_overrides(text: str) -> dict[str, Any]:
    """"links_per_segment=5,physics_dt=5e-4" → {"links_per_segment": 5, "physics_dt": 0.0005} (TOML values)."""
    out: dict[str, Any] = {}
    for part in text.split(","):
        path, value = parse_setting(part)
        if len(path) != 1:
            raise ValueError(f"a setting is KEY=VALUE of scenario parameters, got {part!r}")
        out[path[0]] = value
    return out


def run_one(path: str, sets: list[str], overrides: dict[str, Any], index: int) -> dict[str, Any]:
    """In a worker: sample `index` of the study at `path` (with `sets`) and `overrides` in [fixed]; its row,
    its tip (T, 2) and plate forces (T, P), its scene's F_max and n_max, and the params the scenario ran with."""
    study = load_study(path, [*sets, *(f"fixed.{k}={json.dumps(v)}" for k, v in overrides.items())])
    with tempfile.TemporaryDirectory(prefix="study-convergence-") as tmp, data_only():
        row = run_sample(study, index, keep_dir=tmp)
        if row["status"] == "error":
            return {"row": row}
        summary = json.loads((Path(tmp) / SUMMARY_FILE).read_text(encoding="utf-8"))
        log, _ = load_timeseries(Path(tmp) / summary["runs"][0]["timeseries"])
    params = summary["params"]
    for key, value in overrides.items():
        if params.get(key) != value:
            raise ValueError(f"setting {key}={value!r} did not reach scenario {study.scenario!r} "
                             f"(it ran with {key}={params.get(key)!r})")
    scene = summary.get("scene", {})
    return {"row": row, "tip": log.get("tip"), "force": log.get("contact_force"), "params": params,
            "f_max_N": scene.get("f_max_N"), "n_max_m": scene.get("n_max_m")}


def max_error(a: np.ndarray | None, b: np.ndarray | None, norm_axis: int | None = None) -> float:
    """max over steps of |a − b| (or of the norm along `norm_axis`); NaN when either is missing."""
    if a is None or b is None or a.shape != b.shape or a.size == 0:
        return math.nan
    diff = np.abs(a - b) if norm_axis is None else np.linalg.norm(a - b, axis=norm_axis)
    return float(np.max(diff))


def compare(result: dict[str, Any], reference: dict[str, Any]) -> dict[str, Any]:
    """One sample at one setting against its reference run (module docstring)."""
    row, ref = result["row"], reference["row"]
    out: dict[str, Any] = {"status": row["status"]}
    for key in ("force_max_N", "rho_min_meas", "t_violation_s", "wall_s"):
        out[key] = row.get(key)
    out["violated"] = violated(row)
    if row["status"] != "ok" or ref["status"] != "ok":
        return out
    out["d_force_max_N"] = abs(row["force_max_N"] - ref["force_max_N"])
    out["d_rho_min_meas"] = abs(row["rho_min_meas"] - ref["rho_min_meas"])
    out["d_t_violation_s"] = abs(row["t_violation_s"] - ref["t_violation_s"])
    out["flip"] = out["violated"] != violated(ref)
    out["force_err_N"] = max_error(result["force"], reference["force"])
    out["tip_err_m"] = max_error(result["tip"], reference["tip"], norm_axis=1)
    return out


def worst(rows: dict[int, dict[str, Any]], key: str) -> tuple[float, int | None]:
    """The largest finite `key` over the samples and its sample (NaN, None: none)."""
    best, where = math.nan, None
    for index, row in rows.items():
        value = row.get(key)
        if value is not None and math.isfinite(value) and not (value <= best):
            best, where = value, index
    return best, where


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path)
    parser.add_argument("--draws", default="", help="draw indices, every tuning of each (comma-separated)")
    parser.add_argument("--samples", default="", help="sample indices (comma-separated)")
    parser.add_argument("--setting", action="append", default=[], metavar="KEY=VALUE[,KEY=VALUE]",
                        help="a discretisation to compare (repeatable), e.g. links_per_segment=5,physics_dt=5e-4")
    parser.add_argument("--reference", default=DEFAULT_REFERENCE, metavar="KEY=VALUE[,KEY=VALUE]",
                        help=f"the finer setting every run is compared with (default {DEFAULT_REFERENCE})")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="as `softcbf study run --set`")
    parser.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    args = parser.parse_args()
    try:
        study = load_study(args.study, args.set)
        settings = {STUDY_LABEL: {}, **{s: parse_overrides(s) for s in args.setting}}
        reference = parse_overrides(args.reference)
        for overrides in (*settings.values(), reference):  # refused here, with the study's own message
            load_study(args.study, [*args.set, *(f"fixed.{k}={json.dumps(v)}" for k, v in overrides.items())])
        indices = [int(d) * len(study.tunings) + t for d in filter(None, args.draws.split(","))
                   for t in range(len(study.tunings))]
        indices += [int(i) for i in filter(None, args.samples.split(","))]
        indices = list(dict.fromkeys(indices))  # in the order given (run first, so an interrupt keeps them)
        if not indices:
            raise ValueError("give --draws or --samples")
        for i in indices:
            study.sample(i)  # IndexError: out of range
        if args.workers < 1:
            raise ValueError(f"--workers must be >= 1, got {args.workers}")
    except (ValueError, IndexError) as exc:
        sys.exit(f"study_convergence: {exc}")

    jobs = [(label, overrides, i) for i in indices for label, overrides in (("reference", reference), *settings.items())]
    results: dict[tuple[str, int], dict[str, Any]] = {}
    progress = Progress("study_convergence", len(jobs), unit="runs")
    progress.update(0)
    start = time.perf_counter()
    pool = ProcessPoolExecutor(max_workers=args.workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=exit_with_parent, initargs=(os.getpid(),))  # no orphans when killed
    pending = {pool.submit(run_one, str(args.study), args.set, overrides, i): (label, i)
               for label, overrides, i in jobs}
    runs_per_sample = 1 + len(settings)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # kill PID reports as Ctrl-C does
    signal.signal(signal.SIGINT, signal.default_int_handler)  # also when started in the background (SIGINT ignored)
    try:
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                label, i = pending.pop(future)
                results[(label, i)] = future.result()
                if sum(1 for (_, j) in results if j == i) == runs_per_sample:  # the sample is complete
                    print(f"sample {i}: " + json.dumps({lab: compare(results[(lab, i)], results[("reference", i)])
                                                        for lab in settings}), flush=True)
            progress.update(len(results))
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the samples that are complete are reported
        print(f"interrupted: {len(pending)} runs not done; the table holds the complete samples", file=sys.stderr)
    finally:
        pool.shutdown(wait=not pending, cancel_futures=True)
    wall = time.perf_counter() - start
    indices = [i for i in indices if all((lab, i) in results for lab in ("reference", *settings))]
    if not indices:
        sys.exit("study_convergence: no sample complete")

    first = next(results[k] for k in results if k[1] in indices and "params" in results[k])
    f_max, n_max = first["f_max_N"], first["n_max_m"]
    tol_force = CRITERION_FRACTION * f_max if f_max else math.nan
    tol_tip = CRITERION_FRACTION * n_max if n_max else math.nan
    keys = sorted({k for o in (*settings.values(), reference) for k in o})
    own_run = results.get((STUDY_LABEL, indices[0]), {})
    own = {k: own_run.get("params", {}).get(k) for k in keys}
    print(f"\n{study.name}: {len(indices)} samples, reference {args.reference}; the study's own setting: "
          + ", ".join(f"{k}={v!r}" for k, v in own.items()) + f"; {wall:.0f} s wall on {args.workers} worker(s)")
    print(f"criterion: worst force error <= {tol_force * 1e3:.2f} mN (1 % of F_max), "
          f"tip error <= {tol_tip * 1e3:.3f} mm (1 % of n_max)\n")
    print(f"{'setting':<34} {'F err/mN':>9} {'tip/mm':>7} {'dFmax/mN':>9} {'drho':>7} {'dt_viol/s':>9} "
          f"{'flips':>5} {'wall/s':>7}  meets  (worst sample)")
    report: dict[str, Any] = {"study": study.name, "samples": indices, "reference": args.reference,
                              "own_setting": own, "tol_force_N": tol_force, "tol_tip_m": tol_tip,
                              "wall_s": wall, "workers": args.workers, "settings": {}}
    per_sample: dict[str, dict[int, dict[str, Any]]] = {}
    for label in settings:
        rows = {i: compare(results[(label, i)], results[("reference", i)]) for i in indices}
        per_sample[label] = rows
        figures = {key: worst(rows, key) for key in ("force_err_N", "tip_err_m", "d_force_max_N", "d_rho_min_meas",
                                                     "d_t_violation_s")}
        flips = [i for i, r in rows.items() if r.get("flip")]
        failed = [i for i, r in rows.items() if r["status"] != "ok"]
        walls = [r["wall_s"] for r in rows.values() if r.get("wall_s") is not None]
        meets = (not failed and figures["force_err_N"][0] <= tol_force and figures["tip_err_m"][0] <= tol_tip)
        print(f"{label:<34} {figures['force_err_N'][0] * 1e3:9.3f} {figures['tip_err_m'][0] * 1e3:7.4f} "
              f"{figures['d_force_max_N'][0] * 1e3:9.3f} {figures['d_rho_min_meas'][0]:7.4f} "
              f"{figures['d_t_violation_s'][0]:9.3f} {len(flips):5d} {np.mean(walls) if walls else math.nan:7.1f}  "
              f"{'yes' if meets else 'no ':<5}  (F {figures['force_err_N'][1]}, tip {figures['tip_err_m'][1]})"
              + (f"  failed: {failed}" if failed else ""))
        report["settings"][label] = {"overrides": settings[label], "meets": meets, "flips": flips, "failed": failed,
                                     "loop_wall_s_mean": float(np.mean(walls)) if walls else None,
                                     **{f"worst_{k}": v for k, (v, _) in figures.items()},
                                     **{f"worst_{k}_sample": s for k, (_, s) in figures.items()}}
    print(f"\nper sample: F max [mN] / rho_meas min / t_viol [s] / verdict (V: violated), reference first")
    for i in indices:
        sample = study.sample(i)
        values = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v!r}" for k, v in sample.values.items())
        ref = compare(results[("reference", i)], results[("reference", i)])
        cells = [ref, *(per_sample[label][i] for label in settings)]
        text = "  ".join(f"{c['force_max_N'] * 1e3:6.1f}/{c['rho_min_meas']:+.4f}/{c['t_violation_s']:5.2f}/"
                         f"{'V' if c['violated'] else '-'}" if c["status"] == "ok" else f"{c['status']:^26}" for c in cells)
        print(f"  {i:5d} {sample.tuning:<8} {values}: {text}")
    report["per_sample"] = {label: {str(i): r for i, r in rows.items()} for label, rows in per_sample.items()}
    report["reference_rows"] = {str(i): {k: results[("reference", i)]["row"].get(k) for k in
                                         ("status", "force_max_N", "rho_min_meas", "t_violation_s", "wall_s")}
                                for i in indices}
    print(json.dumps(report), flush=True)


if __name__ == "__main__":
    main()
