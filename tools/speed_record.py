"""The speed record: a short suite of the benchmarks, one JSON line per run appended to a history, and its figure.

Each benchmark runs as its own process (this tree first on PYTHONPATH), with short settings, and its last stdout
line (its one JSON line, tools/timing.py) gives the figures kept here, CPU-time based where the benchmark has them
(least disturbed by other jobs on a shared machine):

| figure                       | benchmark and settings                                        | unit, better   |
|------------------------------|---------------------------------------------------------------|----------------|
| mj_step_L{n}                 | bench_mujoco --links 5,10,20,40: contact steps per CPU s       | steps/s, higher |
| serial_fraction_{tuning}     | bench_serial_loop --duration 3 --repeats 2: t_mj_step / t_loop | 1, higher       |
| batch_fraction_of_ceiling    | bench_batch, MuJoCo B = 32 on 1 thread: loop / its replay, CPU | 1, higher       |
| pcc_batch_ratio              | bench_batch, PCC B = 256: batched / serial samples per CPU-h   | ×, higher       |
| camera_rtf                   | bench_camera_loop --duration 5, HW-Low, 1280 × 720: sim s / wall s | 1, higher   |
| recommended_filter_share_1kHz | bench_governors, c-erg-recommended at 1 kHz: median CPU µs / 1000 µs | 1, lower |

An entry is {commit, dirty, date (UTC), machine (architecture, processor, cores, 1-minute load at the start and the
end), python, mujoco, seconds (the suite's wall time), figures}. The load matters: on a shared machine a figure taken
at load 8 on 2 cores is not the same measurement as one at load 1, so the plot marks each point's load.

`--plot` draws the history (one panel per figure, one point per entry in order, labelled by commit): a regression
shows as a step. Usage:

    .venv/bin/python tools/speed_record.py                # run the suite, append to docs/speed/history.jsonl
    .venv/bin/python tools/speed_record.py --only camera_rtf,mj_step --no-append   # a subset, printed only
    .venv/bin/python tools/speed_record.py --plot         # docs/speed/history.png from the history

Ends with one JSON line (the entry, or with --plot the figure's path and the number of entries).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

from timing import emit, machine

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ROOT / "tools"
HISTORY = ROOT / "docs" / "speed" / "history.jsonl"
FIGURE = ROOT / "docs" / "speed" / "history.png"
MJ_LINKS = (5, 10, 20, 40)
SERIAL_TUNINGS = ("None", "Low")
CONTROL_PERIOD_US = 1000.0  # 1 kHz
RECOMMENDED_CASE = "c-erg-recommended 1 kHz sin T=8s"


def mj_step(report: dict) -> dict[str, float]:
    return {f"mj_step_L{row['links']}": row["contact_steps_per_s"]["median"] for row in report["steps_per_s"]}


def serial_loop(report: dict) -> dict[str, float]:
    return {f"serial_fraction_{tuning}": entry["this"]["fraction"] for tuning, entry in report["runs"].items()}


def batch(report: dict) -> dict[str, float]:
    return {"batch_fraction_of_ceiling": report["fraction_of_physics_ceiling_cpu"]["mujoco_contact_1_thread"],
            "pcc_batch_ratio": report["ratio_vs_serial_cpu"]["pcc"]}


def camera(report: dict) -> dict[str, float]:
    return {"camera_rtf": report["rtf_min"]}


def recommended_filter(report: dict) -> dict[str, float]:
    return {"recommended_filter_share_1kHz": report["cpu_us_median"] / CONTROL_PERIOD_US}


# name → (tool, its arguments, the figures of its JSON line)
SUITE: dict[str, tuple[str, list[str], Callable[[dict], dict[str, float]]]] = {
    "mj_step": ("bench_mujoco.py", ["--links", ",".join(map(str, MJ_LINKS)), "--repeats", "3", "--seconds", "0.5"],
                mj_step),
    "serial_loop": ("bench_serial_loop.py", ["--duration", "3", "--repeats", "2", "--tunings", ",".join(SERIAL_TUNINGS)],
                    serial_loop),
    "batch": ("bench_batch.py", ["--duration", "0.2", "--serial", "4", "--batches", "32", "--pcc-batches", "256",
                                 "--repeats", "2", "--step-calls", "500"], batch),
    "camera_rtf": ("bench_camera_loop.py", ["--duration", "5", "--tunings", "HW-Low"], camera),
    "recommended_filter": ("bench_governors.py", ["--quick", "--repeat", "2", "--one", RECOMMENDED_CASE],
                           recommended_filter),
}
LOWER_IS_BETTER = ("recommended_filter_share_1kHz",)


def run_tool(tool: str, args: list[str]) -> dict:
    """The last stdout line (JSON) of `python tools/TOOL ARGS`, run with this tree first on PYTHONPATH."""
    path = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])
    done = subprocess.run([sys.executable, str(TOOLS / tool), *args], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": path})
    if done.returncode != 0:
        raise RuntimeError(f"{tool} {' '.join(args)} failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()


def record(names: list[str]) -> dict[str, Any]:
    """Run the benchmarks `names` of SUITE; the history entry."""
    import mujoco

    start = time.perf_counter()
    entry: dict[str, Any] = {"commit": git("rev-parse", "--short=12", "HEAD"), "dirty": bool(git("status", "--porcelain",
                             "--untracked-files=no")), "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                             "machine": machine(), "python": platform.python_version(), "mujoco": mujoco.__version__}
    figures: dict[str, float] = {}
    for name in names:
        tool, args, pick = SUITE[name]
        began = time.perf_counter()
        got = pick(run_tool(tool, args))
        figures.update(got)
        print(f"{name:20s} {time.perf_counter() - began:6.1f} s  "
              + ", ".join(f"{key} {value:.4g}" for key, value in got.items()), flush=True)
    entry["machine"]["load_1min_end"] = round(os.getloadavg()[0], 2)
    entry["seconds"] = round(time.perf_counter() - start, 1)
    entry["figures"] = figures
    return entry


def read_history(path: Path) -> list[dict]:
    """The entries of the history file `path`, in order (a line that is not an entry is an error naming its line)."""
    entries = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as error:
            raise ValueError(f"{path}:{number}: not a JSON line ({error.msg})") from error
        if not isinstance(entry, dict) or not isinstance(entry.get("figures"), dict) or "commit" not in entry:
            raise ValueError(f"{path}:{number}: an entry needs 'commit' and 'figures'")
        entries.append(entry)
    return entries


def plot(entries: list[dict], out: Path) -> None:
    """One panel per figure over the entries in order; x labels the commits, each point's colour its load per core."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = sorted({name for entry in entries for name in entry["figures"]},
                   key=lambda name: re.sub(r"\d+", lambda number: number.group().zfill(6), name))  # L5 before L10
    if not names:
        raise ValueError("the history has no figures to plot")
    columns = 3
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 2.6 * rows), squeeze=False, sharex=True)
    x = list(range(len(entries)))
    load = [entry["machine"]["load_1min"] / max(1, entry["machine"]["cpus"]) for entry in entries]
    labels = [entry["commit"][:7] + ("+" if entry.get("dirty") else "") for entry in entries]
    for ax, name in zip(axes.flat, names):
        points = [(i, e["figures"][name], load[i]) for i, e in zip(x, entries) if name in e["figures"]]
        ax.plot([p[0] for p in points], [p[1] for p in points], color="0.6", lw=1, zorder=1)
        shown = ax.scatter([p[0] for p in points], [p[1] for p in points], c=[p[2] for p in points], cmap="viridis",
                           vmin=0, vmax=4, s=22, zorder=2)
        ax.set_title(name + (" (lower is better)" if name in LOWER_IS_BETTER else ""), fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_ylim(bottom=0)
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xticks(x, labels, rotation=60, fontsize=7)
    fig.colorbar(shown, ax=axes.ravel().tolist(), label="1-min load per core at the start", shrink=0.6)
    fig.suptitle(f"speed record: {len(entries)} entries (tools/speed_record.py)", fontsize=10)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--history", type=Path, default=HISTORY, help="the history file (JSON lines)")
    parser.add_argument("--only", default="", help=f"comma-separated benchmarks of the suite: {', '.join(SUITE)}")
    parser.add_argument("--no-append", action="store_true", help="print the entry without appending it")
    parser.add_argument("--plot", action="store_true", help="draw the history's figure instead of running the suite")
    parser.add_argument("--figure", type=Path, default=FIGURE, help="where --plot writes the figure (PNG)")
    args = parser.parse_args()
    if args.plot:
        if not args.history.is_file():
            parser.error(f"--history: no such file {args.history}")
        try:
            entries = read_history(args.history)
            plot(entries, args.figure)
        except ValueError as error:
            parser.error(str(error))
        print(f"{args.figure}: {len(entries)} entries")
        emit({"figure": str(args.figure), "entries": len(entries)})
        return
    names = [name.strip() for name in args.only.split(",") if name.strip()] or list(SUITE)
    unknown = [name for name in names if name not in SUITE]
    if unknown:
        parser.error(f"--only: {unknown[0]!r} is not one of {', '.join(SUITE)}")
    entry = record(names)
    if not args.no_append:
        args.history.parent.mkdir(parents=True, exist_ok=True)
        with args.history.open("a", encoding="utf-8") as history:
            history.write(json.dumps(entry) + "\n")
        print(f"appended to {args.history}")
    emit(entry)


if __name__ == "__main__":
    main()
