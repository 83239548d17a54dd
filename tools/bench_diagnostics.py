"""What a filter's diagnostics cost per control step: a plain dict against the recorder's flat layout, side by side.

The plug-in contract asks a filter for its diagnostics as a plain mapping (str → float or a small array). The
control step converts them once (`controllers.contract.safety_filter.OutputCheck`: every value read once into plain floats,
kept flat in the check's own layout) and the recorder copies that flat row (`closedloop.record.Recorder`). A built-in
filter may instead hand the check its values already flat (`controllers.contract.diagnostics.FlatDiagnostics`, in a layout
made once), which the check copies without unpacking: the internal fast path this benchmark measures.

Per variant, CPU µs per control step of the paper's two-segment robot (limits on, 1 kHz), best of `--repeats` passes
of `--steps` steps after a warm-up pass:
- a filter that builds its diagnostics from the same Python floats every call, with the keys, shapes and units of
  the paper CBF's (`controllers.cbf.paper_filter.CBF_DIAGNOSTIC_UNITS`: b, B, constraint, active (P,), recovery, slack,
  solve_us; P the force-safe set's rows): `dict_lists` (values as lists and floats), `dict_arrays` (numpy arrays, as
  a numpy user writes them) or `flat` (`FlatDiagnostics`);
- then the control step (`closedloop.step.ControlStep`: the output check included) and the recorder's row
  (`Recorder.record`), as every serial loop calls them;
- `none`: the same filter returning no diagnostics (the step and the row without them).
For scale, `cbf_call_us`: the paper's CBF (`paper-cbf`, tuning Low) called alone at a state inside the set, the
filter whose diagnostics these are. The figures that decide whether the fast path is worth keeping:
`flat_saves_us` = dict_arrays − flat (per step) and its share of a paper-CBF step (`flat_saves_share`: over
cbf_call_us + flat).

    .venv/bin/python tools/bench_diagnostics.py [--steps 20000] [--repeats 5]

Prints one line per variant, then one line of JSON (`timing.emit`).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from timing import best_of, emit, machine

VARIANTS = ("none", "dict_lists", "dict_arrays", "flat")


def step_us(variant: str, steps: int, repeats: int) -> float:
    """CPU µs per control step (filter call, `ControlStep`, `Recorder.record`) of `variant` (module docstring)."""
    from closedloop.record import Recorder
    from closedloop.step import ControlStep
    from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
    from controllers.cbf.paper_filter import CBF_DIAGNOSTIC_UNITS
    from controllers.model.params import reference_robot
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import Estimate, FilterContext, FilterOutput

    robot, safe_set = reference_robot(), paper_safe_set()
    context = FilterContext.for_robot(robot, safe_set, 1e-3)
    p, n = len(safe_set.H_prime), robot.n_segments
    b, big_b, constraint = [0.01 * (i + 1) for i in range(p)], [1.0 + i for i in range(p)], [-0.5] * p
    active = [False] * p
    units = dict(CBF_DIAGNOSTIC_UNITS)
    layout = DiagnosticLayout({"b": (p,), "B": (p,), "constraint": (p,), "active": (p,), "recovery": (), "slack": (),
                               "solve_us": ()}, units, frozenset({"active", "recovery"}))

    def diagnostics() -> object:
        if variant == "dict_lists":
            return {"b": b, "B": big_b, "constraint": constraint, "active": active, "recovery": False, "slack": 0.0,
                    "solve_us": 12.0}
        if variant == "dict_arrays":
            return {"b": np.array(b), "B": np.array(big_b), "constraint": np.array(constraint),
                    "active": np.array(active), "recovery": False, "slack": 0.0, "solve_us": 12.0}
        return FlatDiagnostics(layout, [*b, *big_b, *constraint, *active, False, 0.0, 12.0])

    def diagnosed(estimate, u_nom):
        if variant == "none":
            return FilterOutput(np.clip(u_nom, -100.0, 100.0), "qp")
        return FilterOutput(np.clip(u_nom, -100.0, 100.0), "qp", False, 0.5, diagnostics(), units)

    def nominal(t, q, qd):
        return np.array([80.0 * math.sin(t), -80.0 * math.sin(t)])

    control = ControlStep(diagnosed, nominal, context)
    q, qd = np.array([0.1, -0.1]), np.zeros(n)

    def one_pass() -> None:
        control.reset()
        recorder = Recorder(steps, n, {})
        for k in range(steps):
            recorder.record(k, control(Estimate(k * 1e-3, q, qd, k * 1e-3)), True, ())

    one_pass()  # warm-up: the compiled admission kernel loads on its first call
    return best_of(repeats, one_pass)[1].cpu / steps * 1e6


def cbf_call_us(calls: int, repeats: int) -> float:
    """CPU µs per call of the paper's CBF (tuning Low) alone, at a state inside the force-safe set."""
    from controllers.model.params import reference_robot
    from controllers.registry import build_filter
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import Estimate, FilterContext

    context = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3)
    cbf = build_filter("paper-cbf", {"tuning": "Low"}, context)
    q, qd, u_nom = np.array([0.1, -0.1]), np.zeros(2), np.array([20.0, -20.0])
    cbf(Estimate(0.0, q, qd, 0.0), u_nom)  # warm-up: imports, compiled kernels

    def one_pass() -> None:
        for k in range(calls):
            cbf(Estimate(k * 1e-3, q, qd, k * 1e-3), u_nom)

    return best_of(repeats, one_pass)[1].cpu / calls * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000, help="control steps per pass (default 20000)")
    parser.add_argument("--repeats", type=int, default=5, help="passes; each figure is the best (default 5)")
    args = parser.parse_args()
    if args.steps < 1 or args.repeats < 1:
        parser.error(f"--steps and --repeats must be >= 1, got {args.steps} and {args.repeats}")
    report: dict[str, object] = {"benchmark": "diagnostics", "steps": args.steps, "repeats": args.repeats}
    for variant in VARIANTS:
        report[f"{variant}_step_us"] = round(step_us(variant, args.steps, args.repeats), 2)
        print(f"{variant:12s} {report[f'{variant}_step_us']:8.2f} µs CPU per control step")
    report["cbf_call_us"] = round(cbf_call_us(max(1, args.steps // 10), args.repeats), 2)
    print(f"{'paper-cbf':12s} {report['cbf_call_us']:8.2f} µs CPU per call (the filter alone)")
    saved = report["dict_arrays_step_us"] - report["flat_step_us"]
    report["flat_saves_us"] = round(saved, 2)
    report["flat_saves_share"] = round(saved / (report["cbf_call_us"] + report["flat_step_us"]), 3)
    report.update(machine())
    emit(report)


if __name__ == "__main__":
    main()
