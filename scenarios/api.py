"""The Python API: a scenario as a typed spec, run in memory, saved as a run folder (docs/quickstart.md).

    from scenarios.api import Filter, MujocoContact, Plate, Run, run, save

    spec = MujocoContact(run=Run(duration=2.0), filter=Filter("e-erg", contact_aware=True),
                         plate=Plate(stiffness=12.0))
    result = run(spec)                 # the time series and the summary, in memory
    result.runs[0]["rho_min_meas"]     # summary.json's row of the first run
    result.series["e-erg(...)"]["F"]   # a run's time series, column by column
    save(result, "runs/contact")       # the run folder `softcbf run` writes

A spec is a frozen dataclass of typed sections (scenarios.spec: `Run`, `Filter`, `Nominal`,
`Model`, `TrueArm`, `Plate`, `Camera`), one per scenario (`PaperSim`, `MujocoContact`,
`CameraLoop`); every value is checked when the spec is built, the filter's and the nominal's
parameters (keywords of their sections, a mapping `params={name: value}`, or the command
line's "name=value;..." text) against their declarations (controllers.contract.filter_parameters), so a
bad value is refused before anything runs. No scenario or setting is named by a string: a field left out takes the scenario's
default, the paper filter's tunings are a tuple of preset names (`Filter(tunings=("None", "High"))`), and
`spec.flat()` gives the flat names and forms that the command line and the files use (the tunings as "None,High").

`run(spec)` runs the spec's scenario (the same function `softcbf run` calls) into a temporary
folder without the report and the recording (`scenarios.common.data_only`) and returns a
`Result` holding every file it wrote (bytes, by relative path), summary.json parsed and each
run's time series loaded (`softcbf_mj.outputs.runio.load_timeseries`: columns and units). The folder
is deleted when `run` returns, so the lines the scenario prints name what holds its files
instead: "outputs in result.files", "(every column): result.files['table.txt']" (`InMemoryNames`);
`save(result, out_dir)` writes those files into a new run folder (the same checks and lock as
`softcbf run --out`) and builds the report and the recording from it, as `softcbf run` does
after its last run. Every file stays inside the folder: a relative path with no "..", no "."
and no backslash (`folder_path`; anything else is a ValueError before anything is written).
The save is all or nothing: the folder is built in a temporary folder beside it (a
subfolder of the same name, so the report's title is the folder's), and only when it is
complete is `out_dir` prepared (checked, locked, emptied with `overwrite`) and the files
renamed into it; a failure before that leaves `out_dir` as it was and removes the temporary
folder and any parent folder the save created. One implementation of the outputs: the API writes nothing `softcbf run`
does not (tests/test_spec_api.py compares the two folders).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, TextIO

import numpy as np

from scenarios import registry
from scenarios.camera_loop import CameraLoop
from scenarios.common import data_only
from scenarios.mujoco_contact import MujocoContact
from scenarios.paper_sim import PaperSim
from scenarios.spec import Camera, Filter, Model, Nominal, Plate, Run, TrueArm
from softcbf_mj.outputs.runio import RUN_MARKER, SUMMARY_FILE, load_timeseries, prepare_out_dir, release_out_dir

__all__ = ["Camera", "CameraLoop", "Filter", "Model", "MujocoContact", "Nominal", "PaperSim", "Plate", "Result", "Run",
           "TrueArm", "run", "save"]

TIMESERIES = "timeseries"
IN_MEMORY = "result.files"  # what run(spec)'s printed lines name instead of its temporary folder


class InMemoryNames(io.TextIOBase):
    """A text stream that passes what is written on to `stream`, at once, with `folder` (a folder deleted before the
    reader can look) named as the `Result` that holds its files: `folder/NAME` → result.files['NAME'], `folder` →
    result.files (module docstring)."""

    def __init__(self, stream: TextIO, folder: Path) -> None:
        super().__init__()
        self.stream = stream
        self.pattern = re.compile(re.escape(str(folder)) + r"(?:/([^\s:;,'\")]+))?")

    def renamed(self, text: str) -> str:
        return self.pattern.sub(lambda m: f"{IN_MEMORY}[{m.group(1)!r}]" if m.group(1) else IN_MEMORY, text)

    def write(self, text: str) -> int:
        self.stream.write(self.renamed(text))
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:  # also asked after run returns, by a module that kept sys.stdout (numba's colorama)
        return not self.stream.closed and self.stream.isatty()


@dataclass(frozen=True, eq=False)
class Result:
    """A finished scenario in memory (module docstring).

    spec: what ran; summary: summary.json (scenario, params, versions, scene, runs); series:
    time series file stem → {column: array} (a run's label, and `<label>_frames` for the camera's);
    units: the same stems → {column: unit}; files: every file of the run folder, relative path → bytes.
    """

    spec: Any
    summary: dict[str, Any]
    series: dict[str, dict[str, np.ndarray]]
    units: dict[str, dict[str, str]]
    files: dict[str, bytes]

    @property
    def runs(self) -> list[dict[str, Any]]:
        """summary.json's rows, one per controller run (docs/run-outputs.md)."""
        return self.summary["runs"]


def run(spec: Any) -> Result:
    """Run `spec` (a spec of a registered scenario) and return its `Result` (module docstring)."""
    scenario = registry().get(getattr(type(spec), "CONTEXT", None))
    if scenario is None or not isinstance(spec, scenario.spec):
        raise TypeError(f"run takes a scenario's spec ({', '.join(s.spec.__name__ for s in registry().values())}), "
                        f"got {spec!r}")
    with tempfile.TemporaryDirectory(prefix="softcbf-") as tmp, data_only():
        folder = Path(tmp)
        with contextlib.redirect_stdout(InMemoryNames(sys.stdout, folder)):
            scenario.function(folder, spec)
        files = {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
        loaded = {p.stem: load_timeseries(p) for p in sorted((folder / TIMESERIES).glob("*.npz"))}
    return Result(spec, json.loads(files[SUMMARY_FILE]), {k: v[0] for k, v in loaded.items()},
                  {k: dict(v[1]) for k, v in loaded.items()}, files)


def folder_path(name: object) -> PurePosixPath:
    """`name` as a file's path inside a run folder: a non-empty relative POSIX path with no "..", "." or empty part,
    no backslash, not the folder's marker; ValueError naming it otherwise (module docstring)."""
    path = PurePosixPath(name) if isinstance(name, str) and name and "\\" not in name and "\0" not in name else None
    if (path is None or not path.parts or path.is_absolute() or path.as_posix() != name or ".." in path.parts
            or name == RUN_MARKER):
        raise ValueError(f"a saved file must be a path inside the run folder (relative, no '..'), got {name!r}")
    return path


def save(result: Result, out_dir: str | Path, overwrite: bool = False) -> Path:
    """Write `result`'s run folder into `out_dir` (refused if it exists and is not empty, unless `overwrite`
    replaces a run folder's contents: `softcbf_mj.outputs.runio.prepare_out_dir`), then its report and recording, all or
    nothing (module docstring); returns the folder."""
    from softcbf_mj.outputs.recording import write_recording  # rerun, matplotlib: +9.8 s and +2.0 s to import, when a folder is saved
    from softcbf_mj.outputs.report import write_report

    files = {folder_path(name): data for name, data in result.files.items()}
    if str(out_dir) == "":
        raise ValueError("save needs a folder to write, got ''")
    target = Path(out_dir).absolute()
    created = [p for p in (target.parent, *target.parent.parents) if not p.exists()]  # deepest first
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=".softcbf-save-", dir=target.parent) as tmp:
            staged = prepare_out_dir(Path(tmp) / target.name)
            try:
                for name, data in files.items():
                    (staged / name).parent.mkdir(parents=True, exist_ok=True)
                    (staged / name).write_bytes(data)
                write_report(staged)
                write_recording(staged)
            finally:
                release_out_dir(staged)
            out = prepare_out_dir(out_dir, overwrite=overwrite)
            try:
                for entry in staged.iterdir():
                    if entry.name != RUN_MARKER:
                        os.replace(entry, out / entry.name)
            finally:
                release_out_dir(out)
    except BaseException:
        for folder in created:
            try:
                folder.rmdir()
            except OSError:  # not empty: something else wrote there meanwhile
                break
        raise
    return out
