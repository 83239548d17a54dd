"""Robustness studies: how safe is the CBF filter when its model is wrong?

A study (`definition`) runs one registered scenario many times over distributions of its
parameters — model mismatches between the ground truth and the controller's model, sensor
imperfections, tunings — sampled by seeded Monte Carlo or on a grid. `execute` runs the
samples on a local process pool or a Dask cluster and streams one row per sample into the
study folder (`store`, Parquet parts, resumable); `analysis` turns the rows into violation
probabilities with confidence intervals and sensitivities; `report` writes the plots and a
Markdown summary; `cli` is `python -m softcbf.study run|report`.
"""

from softcbf.study.definition import Distribution, Sample, Study, load_study
from softcbf.study.execute import StudyOutcome, run_study
from softcbf.study.store import WALL_CLOCK_COLUMNS, StudyStore

__all__ = ["Distribution", "Sample", "Study", "StudyOutcome", "StudyStore", "WALL_CLOCK_COLUMNS", "load_study", "run_study"]
