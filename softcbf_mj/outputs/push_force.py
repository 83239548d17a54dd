"""The force a push delivers: the steady measured plate force of one run.

A push (a constant command held from rest) settles against the plate; its delivered force is the mean, over the last
third of the run's samples, of the largest facet force per sample (N). The last third leaves out the approach and the
first contact's transient of every push the battery and the tuning studies run (6–12 s pushes settle within the
first half); a run shorter than three samples uses its last sample. The bench (`softcbf.bench`) and robust tuning
(`softcbf.study.tune`) read it from the run's time series (`contact_force`, (T,) or (T, plates) N) alike.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from softcbf_mj.outputs.runio import load_timeseries, read_run_folder


def steady_force(force: np.ndarray) -> float:
    """The steady measured force of a push (N): the mean over the last third of the run's samples of the
    largest facet force per sample (`force`: (T,) or (T, plates) N)."""
    force = np.asarray(force, dtype=float)
    per_sample = force.max(axis=1) if force.ndim == 2 else force
    if per_sample.size == 0:
        raise ValueError("a push needs at least one force sample")
    return float(np.mean(per_sample[-max(1, per_sample.size // 3):]))


def steady_force_of_folder(folder: Path) -> float:
    """`steady_force` of the one run in a run folder (its time series' `contact_force`)."""
    run_folder = read_run_folder(folder)
    if len(run_folder.runs) != 1:
        raise ValueError(f"{folder} holds {len(run_folder.runs)} runs; a push is one run")
    series, _ = load_timeseries(folder / run_folder.runs[0]["timeseries"])
    return steady_force(series["contact_force"])
