"""How far this tree's batched paper CBF (`controllers.cbf.batch.cbf_qp_batch`) moved from another tree's, and from the scalar filter.

On `--states` random N = 2 states of the reference arm around the paper's facet (q ~ U(−0.3, 0.6)
rad, q̇ ~ N(0, 1.5) rad/s, a tenth of them nearly at rest, u_nom ~ U(−250, 250) hPa: the states of
tests/test_cbf_batch.py), split evenly over the tunings Low, High, HW-Low, HW-High with and without
the ±150 hPa box, both trees' `cbf_qp_batch` run without recovery rows (the states each resolves
without the scalar filter must be the same); printed: how many commands and labels differ, and the
largest |Δu| (hPa). Then this tree with the filter's recovery rows (`RecoveryRows`) on the states
outside P against the filter's scalar QP (`CBFFilter.step(..., scalar=True)`): labels that differ and the largest
|Δu|.

Both trees run in this process: `--against DIR`'s controllers/cbf/batch.py (and its compiled kernel,
controllers/cbf/kernels.py, where it has one) is loaded under another module name on top of this tree's
other modules (the baseline must share this tree's `BatchDynamics`; true of the numpy version before the
compiled kernel). Usage:
`python tools/cbf_batch_agreement.py --against ../pin [--states 120000]`; ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import tempfile
from pathlib import Path

# numba's cache of this run, the other tree's kernel included, goes here and not into that tree's __pycache__
# (where its entries, compiled under this tool's module name, would break that tree's own runs); set before
# numba is imported
os.environ.setdefault("NUMBA_CACHE_DIR", str(Path(tempfile.gettempdir()) / "cbf_batch_agreement_numba"))

import numpy as np  # noqa: E402

from controllers.cbf.barrier import TUNINGS  # noqa: E402
from controllers.cbf.batch import RecoveryRows, cbf_qp_batch  # noqa: E402
from controllers.model.dynamics_batch import BatchDynamics  # noqa: E402
from controllers.cbf.paper_filter import CBFFilter  # noqa: E402
from controllers.model.params import reference_robot  # noqa: E402
from controllers.model.safe_set import paper_safe_set  # noqa: E402


def load_module(name: str, path: Path):
    """The module at `path`, executed under `name` (beside this tree's modules; registered, so that numba's
    cache can find it again)."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, required=True, help="the other tree (its controllers/cbf/batch.py)")
    parser.add_argument("--states", type=int, default=120_000)
    parser.add_argument("--seed", type=int, default=123)
    args = parser.parse_args()
    baseline = load_module("baseline_cbf_batch", args.against / "controllers" / "cbf_batch.py")
    kernels = args.against / "controllers" / "cbf_kernels.py"
    if kernels.exists():  # the baseline's own compiled kernel: its arguments may differ from this tree's
        baseline.cbf_kernels = load_module("baseline_cbf_kernels", kernels)
    params, safe_set = reference_robot(), paper_safe_set()
    rng = np.random.default_rng(args.seed)
    cases = [(tuning, limits) for tuning in ("Low", "High", "HW-Low", "HW-High") for limits in (True, False)]
    per = args.states // len(cases)
    report = {"states": per * len(cases), "changed": 0, "max_abs_du_hPa": 0.0, "label_differences": 0,
              "resolved_differences": 0, "recovery_states": 0, "recovery_label_differences": 0,
              "recovery_max_abs_du_hPa": 0.0}
    for tuning, limits in cases:
        q, qd = rng.uniform(-0.3, 0.6, (per, 2)), rng.normal(0.0, 1.5, (per, 2))
        qd[: per // 10] *= 1e-3
        u_nom = rng.uniform(-250.0, 250.0, (per, 2))
        bounds = (np.array(params.u_min), np.array(params.u_max)) if limits else (None, None)
        scalar = CBFFilter(params, safe_set, TUNINGS[tuning], pressure_limits=limits)

        def fallback(i: int):
            return scalar.step(np.concatenate((q[i], qd[i])), u_nom[i])

        old = baseline.cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS[tuning], q, qd, u_nom, *bounds,
                                    fallback=fallback)
        new = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS[tuning], q, qd, u_nom, *bounds, fallback=fallback)
        du = np.max(np.abs(old.u - new.u), axis=1)
        report["changed"] += int(np.count_nonzero(du > 0.0))
        report["max_abs_du_hPa"] = max(report["max_abs_du_hPa"], float(du.max()))
        report["label_differences"] += int(np.count_nonzero(old.action != new.action))
        report["resolved_differences"] += int(np.count_nonzero(old.resolved != new.resolved))
        covered = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS[tuning], q, qd, u_nom, *bounds,
                               fallback=fallback, recovery=RecoveryRows.of(params, safe_set, scalar.recovery_margin))
        outside = np.flatnonzero(covered.resolved & ~new.resolved)
        want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True) for i in outside]  # the scalar QP
        report["recovery_states"] += len(outside)
        report["recovery_label_differences"] += sum(w.action != covered.action[i] for w, i in zip(want, outside))
        report["recovery_max_abs_du_hPa"] = max([report["recovery_max_abs_du_hPa"]]
                                                + [float(np.max(np.abs(w.u - covered.u[i]))) for w, i in zip(want, outside)])
    print(f"N = 2, {report['states']} states, {args.against} against this tree (no recovery rows): "
          f"{report['changed']} commands differ (max |Δu| {report['max_abs_du_hPa']:.3g} hPa), "
          f"{report['label_differences']} labels, {report['resolved_differences']} resolved flags")
    print(f"this tree with recovery rows, {report['recovery_states']} states outside P against CBFFilter: "
          f"{report['recovery_label_differences']} labels differ, max |Δu| {report['recovery_max_abs_du_hPa']:.3g} hPa")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
