"""Per-solve time of each QP backend on the CBF filter's problem (docs/model.md#control-barrier-function).

Problem: N = 2 pressures (hPa), one CBF row with L_gB-sized coefficients (≈ 1e-5…1e-4
per hPa) and the ±150 hPa box. Three cases, `--samples` random problems each (u_nom
of 40…80 hPa as in the paper's sinusoid), each checked to be what it claims:
- inactive: u_nom already satisfies the row (the front end returns it; no backend runs),
- row:      the CBF row is active, the box is not,
- row+box:  the solution lies at the row's intersection with a bound.
Every backend is timed through `solve_qp` (what the filter pays), one call at a time,
round-robin over the backends per sample so that drifting machine load biases none of
them; qpsolvers:osqp (≈ 1 ms) only every 10th sample. For reference, the 'raw' rows time
the solvers' own APIs on every 10th (already normalised) active-row problem without the
front end: daqp.solve, quadprog.solve_qp, and OSQP and ProxQP (dense) with one workspace
set up once and updated per solve. The garbage collector is off while timing (as in
timeit). The default clock is the thread's CPU time, so that other processes sharing the
machine do not inflate the figures (with --clock wall they add multi-ms p99 outliers).
Prints a table (median and p99 in µs) and, last, one line of JSON with the same figures.

Usage: python tools/bench_qp.py [--samples 3000] [--seed 0] [--clock cpu|wall]
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
from typing import Callable

import numpy as np

from controllers.cbf.qp import DEFAULT_BACKEND, available_backends, solve_qp
from timing import CLOCKS_NS, call_us, emit, summary_us

U_MAX = 150.0


def cases(rng: np.random.Generator, samples: int) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """(u_nom, A (1, 2), b (1,)) per sample and case; each case is checked to be what it claims."""
    out: dict[str, list] = {"inactive": [], "row": [], "row+box": []}
    box = dict(lb=-U_MAX * np.ones(2), ub=U_MAX * np.ones(2))
    while min(len(v) for v in out.values()) < samples:
        u_nom = rng.uniform(40.0, 80.0, 2)
        a = rng.uniform(1e-5, 1e-4, 2)
        norm = np.linalg.norm(a)
        candidates = {
            "inactive": (u_nom, a[None], np.array([a @ u_nom + rng.uniform(1.0, 10.0) * norm])),
            "row": (u_nom, a[None], np.array([a @ u_nom - rng.uniform(5.0, 40.0) * norm])),
            "row+box": (np.array([-U_MAX + 10.0, u_nom[1]]), a[None], np.array([a @ [-U_MAX, rng.uniform(-140.0, 0.0)]])),
        }
        for case, (u, A, b) in candidates.items():
            sol = solve_qp(u, A, b, backend="native", **box)
            bound_active = np.any(np.isclose(np.abs(sol.u), U_MAX, rtol=0, atol=1e-9))
            expected = {"inactive": (False, False), "row": (True, False), "row+box": (True, True)}[case]
            if (bool(sol.active[0]), bound_active) == expected and len(out[case]) < samples:
                out[case].append((u, A, b))
    return out


def raw_solvers() -> dict[str, Callable[[np.ndarray, np.ndarray, np.ndarray], object]]:
    """Own-API solves of the normalised problem (u_nom, â (1, 2), b̂ (1,)) with the box, no checks.

    OSQP and ProxQP keep one workspace set up at the first call and update q, A and b after.
    """
    import daqp
    import quadprog

    lb, ub = -U_MAX * np.ones(2), U_MAX * np.ones(2)
    sense = np.zeros(3, dtype=np.int32)
    eye = np.eye(2)
    solvers: dict[str, Callable] = {
        "raw daqp.solve": lambda u, a, b: daqp.solve(
            eye, -u, a, np.concatenate((ub, b)), np.concatenate((lb, [-1e30])), sense),
        "raw quadprog.solve_qp": lambda u, a, b: quadprog.solve_qp(
            eye, u, np.vstack((-a, eye, -eye)).T, np.concatenate((-b, lb, -ub)), 0),
    }
    try:
        import osqp
        import scipy.sparse as sp

        osqp_model: list = []

        def osqp_solve(u, a, b):
            if not osqp_model:
                osqp_model.append(osqp.OSQP())
                osqp_model[0].setup(sp.csc_matrix(eye), -u, sp.csc_matrix(np.vstack((a, eye))),
                                    np.concatenate(([-np.inf], lb)), np.concatenate((b, ub)),
                                    verbose=False, eps_abs=1e-9, eps_rel=1e-9, polishing=True)
            # [â; I] in CSC order: â_1, 1, â_2, 1 (the pattern of the set-up matrix)
            osqp_model[0].update(q=-u, Ax=np.array([a[0, 0], 1.0, a[0, 1], 1.0]), u=np.concatenate((b, ub)))
            return osqp_model[0].solve()
        solvers["raw osqp (one workspace, update)"] = osqp_solve
    except ImportError:
        pass
    try:
        from proxsuite import proxqp

        prox_model: list = []

        def proxqp_solve(u, a, b):
            if not prox_model:
                prox_model.append(proxqp.dense.QP(2, 0, 1, True))
                prox_model[0].settings.eps_abs = 1e-9
                prox_model[0].init(eye, -u, None, None, a, None, b, lb, ub)
            prox_model[0].update(eye, -u, None, None, a, None, b, lb, ub)
            prox_model[0].solve()
            return prox_model[0].results.x
        solvers["raw proxqp dense (one workspace, update)"] = proxqp_solve
    except ImportError:
        pass
    return solvers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--clock", choices=list(CLOCKS_NS), default="cpu",
                        help="cpu: this thread's CPU time (immune to other processes on a shared machine; "
                             "~1 µs clock overhead); wall: elapsed time")
    args = parser.parse_args()
    problems = cases(np.random.default_rng(args.seed), args.samples)
    box = dict(lb=-U_MAX * np.ones(2), ub=U_MAX * np.ones(2))
    backends = available_backends()
    raw = raw_solvers()
    gc.disable()  # as timeit does: collector pauses would land on whichever call triggers them
    times: dict[str, dict[str, list[float]]] = {name: {} for name in backends + list(raw)}
    for case, items in problems.items():
        for backend in backends:  # warm-up: imports, first-call set-up
            solve_qp(*items[0], backend=backend, **box)
        for solve in raw.values() if case == "row" else ():
            solve(*items[0])
        # round-robin over backends per sample, so that drifting machine load biases none of them
        for k, (u, A, b) in enumerate(items):
            for backend in backends:
                if backend != "qpsolvers:osqp" or k % 10 == 0:
                    times[backend].setdefault(case, []).append(call_us(lambda: solve_qp(u, A, b, backend=backend, **box), args.clock)[1])
            if case == "row" and k % 10 == 0:
                a_hat, b_hat = A / np.linalg.norm(A), b / np.linalg.norm(A)
                for name, solve in raw.items():
                    times[name].setdefault(case, []).append(call_us(lambda: solve(u, a_hat, b_hat), args.clock)[1])
    results = {name: {case: summary_us(t) for case, t in row.items()} for name, row in times.items()}
    case_names = list(problems)
    print(f"QP per-solve {args.clock} time, N=2, 1 CBF row + ±{U_MAX:g} hPa box, {args.samples} samples/case "
          f"({platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__})")
    header = f"{'backend':40s}" + "".join(f"{c + ' med':>14s}{c + ' p99':>14s}" for c in case_names)
    print(header)
    print("-" * len(header))
    for name, row in results.items():
        cells = "".join(f"{row[c]['median_us']:14.1f}{row[c]['p99_us']:14.1f}" if c in row else f"{'':14s}{'':14s}"
                        for c in case_names)
        print(f"{name:40s}{cells}")
    print(f"(µs; default backend: {DEFAULT_BACKEND}; qpsolvers:osqp and the raw rows use 1/10 of the samples)")
    emit({"unit": "us", "clock": args.clock, "samples": args.samples, "default": DEFAULT_BACKEND, "results": results})


if __name__ == "__main__":
    main()
