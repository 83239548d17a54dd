"""Run outputs (SPEC §8): the output folder, summary.json and per-run time series.

Layout of a run folder DIR:
    DIR/summary.json                 {"scenario", "params", "versions", "runs": [...]}
    DIR/timeseries/<run>.npz         one NumPy .npz archive per run (format below)

Time-series format: a compressed `.npz` (numpy.savez_compressed) holding one
array per signal, the first axis the control step k = 0..T-1; `t` (T,) s is always
present. Units are SI, pressures in hPa, angles in rad; the keys and their units are
listed in the archive's `units` entry (a JSON string). Read with
`numpy.load(path)` or `softcbf_mj.runio.load_timeseries(path)`.

summary.json is rewritten (atomically) after every run, so an interrupted scenario
leaves a readable folder holding every finished run.
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any, Mapping

import numpy as np


class OutputDirError(ValueError):
    """The output folder cannot be used (exists and is not empty, or is a file)."""


def prepare_out_dir(path: str | Path, overwrite: bool = False) -> Path:
    """Create the run folder; refuse an existing non-empty one unless `overwrite` (then empty it)."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputDirError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise OutputDirError(f"{out} exists and is not empty; choose another --out or pass --overwrite")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def versions() -> dict[str, str | None]:
    """Versions of everything that changes behaviour, recorded in every summary."""
    import softcbf_mj

    return {
        "softcbf_mj": softcbf_mj.__version__,
        "mujoco": _version("mujoco"),
        "python": platform.python_version(),
        "numpy": _version("numpy"),
        "qpsolvers": _version("qpsolvers"),
        "daqp": _version("daqp"),
        "platform": platform.platform(),
    }


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if np.isfinite(v) else None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write UTF-8 JSON atomically (temp file + rename); non-finite floats become null."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        json.dump(_jsonable(data), fh, indent=2, allow_nan=False)
        fh.write("\n")
    os.replace(tmp, path)


def safe_name(text: str) -> str:
    """A file-name-safe version of a run label ('HW-High' -> 'HW-High', 'a b/c' -> 'a_b_c')."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "run"


def save_timeseries(out_dir: Path, run: str, series: Mapping[str, np.ndarray], units: Mapping[str, str]) -> Path:
    """Write one run's time series to DIR/timeseries/<run>.npz and return its path."""
    folder = Path(out_dir) / "timeseries"
    folder.mkdir(exist_ok=True)
    lengths = {k: len(v) for k, v in series.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"time series of run {run!r} have different lengths: {lengths}")
    missing = set(series) - set(units)
    if missing:
        raise ValueError(f"time series of run {run!r} lack units for {sorted(missing)}")
    path = folder / f"{safe_name(run)}.npz"
    tmp = folder / f".{path.stem}.tmp.npz"
    np.savez_compressed(tmp, units=np.array(json.dumps(dict(units))), **{k: np.asarray(v) for k, v in series.items()})
    os.replace(tmp, path)
    return path


def load_timeseries(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Read a run's time series: (arrays by key, units by key)."""
    with np.load(path) as data:
        units = json.loads(str(data["units"]))
        arrays = {k: data[k] for k in data.files if k != "units"}
    return arrays, units


class SummaryWriter:
    """Builds DIR/summary.json run by run; each `add_run` rewrites the file."""

    def __init__(self, out_dir: Path, scenario: str, params: Mapping[str, Any]) -> None:
        self.path = Path(out_dir) / "summary.json"
        self.data: dict[str, Any] = {"scenario": scenario, "params": dict(params), "versions": versions(), "runs": []}
        write_json(self.path, self.data)

    def add_run(self, run: Mapping[str, Any]) -> None:
        self.data["runs"].append(dict(run))
        write_json(self.path, self.data)
