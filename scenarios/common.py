"""Builders shared by scenarios: robot, environment, force-safe set, tunings, one tuning's run."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from controllers.cbf import Tuning, get_tuning
from controllers.filter import CBFFilter
from controllers.nominal import NominalController
from controllers.params import RobotParams, reference_robot
from controllers.safe_set import Environment, ForceSafeSet, LinearStiffness, paper_environment
from softcbf_mj.loop import TIMESERIES_UNITS, Estimate, exact_state, run_closed_loop
from softcbf_mj.metrics import run_figures
from softcbf_mj.plant import Plant, PlantState
from softcbf_mj.progress import Progress
from softcbf_mj.runio import SummaryWriter, save_timeseries


def load_robot(spec: str) -> RobotParams:
    """'' or 'reference' → the SPEC §3 reference arm; otherwise a JSON file written by RobotParams.save."""
    if spec in ("", "reference"):
        return reference_robot()
    path = Path(spec)
    if not path.is_file():
        raise ValueError(f"robot must be 'reference' or a robot JSON file, got {spec!r} (no such file)")
    return RobotParams.load(path)


def load_environment(spec: str) -> Environment:
    """'paper' → the paper's facet; otherwise a JSON file {"H": [[a, b], ...], "h": [...]} (m)."""
    if spec == "paper":
        return paper_environment()
    path = Path(spec)
    if not path.is_file():
        raise ValueError(f"environment must be 'paper' or a JSON file with keys H and h, got {spec!r} (no such file)")
    data = json.loads(path.read_text(encoding="utf-8"))
    try:
        return Environment(np.asarray(data["H"], dtype=float), np.asarray(data["h"], dtype=float))
    except KeyError as exc:
        raise ValueError(f"environment file {path} lacks key {exc.args[0]!r} (needs H and h)") from None


def build_safe_set(environment: str, plate_stiffness: float, f_max: float, row_scaling: str) -> ForceSafeSet:
    return ForceSafeSet(load_environment(environment), LinearStiffness(plate_stiffness), f_max, row_scaling=row_scaling)


def parse_tunings(text: str) -> list[Tuning]:
    """Comma-separated tuning names ('None,Low,High'); errors list the valid names."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise ValueError("tunings must name at least one tuning, e.g. None,Low,High")
    return [get_tuning(name) for name in names]


def initial_configuration(n_segments: int, seed: int, q0_std: float) -> np.ndarray:
    """Straight arm, plus seeded Gaussian noise of q0_std rad per segment."""
    if q0_std < 0:
        raise ValueError(f"q0_std must be >= 0 rad, got {q0_std}")
    return np.random.default_rng(seed).normal(0.0, q0_std, n_segments) if q0_std > 0 else np.zeros(n_segments)


def run_tuning(
    out_dir: Path,
    summary: SummaryWriter,
    label: str,
    plant: Plant,
    controller: CBFFilter,
    nominal: NominalController,
    duration: float,
    q0: np.ndarray,
    show_progress: bool,
    estimator: Callable[[PlantState], Estimate] = exact_state,
    extra_figures: Callable[[dict[str, np.ndarray]], dict[str, Any]] | None = None,
    extra_units: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Run one tuning, save its time series, add its row to summary.json and return the row."""
    progress = Progress(f"{summary.data['scenario']} {label}", int(round(duration / plant.control_dt)), enabled=show_progress)
    start = time.perf_counter()
    log = run_closed_loop(plant, controller, nominal, duration, q0, estimator=estimator, progress=progress)
    wall = time.perf_counter() - start
    row: dict[str, Any] = {"tuning": label}
    row.update(run_figures(log, plant.control_dt, controller.enabled, wall))
    if extra_figures is not None:
        row.update(extra_figures(log))
    units = dict(TIMESERIES_UNITS)
    units.update(extra_units or {})
    row["timeseries"] = str(save_timeseries(out_dir, label, log, units).relative_to(out_dir))
    summary.add_run(row)
    return row
