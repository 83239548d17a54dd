"""Run outputs (docs/run-outputs.md): the output folder, summary.json and per-run time series.

Layout of a run folder DIR:
    DIR/config.json                  {"scenario", "params", "seed", "versions", "command",
                                      "cwd", "started", "sources"}: written once, when the run starts
    DIR/summary.json                 {"scenario", "params", "versions", "scene", "runs": [...]}
    DIR/timeseries/<run>.npz         one NumPy .npz archive per run (format below)
    DIR/frames/<run>/frames.json     optional camera frames of a run (format below)
    DIR/plots/*.png, DIR/report.md   the report (softcbf_mj.outputs.report)
    DIR/recording.rrd                the rerun recording (softcbf_mj.outputs.recording)

summary.json's optional "scene" holds the geometry a run used (written by the scenario,
read by the report and the recording): "segment_lengths_m" (N,) of the true arm;
"facets" {"H" (P, 2), "h" (P,) m}: the controller's free space N; "plates" {"H", "h"}:
the true plates' surfaces at rest (equal to "facets" unless the scenario moves them);
"force_safe_set" {"H_prime" (P', 2), "h_prime" (P',), "is_vertex_correction" (P',),
"row_scaling"}: the controller's P; "n_max_m", "f_max_N"; "stiffness" {"law":
"LinearStiffness" | "PowerLawStiffness", and that law's fields}: the controller's ψ;
"plate_stiffness_N_per_m": the true plates' spring.

Time-series format: a compressed `.npz` (numpy.savez_compressed) holding one
array per signal, the first axis the control step k = 0..T-1; `t` (T,) s is always
present. Units are SI, pressures in hPa, angles in rad; the keys and their units are
listed in the archive's `units` entry (a JSON string). Read with
`numpy.load(path)` or `softcbf_mj.outputs.runio.load_timeseries(path)`.

Camera frames (`save_frames_index` / `load_frames_index`): DIR/frames/<run>/ holds the
images (PNG or JPEG, any names) and frames.json = {"frames": [{"t": s, "file": name
relative to that folder, "detections": [{"id": int, "corners": [[x, y] × 4] px}]}]},
times ascending, corners in OpenCV's image convention (x right, y down) and the order of
`perception.detect` (top-left, top-right, bottom-right, bottom-left of the upright tag).

summary.json is rewritten (atomically) after every run, so an interrupted scenario
leaves a readable folder holding every finished run. Every file is written atomically
(a hidden temp file renamed into place, removed again if writing fails or is
interrupted: `atomic_path`) with the mode umask gives new files (0644 under umask 022).

The run folder is marked and locked by DIR/.softcbf-run (`prepare_out_dir`): the marker
says that this tool made the folder, so `--overwrite` replaces its contents and no other
folder's (never the working folder, one above it or the home folder); while a process
holds an exclusive `fcntl.flock` on it (until `release_out_dir` or its exit, also when it
is killed: no stale locks), any other process is refused the folder. The marker holds the
PID of the last process that locked it, for the message.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import fcntl
import json
import os
import pickle
import platform
import re
import shlex
import shutil
import sys
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any, Mapping

import numpy as np

import softcbf_mj
from controllers.registry import recorded_sources
from controllers.model.safe_set import LinearStiffness, PowerLawStiffness, StiffnessLaw

CONFIG_FILE = "config.json"
SUMMARY_FILE = "summary.json"
TIMESERIES_DIR = "timeseries"
FRAMES_DIR = "frames"
FRAMES_INDEX = "frames.json"
STIFFNESS_LAWS = {law.__name__: law for law in (LinearStiffness, PowerLawStiffness)}


RUN_MARKER = ".softcbf-run"


class OutputDirError(ValueError):
    """The output folder cannot be used (not empty, a file, not writable, in use by another run...)."""


_LOCKS: dict[Path, int] = {}  # run folder (resolved) -> descriptor of its locked marker


def is_run_folder(path: str | Path) -> bool:
    """Whether `path` was written by this tool: it holds the marker, or (folders written
    before the marker existed) a summary.json with docs/run-outputs.md's scenario, params and runs."""
    folder = Path(path)
    if (folder / RUN_MARKER).is_file():
        return True
    try:
        summary = json.loads((folder / SUMMARY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(summary, dict) and {"scenario", "params", "runs"} <= summary.keys()


def _protected(folder: Path) -> str | None:
    """Why `folder` must never be emptied (the working folder, a folder above it, home), or None."""
    resolved, cwd = folder.resolve(), Path.cwd().resolve()
    if resolved == cwd:
        return "it is the working folder"
    if resolved in cwd.parents:
        return "the working folder lies inside it"
    if resolved == Path.home().resolve():
        return "it is the home folder"
    return None


def _lock(folder: Path) -> None:
    """Lock `folder` for this process (created marker + exclusive flock); OutputDirError if
    another process holds it. Locking a folder this process holds already is a no-op."""
    key = folder.resolve()
    if key in _LOCKS:
        return
    marker = folder / RUN_MARKER
    fd = os.open(marker, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if os.fstat(fd).st_ino != os.stat(marker).st_ino:  # its holder removed it meanwhile
            raise BlockingIOError
    except (BlockingIOError, FileNotFoundError):
        holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
        os.close(fd)
        raise OutputDirError(f"{folder} is in use by another run (process {holder}); "
                             "wait for it to finish or choose another --out") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
    _LOCKS[key] = fd


def release_out_dir(path: str | Path) -> None:
    """Release this process's lock on a run folder (`prepare_out_dir`); the marker stays."""
    fd = _LOCKS.pop(Path(path).resolve(), None)
    if fd is not None:
        os.close(fd)


def remove_if_unused(path: str | Path) -> None:
    """Release and remove a run folder that holds nothing but its marker (made for a run
    that did not start), so that the corrected command is not refused."""
    folder = Path(path)
    release_out_dir(folder)
    if folder.is_dir() and not folder.is_symlink() and {p.name for p in folder.iterdir()} <= {RUN_MARKER}:
        (folder / RUN_MARKER).unlink(missing_ok=True)
        folder.rmdir()


def _empty(folder: Path, keep: str) -> None:
    for entry in folder.iterdir():
        if entry.name == keep:
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def prepare_out_dir(path: str | Path, overwrite: bool = False, keep: bool = False) -> Path:
    """Create (or take, when empty) the run folder `path`, mark it and lock it for this
    process (see the module docstring); return it.

    A folder holding anything but the marker is refused unless `overwrite`, and then only
    when it is a run folder (`is_run_folder`) and not the working folder, one above it or
    home: its contents are deleted. With `keep` such a folder is taken as it is (marked,
    locked, nothing deleted: a bench continued with --resume, whose caller has checked that
    the folder is its own). Raises OutputDirError (never OSError) naming the folder and
    what is wrong, before deleting anything. The folder returned is absolute (`os.path.abspath`:
    symbolic links kept), so that whatever changes the working folder meanwhile, outputs land in it.
    """
    if str(path) == "":
        raise OutputDirError("--out must name a folder, got ''")
    out = Path(os.path.abspath(path))  # absolute: a filter that changes the working folder cannot move it
    try:
        if out.exists() and not out.is_dir():
            raise OutputDirError(f"{out} exists and is not a folder")
        marked, run_folder = (out / RUN_MARKER).is_file(), is_run_folder(out)  # before the lock marks it
        out.mkdir(parents=True, exist_ok=True)
        _lock(out)
    except OSError as exc:
        raise OutputDirError(f"cannot write the run folder {out}: {exc.strerror or exc}") from None
    try:
        if not keep and any(entry.name != RUN_MARKER for entry in out.iterdir()):
            if not overwrite:
                raise OutputDirError(f"{out} exists and is not empty; choose another --out or pass --overwrite")
            if not run_folder:
                raise OutputDirError(f"{out} is not a run folder (it has no {RUN_MARKER} or {SUMMARY_FILE}); "
                                     "--overwrite only replaces folders written by softcbf: choose another --out")
            reason = _protected(out)
            if reason:
                raise OutputDirError(f"refusing to overwrite {out}: {reason}; choose another --out")
            _empty(out, keep=RUN_MARKER)
    except (OSError, OutputDirError) as exc:
        if not marked:
            (out / RUN_MARKER).unlink(missing_ok=True)
        release_out_dir(out)
        if isinstance(exc, OutputDirError):
            raise
        raise OutputDirError(f"cannot empty the run folder {out}: {exc.strerror or exc}") from None
    return out


def new_run_dir(parent: str | Path, stem: str) -> Path:
    """Create a new folder parent/<stem>-<YYYYmmdd-HHMMSS> (suffix -2, -3, ... when that
    exists) atomically (mkdir), so that runs started in the same second get one each."""
    base = Path(os.path.abspath(parent)) / f"{stem}-{datetime.datetime.now():%Y%m%d-%H%M%S}"
    candidate, index = base, 1
    try:
        base.parent.mkdir(parents=True, exist_ok=True)
        while True:
            try:
                candidate.mkdir()
                return candidate
            except FileExistsError:
                index += 1
                candidate = base.with_name(f"{base.name}-{index}")
    except OSError as exc:
        raise OutputDirError(f"cannot create the run folder {candidate}: {exc.strerror or exc}") from None


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def versions() -> dict[str, str | None]:
    """Versions of everything that changes behaviour, recorded in every summary."""
    return {
        "softcbf_mj": softcbf_mj.__version__,
        "mujoco": _version("mujoco"),
        "python": platform.python_version(),
        "numpy": _version("numpy"),
        "qpsolvers": _version("qpsolvers"),
        "daqp": _version("daqp"),
        "rerun_sdk": _version("rerun-sdk"),
        "matplotlib": _version("matplotlib"),
        "opencv": _version("opencv-python-headless"),
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


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A hidden temp path beside `path` (".<stem>.tmp<suffix>") for a writer to create; it
    is renamed onto `path` when the block ends, and removed when the block raises
    (KeyboardInterrupt included), so no torn or temp file stays behind."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write UTF-8 JSON atomically (`atomic_path`); non-finite floats become null."""
    text = json.dumps(_jsonable(data), indent=2, allow_nan=False) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def safe_name(text: str) -> str:
    """A file-name-safe version of a run label ('HW-High' -> 'HW-High', 'a b/c' -> 'a_b_c')."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "run"


def save_timeseries(out_dir: Path, run: str, series: Mapping[str, np.ndarray], units: Mapping[str, str]) -> Path:
    """Write one run's time series to DIR/timeseries/<run>.npz and return its path."""
    folder = Path(out_dir) / TIMESERIES_DIR
    folder.mkdir(exist_ok=True)
    lengths = {k: len(v) for k, v in series.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"time series of run {run!r} have different lengths: {lengths}")
    missing = set(series) - set(units)
    if missing:
        raise ValueError(f"time series of run {run!r} lack units for {sorted(missing)}")
    path = folder / f"{safe_name(run)}.npz"
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, units=np.array(json.dumps(dict(units))), **{k: np.asarray(v) for k, v in series.items()})
    return path


def load_timeseries(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Read a run's time series: (arrays by key, units by key). RunFolderError naming the
    file when it cannot be read (missing, truncated, not an archive of this format)."""
    try:
        with np.load(path) as data:
            units = json.loads(str(data["units"]))
            arrays = {k: data[k] for k in data.files if k != "units"}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, pickle.UnpicklingError) as exc:
        raise RunFolderError(f"time series {path} cannot be read ({type(exc).__name__}: {exc}); "
                             "rerun the scenario to write it again") from None
    return arrays, units


def write_config(out_dir: Path, scenario: str, params: Mapping[str, Any]) -> dict[str, Any]:
    """Write DIR/config.json: every parameter, the seed (params["seed"], None without one),
    the versions, the command line (this process's, as the shell received it), the working folder
    and the start time (UTC, ISO 8601), and for a filter or nominal FILE.py:Factory its file's absolute path and
    SHA-256 (controllers.registry.recorded_sources: a replay checks it); return what it wrote."""
    config = {
        "scenario": scenario,
        "params": dict(params),
        "seed": params.get("seed"),
        "versions": versions(),
        "command": shlex.join(sys.orig_argv),
        "cwd": os.getcwd(),
        "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "sources": recorded_sources(params),
    }
    write_json(Path(out_dir) / CONFIG_FILE, config)
    return config


class SummaryWriter:
    """Builds DIR/summary.json run by run; each `add_run` rewrites the file.

    Construction also writes DIR/config.json (`write_config`). `scene` (see the module
    docstring) is stored as summary.json's "scene" when given.
    """

    def __init__(self, out_dir: Path, scenario: str, params: Mapping[str, Any],
                 scene: Mapping[str, Any] | None = None) -> None:
        self.path = Path(out_dir) / SUMMARY_FILE
        write_config(out_dir, scenario, params)
        self.data: dict[str, Any] = {"scenario": scenario, "params": dict(params), "versions": versions()}
        if scene is not None:
            self.data["scene"] = _jsonable(scene)
        self.data["runs"] = []
        write_json(self.path, self.data)

    def add_run(self, run: Mapping[str, Any]) -> None:
        """Append a run's row and rewrite the file; a row with a `fault` (a run that ended on a
        filter fault, closedloop.step) also sets the summary's top-level `fault` (the first
        one, with the run's label as "run")."""
        self.data["runs"].append(dict(run))
        if run.get("fault") and "fault" not in self.data:
            self.data["fault"] = {"run": run.get("tuning"), **run["fault"]}
        write_json(self.path, self.data)


def stiffness_to_json(law: StiffnessLaw) -> dict[str, Any]:
    """ψ as {"law": class name, **fields}, e.g. {"law": "LinearStiffness", "k": 11.16}."""
    name = type(law).__name__
    if name not in STIFFNESS_LAWS:
        raise ValueError(f"stiffness law {name} cannot be recorded; known: {', '.join(STIFFNESS_LAWS)}")
    return {"law": name, **dataclasses.asdict(law)}


def stiffness_from_json(data: Mapping[str, Any]) -> StiffnessLaw:
    """The inverse of `stiffness_to_json`."""
    fields = dict(data)
    name = fields.pop("law", None)
    if name not in STIFFNESS_LAWS:
        raise ValueError(f"stiffness law must be one of {', '.join(STIFFNESS_LAWS)}, got {name!r}")
    return STIFFNESS_LAWS[name](**fields)


class RunFolderError(ValueError):
    """A folder is not a readable run folder (no summary.json, a missing time series...)."""


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise RunFolderError(f"{path} cannot be read as JSON ({exc})") from None


@dataclass(frozen=True)
class RunFolder:
    """A run folder as written by a scenario: summary.json, config.json (None in folders
    written before it existed) and the time series of every finished run."""

    path: Path
    summary: dict[str, Any]
    config: dict[str, Any] | None

    @property
    def runs(self) -> list[dict[str, Any]]:
        return self.summary["runs"]

    @property
    def labels(self) -> list[str]:
        return [run["tuning"] for run in self.runs]

    @property
    def scene(self) -> dict[str, Any] | None:
        return self.summary.get("scene")

    def timeseries(self, label: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
        """The time series of run `label`: (arrays by key, units by key)."""
        return load_timeseries(self._timeseries_path(label))

    def frames(self, label: str) -> list[dict[str, Any]]:
        """Camera frames of run `label` (`load_frames_index`); [] when it has none."""
        return load_frames_index(self.path, label)

    def _timeseries_path(self, label: str) -> Path:
        rows = [run for run in self.runs if run["tuning"] == label]
        if not rows:
            raise RunFolderError(f"{self.path} has no run {label!r}; runs: {', '.join(self.labels) or 'none'}")
        path = self.path / rows[0].get("timeseries", f"{TIMESERIES_DIR}/{safe_name(label)}.npz")
        if not path.is_file():
            raise RunFolderError(f"time series of run {label!r} is missing: {path}")
        return path


def read_run_folder(path: str | Path) -> RunFolder:
    """Open a run folder; errors name what is missing and what a run folder holds."""
    folder = Path(path)
    summary_path = folder / SUMMARY_FILE
    if not summary_path.is_file():
        raise RunFolderError(f"{folder} is not a run folder: it has no {SUMMARY_FILE} "
                             "(give a folder written by `softcbf run` or `python -m scenarios`)")
    summary = _read_json(summary_path)
    for key in ("scenario", "params", "runs"):
        if key not in summary:
            raise RunFolderError(f"{summary_path} lacks {key!r} (docs/run-outputs.md: scenario, params, versions, runs)")
    config_path = folder / CONFIG_FILE
    config = _read_json(config_path) if config_path.is_file() else None
    return RunFolder(folder, summary, config)


def frames_folder(out_dir: Path, run: str) -> Path:
    """DIR/frames/<run>/: where a run's camera images and frames.json go."""
    return Path(out_dir) / FRAMES_DIR / safe_name(run)


def save_frames_index(out_dir: Path, run: str, frames: list[Mapping[str, Any]]) -> Path:
    """Write frames.json of run `run` (format in the module docstring) after checking every
    entry: t finite and ascending, the image file present, four [x, y] corners per tag."""
    folder = frames_folder(out_dir, run)
    last = -np.inf
    for i, frame in enumerate(frames):
        t = float(frame["t"])
        if not (np.isfinite(t) and t >= last):
            raise ValueError(f"frame {i}: t must be finite and ascending, got {t} after {last}")
        last = t
        if not (folder / frame["file"]).is_file():
            raise ValueError(f"frame {i}: image {folder / frame['file']} does not exist; write it before the index")
        for det in frame.get("detections", []):
            if np.shape(det["corners"]) != (4, 2):
                raise ValueError(f"frame {i}, tag {det['id']}: corners must be 4 [x, y] pairs, got shape {np.shape(det['corners'])}")
    path = folder / FRAMES_INDEX
    write_json(path, {"frames": [dict(f) for f in frames]})
    return path


def load_frames_index(out_dir: Path, run: str) -> list[dict[str, Any]]:
    """Frames of run `run` from DIR/frames/<run>/frames.json, [] when there is none."""
    path = frames_folder(out_dir, run) / FRAMES_INDEX
    return _read_json(path)["frames"] if path.is_file() else []
