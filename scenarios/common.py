"""Builders shared by scenarios: robot, environment, force-safe set, tunings, the scene
record, one tuning's run and the saving of a finished run (with its report and recording)."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterator
from contextvars import ContextVar
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
from softcbf_mj.runio import SummaryWriter, save_timeseries, stiffness_to_json


_REPORT_AND_RECORDING: ContextVar[bool] = ContextVar("scenarios_report_and_recording", default=True)


@contextlib.contextmanager
def data_only() -> Iterator[None]:
    """Within this context `run_tuning` writes summary.json and the time series only, not
    the report and the recording (1–3 s per tuning): for studies and tests that run many
    short scenarios. `softcbf report DIR` builds both later from the folder."""
    token = _REPORT_AND_RECORDING.set(False)
    try:
        yield
    finally:
        _REPORT_AND_RECORDING.reset(token)


# Named robot files (`load_robot`); each file's "about" says what its constants are and why.
ROBOT_PRESETS: dict[str, Path] = {
    "hardware-like": Path(__file__).resolve().parents[1] / "models" / "robots" / "hardware_like.json",
}


def load_robot(spec: str) -> RobotParams:
    """'' or 'reference' → the SPEC §3 reference arm; a name of `ROBOT_PRESETS` → that
    file; otherwise a JSON file written by RobotParams.save."""
    if spec in ("", "reference"):
        return reference_robot()
    path = ROBOT_PRESETS.get(spec, Path(spec))
    if not path.is_file():
        raise ValueError(f"robot must be 'reference', one of {', '.join(ROBOT_PRESETS)} or a robot JSON file, "
                         f"got {spec!r} (no such file)")
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


def scene_record(arm: RobotParams, safe_set: ForceSafeSet, plate_stiffness: float,
                 plates: Environment | None = None) -> dict[str, Any]:
    """summary.json's "scene" (format: softcbf_mj.runio): the true arm's segment lengths,
    the controller's facets, P, n_max, F_max and ψ (`safe_set`), the true plates' spring
    (`plate_stiffness`, N/m) and surfaces at rest (`plates`; default: the controller's facets)."""
    env = safe_set.environment
    plates = env if plates is None else plates
    return {
        "segment_lengths_m": list(arm.lengths),
        "facets": {"H": env.H, "h": env.h},
        "plates": {"H": plates.H, "h": plates.h},
        "force_safe_set": {"H_prime": safe_set.H_prime, "h_prime": safe_set.h_prime,
                           "is_vertex_correction": safe_set.is_vertex_correction, "row_scaling": safe_set.row_scaling},
        "n_max_m": safe_set.n_max,
        "f_max_N": safe_set.f_max,
        "stiffness": stiffness_to_json(safe_set.stiffness),
        "plate_stiffness_N_per_m": float(plate_stiffness),
    }


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
    """Run one tuning in the closed loop and `save_run` it; return its summary row."""
    progress = Progress(f"{summary.data['scenario']} {label}", int(round(duration / plant.control_dt)), enabled=show_progress,
                        unit_s=plant.control_dt)
    start = time.perf_counter()
    log = run_closed_loop(plant, controller, nominal, duration, q0, estimator=estimator, progress=progress)
    wall = time.perf_counter() - start
    return save_run(out_dir, summary, label, log, wall, plant.control_dt, controller.enabled, extra_figures, extra_units)


def save_run(
    out_dir: Path,
    summary: SummaryWriter,
    label: str,
    log: dict[str, np.ndarray],
    wall_s: float,
    control_dt: float,
    filtered: bool,
    extra_figures: Callable[[dict[str, np.ndarray]], dict[str, Any]] | None = None,
    extra_units: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Save a finished run `label`: its figures (`run_figures` plus `extra_figures(log)`),
    its time series (TIMESERIES_UNITS plus `extra_units`) and its summary.json row; then
    rebuild the report and the recording from the folder (so an interrupted scenario
    leaves both for its finished runs; not within `data_only()`). Returns the row."""
    row: dict[str, Any] = {"tuning": label}
    row.update(run_figures(log, control_dt, filtered, wall_s))
    if extra_figures is not None:
        row.update(extra_figures(log))
    units = dict(TIMESERIES_UNITS)
    units.update(extra_units or {})
    row["timeseries"] = str(save_timeseries(out_dir, label, log, units).relative_to(out_dir))
    summary.add_run(row)
    if not _REPORT_AND_RECORDING.get():
        return row
    # Imported here: rerun and matplotlib take seconds to import, which listing scenarios
    # and rejecting bad arguments should not pay.
    from softcbf_mj.recording import write_recording
    from softcbf_mj.report import write_report

    write_report(out_dir)
    write_recording(out_dir)
    return row
