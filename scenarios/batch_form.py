"""The closed loop of a scenario's batch form (docs/studies.md#batches): B samples of one tuning at once.

`run_batch_tuning` runs, for samples b = 0 … B−1 that share one `FilterContext` (but for the
nominal's parameters) and run one controller under test each (`ControllerRun` b: the same filter
spec, parameters that may differ), the plant
`plant` (a `BatchPlant` of B simulations, simulation b built from sample b) from q0_b
with the nominal controller built from sample b's parameters, through
`run_batch_closed_loop` (one control step per simulation, as a single run's), and returns
one row per sample: `BatchRun.run(b)` (the docs/run-outputs.md figures of the same names as
the single run's, with a filter fault's fields, `tests/test_study_batch.py`), `wall_s`
(the batch's wall time / B) and `batch_size` (B). Where every sample's filter parameters are equal,
the filter is built once when it declares batched (`controllers.contract.capabilities.filter_capabilities`: the
paper's CBF, `controllers.cbf.batch`), else once per simulation (B independent histories: a user's filter
runs inside the batch, the physics batched). Where they differ (a study or a tuning search that varies a filter parameter), each
simulation gets its own instance built from its own parameters, called per simulation, so row b's
commands and faults are those of sample b run alone; only the physics is batched. Each filter and
nominal is told its own copy of `context` (`FilterContext.copy`); the batched step reads its limits from
`context` itself, which no plug-in is handed.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from closedloop.isolation import isolate
from controllers.registry import build_filter, build_nominal
from controllers.contract.capabilities import filter_capabilities
from controllers.contract.safety_filter import FilterContext
from scenarios.common import ControllerRun
from softcbf_mj.loops.batch_loop import run_batch_closed_loop
from softcbf_mj.physics.plant import BatchPlant


def run_batch_tuning(plant: BatchPlant, runs: Sequence[ControllerRun], context: FilterContext, nominal: str,
                     nominal_kwargs: Sequence[dict[str, object]], duration: float,
                     q0: np.ndarray, progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """One row of run figures per simulation of `plant` (module docstring); `runs`: simulation b's controller
    under test; q0 (B, N) rad; `progress`: the batched loop's (`run_batch_closed_loop`: the fraction of the run
    done, after each control step)."""
    n_sims = plant.n_sims
    if len(runs) != n_sims or len(nominal_kwargs) != n_sims or np.shape(q0) != (n_sims, plant.n_segments):
        raise ValueError(f"runs, nominal_kwargs and q0 must hold one entry per simulation ({n_sims}), got "
                         f"{len(runs)}, {len(nominal_kwargs)} and q0 of shape {np.shape(q0)}")
    run = runs[0]
    if len({(r.filter, r.isolate) for r in runs}) != 1:
        raise ValueError("the samples of one batch must run one filter spec, isolated or not")
    if any(r.filter_params != run.filter_params for r in runs):  # one instance per simulation (module docstring)
        specs = [(r.filter, r.filter_params) for r in runs]
        if run.isolate:
            filters, nominals = isolate(context, specs, [(nominal, kw) for kw in nominal_kwargs])
        else:
            filters = [build_filter(spec, params, context.copy()) for spec, params in specs]
            nominals = [build_nominal(nominal, kwargs, context.copy()) for kwargs in nominal_kwargs]
    elif run.isolate:  # one isolated process hosts the batch's filters and nominals (closedloop.isolation)
        hosted, nominals = isolate(context, [(run.filter, run.filter_params)], [(nominal, kw) for kw in nominal_kwargs],
                                   copies=n_sims)
        filters = hosted[0] if filter_capabilities(hosted[0]).batched else hosted
    else:
        one = build_filter(run.filter, run.filter_params, context.copy())
        filters = one if filter_capabilities(one).batched else [
            build_filter(run.filter, run.filter_params, context.copy()) for _ in range(n_sims)]
        nominals = [build_nominal(nominal, kwargs, context.copy()) for kwargs in nominal_kwargs]
    result = run_batch_closed_loop(plant, filters, nominals, context, duration, q0, progress=progress)
    return [{**result.run(b), "wall_s": result.wall_s / n_sims, "batch_size": n_sims} for b in range(n_sims)]
