"""CPU time of `softcbf list`: user + system seconds of a fresh process, the interpreter's start included.

Each of `--repeats` runs starts `python -m softcbf.cli list` with the interpreter of this
process (so the same virtual environment) with its output discarded, and reads the
child's user and system CPU time from `resource.getrusage(RUSAGE_CHILDREN)` (the
difference before and after the child). The budget is 0.5 s of CPU; the
median over the runs is what is compared with it. Also reported: `softcbf run
mujoco_contact --help` (a scenario's parameters, which import no MuJoCo either:
tests/test_cli_lazy.py) and the bare interpreter's start (`python -c pass`), the floor no
lazy import can go below. Usage:
`.venv/bin/python tools/bench_cli_list.py [--repeats 5]`; prints a table and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import statistics
import sys

from timing import child_timing, emit

BUDGET_S = 0.5  # s of CPU (user + system), the budget of `softcbf list`


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs of each command (>= 1)")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    commands = {"softcbf list": [sys.executable, "-m", "softcbf.cli", "list"],
                "run NAME --help": [sys.executable, "-m", "softcbf.cli", "run", "mujoco_contact", "--help"],
                "python -c pass": [sys.executable, "-c", "pass"]}
    figures: dict[str, dict[str, float]] = {}
    for name, command in commands.items():
        runs = [child_timing(command) for _ in range(args.repeats)]
        cpu, wall = [r.cpu for r in runs], [r.wall for r in runs]
        figures[name] = {"cpu_s_median": statistics.median(cpu), "cpu_s_max": max(cpu), "wall_s_median": statistics.median(wall)}
    print(f"{'command':<16} {'CPU median [s]':>14} {'CPU max [s]':>11} {'wall median [s]':>15}   ({args.repeats} runs)")
    for name, f in figures.items():
        print(f"{name:<16} {f['cpu_s_median']:>14.3f} {f['cpu_s_max']:>11.3f} {f['wall_s_median']:>15.3f}")
    within = figures["softcbf list"]["cpu_s_median"] <= BUDGET_S
    print(f"budget {BUDGET_S} s of CPU: {'met' if within else 'NOT met'}")
    emit({"repeats": args.repeats, "budget_cpu_s": BUDGET_S, "within_budget": within,
          "list_cpu_s_median": figures["softcbf list"]["cpu_s_median"],
          "list_cpu_s_max": figures["softcbf list"]["cpu_s_max"],
          "list_wall_s_median": figures["softcbf list"]["wall_s_median"],
          "run_help_cpu_s_median": figures["run NAME --help"]["cpu_s_median"],
          "python_start_cpu_s_median": figures["python -c pass"]["cpu_s_median"]})


if __name__ == "__main__":
    main()
