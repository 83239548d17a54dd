"""Robustness studies: how safe is the CBF filter when its model is wrong?

A study (`definition`) runs one registered scenario many times over distributions of its
parameters — model mismatches between the ground truth and the controller's model, sensor
imperfections, tunings — sampled by seeded Monte Carlo or on a grid. `execute` runs the
samples on a local process pool or a Dask cluster and streams one row per sample into the
study folder (`store`, Parquet parts, resumable); `analysis` turns the rows into violation
probabilities with confidence intervals (Wilson, exact Clopper–Pearson) and sensitivities
(a sample whose filter faulted counts as a violation: a fault is never a pass);
`report` writes the plots and a Markdown summary; `sequential` draws until the violation
probability is bounded; `falsify` searches a study's box for its worst case (optuna) on the
same engine, `screen` on a cheaper scenario first (multi-fidelity), `campaign` over seeds (ARCH-COMP's
falsification rate); `tune` searches a filter's parameters for the most force that an inner falsification
cannot break; `cli` is `python -m softcbf.study run|falsify|tune|report`.
"""


import importlib
from typing import Any

_EXPORTS = {"Distribution": "definition", "Sample": "definition", "Study": "definition", "load_study": "definition",
            "StudyOutcome": "execute", "run_study": "execute", "WALL_CLOCK_COLUMNS": "store", "StudyStore": "store"}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The exports, imported on first use: `softcbf.study.cli` (mounted by `softcbf`) should not
    make `softcbf list` pay for pyarrow and the executors."""
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
