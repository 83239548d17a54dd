"""Cost per state of the built-in filters' `filter_batch` against B scalar calls, side by side (docs/safety-filter.md#batched-built-in-filters).

paper-cbf (`CBFFilter`, HW-High, ±150 hPa, the paper's facet; `uniform_robot(N)` for N ≠ 2, the
reference arm for N = 2): B = `--batch` states whose tip is inside P (no recovery), moving,
with u_nom ~ U(−250, 250) hPa per input, drawn once in this process and handed to every tree.
Three sets per N: "mixed" (those states as drawn: nominal, qp, and a few slack states), "qp"
(only the states the scalar filter labels "qp": the enumeration's own cost) and "outside" (states of
the same draws whose tip is outside P: the quasi-static "recovery" rows, which the batch solves since
the compiled kernel, and the few infeasible "slack" states it hands to the scalar filter). Per set:
CPU µs per state of one `filter_batch` call of B states, and of B `__call__`s on the same states;
`qp share`: the states labelled "qp" or "recovery".
Each tree (`--against DIR`: a worktree of an older commit, e.g. one whose enumeration was
N = 2 only, sending every N ≠ 2 QP state to the scalar filter) runs in fresh worker processes,
twice, interleaved with the other tree's, each figure the best of both workers' `--repeats`
passes (`time.process_time`: other jobs on a shared machine disturb it far less than wall time).

qsg (`QuasiStaticGovernor`, rate limit 2000 hPa/s, 1 kHz, ±150 hPa, reference arm; this tree
only: the baseline has no `filter_batch`): B rows over `--periods` control periods of a
closed-loop-like sequence (per row the paper's sinusoid, amplitude 80 or 150 hPa, its own
phase, plus noise), CPU µs per row and period of `filter_batch` against B governors of their
own called in turn (what a batched study did before: one filter per simulation), with the
share of rows the vectorised branch decided ("nominal"). Last, this tree's enumeration forced at
every N (`cbf_qp_batch(..., max_candidates=...)` above the count) on the "qp" set: where it is slower
than the scalar filter, `ENUMERATION_MAX_CANDIDATES` hands those states to the scalar filter.

Usage: `python tools/bench_batch_filters.py [--against ../pin] [--batch 256] [--repeats 3]
[--segments 2,3,4,5]`; prints a table and ends with one line of JSON (µs; ratios scalar / batch,
> 1: the batch is cheaper, and baseline / this tree).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from timing import best_of, emit

HERE = Path(__file__).resolve().parents[1]


def _robot(n: int):
    from controllers.model.params import reference_robot, uniform_robot

    return reference_robot() if n == 2 else uniform_robot(n)


def draw_states(segments: list[int], batch: int) -> dict[str, np.ndarray]:
    """Per N: q, qd, u_nom (mixed) and the indices of the scalar filter's "qp" states (this tree)."""
    from controllers.cbf.barrier import TUNINGS
    from controllers.cbf.paper_filter import CBFFilter
    from controllers.model.safe_set import paper_safe_set

    safe_set, out, rng = paper_safe_set(), {}, np.random.default_rng(0)
    for n in segments:
        scalar = CBFFilter(_robot(n), safe_set, TUNINGS["HW-High"])
        q, qd, u_nom, qp, outside = [], [], [], [], []
        while len(q) < batch or len(qp) < batch or len(outside) < batch:
            x = np.concatenate((rng.uniform(-0.4, 0.4, n), rng.normal(0.0, 1.5, n)))
            u = rng.uniform(-250.0, 250.0, n)
            result = scalar.step(x, u)
            if not np.all(result.b > 0.0):
                if len(outside) < batch:
                    outside.append(np.concatenate((x, u)))
                continue
            if len(q) < batch:
                q.append(x[:n]), qd.append(x[n:]), u_nom.append(u)
            if result.action == "qp" and len(qp) < batch:
                qp.append(np.concatenate((x, u)))
        qp, outside = np.array(qp), np.array(outside)
        out.update({f"N{n}_q": np.array(q), f"N{n}_qd": np.array(qd), f"N{n}_u": np.array(u_nom),
                    f"N{n}_qp_q": qp[:, :n], f"N{n}_qp_qd": qp[:, n:2 * n], f"N{n}_qp_u": qp[:, 2 * n:],
                    f"N{n}_outside_q": outside[:, :n], f"N{n}_outside_qd": outside[:, n:2 * n],
                    f"N{n}_outside_u": outside[:, 2 * n:]})
    return out


def cbf_worker(states: dict[str, np.ndarray], segments: list[int], repeats: int) -> dict:
    """paper-cbf figures of the tree on sys.path (public interfaces both trees have)."""
    from controllers.cbf.barrier import TUNINGS
    from controllers.cbf.paper_filter import CBFFilter
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import EstimateBatch

    out = {}
    for n in segments:
        filt = CBFFilter(_robot(n), paper_safe_set(), TUNINGS["HW-High"])
        for name, prefix in (("mixed", f"N{n}_"), ("qp", f"N{n}_qp_"), ("outside", f"N{n}_outside_")):
            q, qd, u = states[prefix + "q"], states[prefix + "qd"], states[prefix + "u"]
            b = len(q)
            est = EstimateBatch(np.zeros(b), q, qd, np.zeros(b))
            batch = filt.filter_batch(est, u)  # warm: the kernels, the subset tables
            calls = [filt(est[i], u[i]) for i in range(b)]
            assert batch.action.tolist() == [c.action for c in calls]
            out[f"cbf_N{n}_{name}_batch_us"] = best_of(repeats, lambda: filt.filter_batch(est, u))[1].cpu / b * 1e6
            out[f"cbf_N{n}_{name}_scalar_us"] = best_of(repeats, lambda: [filt(est[i], u[i]) for i in range(b)])[1].cpu / b * 1e6
            out[f"cbf_N{n}_{name}_qp_share"] = float(np.mean(np.isin(batch.action, ("qp", "recovery"))))
    return out


def forced_enumeration(states: dict[str, np.ndarray], segments: list[int], repeats: int) -> dict:
    """This tree: `cbf_qp_batch` on the "qp" set with the enumeration forced for every N (`max_candidates`),
    CPU µs per state, and the share of states it resolved without the scalar filter."""
    from controllers.cbf.barrier import TUNINGS
    from controllers.cbf.batch import candidate_table, cbf_qp_batch
    from controllers.model.dynamics_batch import BatchDynamics
    from controllers.cbf.paper_filter import CBFFilter
    from controllers.model.safe_set import paper_safe_set

    out = {}
    for n in segments:
        robot, safe_set = _robot(n), paper_safe_set()
        scalar, dynamics = CBFFilter(robot, safe_set, TUNINGS["HW-High"]), BatchDynamics(robot)
        q, qd, u = states[f"N{n}_qp_q"], states[f"N{n}_qp_qd"], states[f"N{n}_qp_u"]
        limits = np.array(robot.u_min), np.array(robot.u_max)

        def run():
            return cbf_qp_batch(dynamics, safe_set, TUNINGS["HW-High"], q, qd, u, *limits, max_candidates=2**62,
                                fallback=lambda i: scalar.step(np.concatenate((q[i], qd[i])), u[i]))

        p = len(safe_set.h_prime)
        out[f"cbf_N{n}_candidates"] = len(candidate_table(p + 2 * n, n, p))
        out[f"cbf_N{n}_forced_resolved"] = float(np.mean(run().resolved))
        out[f"cbf_N{n}_forced_us"] = best_of(repeats, run)[1].cpu / len(q) * 1e6
    return out


def qsg_figures(batch: int, periods: int, repeats: int) -> dict:
    """qsg: filter_batch against B governors of their own over one closed-loop-like sequence."""
    from controllers.model.params import reference_robot
    from controllers.governors.quasi_static_governor import QuasiStaticGovernor
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import EstimateBatch, FilterContext

    ctx = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3)
    rng = np.random.default_rng(1)
    amplitude = rng.choice([80.0, 150.0], (batch, 1))
    phase = rng.uniform(0.0, 2 * np.pi, (batch, 2))
    t = 1e-3 * np.arange(periods)
    u_nom = amplitude[None] * np.sin(2 * np.pi * t[:, None, None] + phase[None]) + rng.normal(0.0, 0.5, (periods, batch, 2))
    est = EstimateBatch(np.zeros(batch), np.zeros((batch, 2)), np.zeros((batch, 2)), np.zeros(batch))
    rows = [est[b] for b in range(batch)]
    shared = QuasiStaticGovernor(ctx, rate_limit_hPa_per_s=2000.0)
    own = [QuasiStaticGovernor(ctx, rate_limit_hPa_per_s=2000.0) for _ in range(batch)]
    nominal = []

    def run_batch():
        shared.reset()
        for k in range(periods):
            nominal.append(np.mean(shared.filter_batch(est, u_nom[k]).action == "nominal"))

    def run_scalar():
        for g in own:
            g.reset()
        for k in range(periods):
            for b, g in enumerate(own):
                g(rows[b], u_nom[k, b])

    per = batch * periods
    out = {"qsg_batch_us": best_of(repeats, run_batch)[1].cpu / per * 1e6, "qsg_scalar_us": best_of(repeats, run_scalar)[1].cpu / per * 1e6}
    out["qsg_nominal_share"] = float(np.mean(nominal))
    return out


def run_tree(tree: Path, states_file: str, segments: str, repeats: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    result = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", states_file, "--segments", segments,
                             "--repeats", str(repeats)], env=env, capture_output=True, text=True, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, help="the baseline tree (a worktree of an older commit)")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--periods", type=int, default=100, help="qsg: control periods of the sequence")
    parser.add_argument("--segments", default="2,3,4,5")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    segments = [int(n) for n in args.segments.split(",")]
    if args.worker:
        with np.load(args.worker) as data:
            emit(cbf_worker(dict(data), segments, args.repeats))
        return
    tmp = tempfile.TemporaryDirectory()
    states_file = str(Path(tmp.name) / "states.npz")
    np.savez(states_file, **draw_states(segments, args.batch))
    this, base = {}, {}
    for _ in range(2):  # the trees' workers interleaved (this, baseline, this, baseline): the best of each
        for tree, figures in ((HERE, this), (args.against, base)):
            if tree is not None:
                for key, value in run_tree(tree, states_file, args.segments, args.repeats).items():
                    figures[key] = min(figures.get(key, value), value)
    report = {"batch": args.batch, "this": this, "baseline": base, "baseline_tree": str(args.against) if args.against else None,
              "load_1min": os.getloadavg()[0]}
    print(f"paper-cbf HW-High ±150 hPa, B = {args.batch}: CPU µs per state (baseline: {args.against})")
    print(f"{'N':>2s} {'set':6s} {'qp share':>8s} {'scalar':>9s} {'batch':>9s} {'scalar/batch':>12s} "
          f"{'base batch':>10s} {'base/this':>9s}")
    ratios = {}
    for n in segments:
        for name in ("mixed", "qp", "outside"):
            key = f"cbf_N{n}_{name}"
            scalar, batch = this[f"{key}_scalar_us"], this[f"{key}_batch_us"]
            old = base.get(f"{key}_batch_us", float("nan"))
            ratios[key] = {"scalar_over_batch": scalar / batch, "baseline_over_this": old / batch}
            print(f"{n:2d} {name:6s} {this[f'{key}_qp_share']:8.2f} {scalar:9.1f} {batch:9.1f} {scalar / batch:12.2f} "
                  f"{old:10.1f} {old / batch:9.2f}")
    report["cbf_ratios"] = ratios
    with np.load(states_file) as data:
        forced = forced_enumeration(dict(data), segments, args.repeats)
    report["forced_enumeration"] = forced
    print("the enumeration forced for every N (cbf_qp_batch, max_candidates unbounded), 'qp' set: CPU µs per state, "
          "share resolved / this tree's scalar __call__")
    for n in segments:
        print(f"{n:2d} {forced[f'cbf_N{n}_candidates']:5d} candidates {forced[f'cbf_N{n}_forced_us']:9.1f} µs, "
              f"{forced[f'cbf_N{n}_forced_resolved']:.2f} resolved / "
              f"{this[f'cbf_N{n}_qp_scalar_us']:.1f} µs scalar")
    qsg = qsg_figures(args.batch, args.periods, args.repeats)
    report["qsg"] = qsg
    report["qsg_scalar_over_batch"] = qsg["qsg_scalar_us"] / qsg["qsg_batch_us"]
    print(f"qsg (rate limit 2000 hPa/s), B = {args.batch}, {args.periods} periods: {qsg['qsg_batch_us']:.1f} µs per row "
          f"and period batched, {qsg['qsg_scalar_us']:.1f} µs with B governors "
          f"({report['qsg_scalar_over_batch']:.2f}×); rows nominal: {qsg['qsg_nominal_share']:.2f}")
    tmp.cleanup()
    print(f"load (1 min): {report['load_1min']:.2f}")
    emit(report)


if __name__ == "__main__":
    main()
