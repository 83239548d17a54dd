"""`softcbf demo [--out DIR]`: the paper's CBF against the recommended filter on the MuJoCo plate, in one figure.

Two runs of scenario mujoco_contact through the Python API (`scenarios.api.run`, the same function
`softcbf run` calls), identical but for the filter:

- the paper's CBF, tuning Low (`paper-cbf`, docs/paper-cbf.md);
- the recommended filter for contact tasks (the preset `c-erg:recommended`, README).

Both get the README's pushing nominal, u_nom = 150 sin(2π·0.25·(t + 1)) hPa on both segments from t = 0,
which presses the arm into the plate at once, for DURATION_S = 5 s of simulated time: on the reference
machine the paper's CBF peaks well above F_max = 0.16 N (ρ_meas < 0) and the recommended filter stays
below it. The figure, DIR/force.png, is `softcbf_mj.outputs.report.plot_force` of the two runs (measured force,
the force each controller predicts, F_max); each run is also saved as a run folder,
DIR/paper-cbf-low and DIR/c-erg-recommended (`scenarios.api.save`: summary, time series, plots,
report.md, recording), which `softcbf report` rebuilds. The demo prints a line before anything heavy
is imported, numba's compile note when it compiles (softcbf_mj.loops.kernels), each run's progress line and
result, and where the figure is.

Time: 5 s of simulated time per run; after set-up with numba's cache warm the demo takes well under a
minute on the 2-core reference machine (docs/command-line.md#softcbf-demo gives the measurement);
a cold cache adds the one-time compile (softcbf_mj.loops.kernels.COLD_COMPILE_S). An existing DIR is reused:
the figure is replaced and the two run folders are replaced as run folders (`save(..., overwrite=True)`
refuses a folder softcbf did not write).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from softcbf_mj.loops.kernels import compile_notes
from softcbf_mj.outputs.palette import run_color

DURATION_S = 5.0  # s of simulated time per run
NOMINAL = {"amplitude": 150.0, "frequency": 0.25, "t0": 1.0}  # hPa, Hz, s: the README's pushing sinusoid
FIGURE_FILE = "force.png"
DEFAULT_OUT = Path("runs/demo")


@dataclass(frozen=True)
class DemoRun:
    """One of the demo's runs: its legend label, its run folder's name, the filter and its parameters."""

    label: str
    folder: str
    filter: str
    params: dict


def demo_runs() -> tuple[DemoRun, ...]:
    """The paper's CBF (Low) and the recommended filter (module docstring)."""
    return (DemoRun("paper's CBF (Low)", "paper-cbf-low", "paper-cbf", {"tuning": "Low"}),
            DemoRun("recommended (c-erg)", "c-erg-recommended", "c-erg:recommended", {}))


def _run_one(k: int, demo: DemoRun, out: Path, duration: float, stream: TextIO) -> Any:
    """Run `demo` (the k-th of two) through `scenarios.api.run`, say its result, save its run folder; its RunFolder."""
    from scenarios.api import Filter, MujocoContact, Nominal, Run, run, save  # 0.78 s (-X importtime): not at --help
    from softcbf_mj.outputs.runio import read_run_folder  # 0.35 s (-X importtime) at --help; loaded with scenarios.api

    print(f"[{k}/2] {demo.label}: {duration:g} s of mujoco_contact", file=stream, flush=True)
    spec = MujocoContact(run=Run(duration=duration, progress=True), filter=Filter(demo.filter, params=demo.params),
                         nominal=Nominal(**NOMINAL))
    with contextlib.redirect_stdout(io.StringIO()):  # the scenario's own table: the demo says its result below
        result = run(spec)
    row = result.runs[0]
    f_max = result.summary["scene"]["f_max_N"]
    print(f"[{k}/2] {demo.label}: peak force {row['force_max_N']:.3f} N = {row['force_max_N'] / f_max:.2f} F_max, "
          f"min ρ_meas {row['rho_min_meas']:+.3f}, {row['t_violation_s']:.2f} s above F_max", file=stream, flush=True)
    return read_run_folder(save(result, out / demo.folder, overwrite=True))


def run_demo(out: Path = DEFAULT_OUT, duration: float = DURATION_S, stream: TextIO | None = None) -> Path:
    """Run the demo into `out` (module docstring), reporting on `stream` (stderr); returns the figure's path."""
    stream = stream if stream is not None else sys.stderr
    start = time.perf_counter()
    print(f"softcbf demo: the paper's CBF and the recommended filter, {duration:g} s each on the MuJoCo plate",
          file=stream, flush=True)
    from softcbf_mj.outputs.report import Scene, plot_force  # matplotlib, MuJoCo: 1.5 s (-X importtime), after the first line

    out, runs, folders = Path(out), demo_runs(), []
    with compile_notes(stream):  # one note for both runs' compiles
        for k, demo in enumerate(runs, start=1):
            folders.append(_run_one(k, demo, out, duration, stream))
    figure = out / FIGURE_FILE
    plot_force(Scene.of(folders[0]), [(demo.label, run_color(demo.label, i), folder.timeseries(folder.labels[0])[0])
                                      for i, (demo, folder) in enumerate(zip(runs, folders))], figure)
    print(f"done in {time.perf_counter() - start:.0f} s; run folders: {', '.join(str(f.path) for f in folders)}",
          file=stream)
    print(f"figure: {figure}", flush=True)
    return figure


HELP = "a contact figure in under a minute: the paper's CBF against the recommended filter on the MuJoCo plate"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    parser.add_argument("--duration", type=float, default=DURATION_S,
                        help=f"simulated seconds per run, > 0 (default {DURATION_S:g})")


def run_command(args: argparse.Namespace, extra: list[str]) -> int:
    """`softcbf demo`: bad input is a UsageError (one line, exit 2)."""
    from scenarios.run import UsageError  # 0.46 s (-X importtime): `softcbf --help` imports this module
    from softcbf_mj.outputs.runio import OutputDirError  # 0.35 s (-X importtime): as above

    if not args.duration > 0:
        raise UsageError(f"--duration must be > 0 s, got {args.duration:g}")
    try:
        run_demo(args.out, args.duration)
    except (OutputDirError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    return 0
