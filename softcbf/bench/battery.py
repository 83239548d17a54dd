"""The battery's data file (`BATTERY_FILE`, softcbf/bench/battery.toml): read, checked, and shown as a table.

The file holds every number of the battery: `[bench]` (each filter's parameters per rate, the contact tasks'
plants, ratios and push length), `[quick]` (--quick's durations, draws and skipped cases) and one `[[case]]`
table per case, in the battery's order. A case's table uses a study file's keys (softcbf.study.definition:
`scenario`, `description`, `fixed`, and for a study `seed`, `sampling`, `draws`, `vary`) and adds the bench's
(`CASE_KEYS`: its `name`, `rate`, `run` and what its run kind needs: `RUN_KEYS`). It is read like a study file
(`vocabulary.files.read_settings_file`); its study cases become `Study`s through `Study.from_dict`
(softcbf.bench.cases), so they pass a study file's checks; here, before any case runs, each table is checked
for its keys (one line naming the case and the key), unique names, a known rate and run kind, and that every
`push` names a contact task (`task`) of its own plant.

`battery_markdown(battery)` is the battery's table in docs/results.md (between `BEGIN` and `END`), generated
from the file (`python -m softcbf.bench.battery docs/results.md` rewrites it; tests check it is current).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vocabulary.files import read_settings_file

BATTERY_FILE = Path(__file__).with_name("battery.toml")
RATES = {"1kHz": "1 kHz", "camera": "10 Hz"}  # a case's rate class → the loop rate it runs at
STUDY_KEYS = ("scenario", "description", "fixed", "vary", "seed", "sampling", "draws")
RUN_KEYS = {  # run kind → (required keys, optional keys) besides name, rate, run, description
    "scenario": ({"scenario", "fixed"}, {"task", "push", "asked_N"}),
    "step": ({"scenario", "fixed", "starts"}, set()),
    "emulator": ({"config", "duration", "options"}, set()),
    "study": ({"scenario", "fixed", "vary", "seed", "sampling", "draws"}, set()),
    "box": ({"scenario", "fixed", "box", "push", "sampling", "draws"}, set()),
}
CASE_KEYS = {"name", "rate", "run", "description"}
TOP_KEYS = {"bench", "quick", "case"}
BENCH_KEYS = {"paper_tunings", "eerg_params", "push_plants", "push_ratios", "force_target_ratio", "push_duration"}
QUICK_KEYS = {"duration", "push_duration", "step_starts", "step_duration", "study_draws", "box_draws", "skipped"}
BEGIN = "<!-- battery table: generated from softcbf/bench/battery.toml by `python -m softcbf.bench.battery docs/results.md` -->"
END = "<!-- end of the battery table -->"


@dataclass(frozen=True)
class Battery:
    """The checked content of a battery file: `bench` and `quick` (its tables) and `cases` (its case tables, in order)."""

    bench: dict[str, Any]
    quick: dict[str, Any]
    cases: tuple[dict[str, Any], ...]


def exactly(where: str, table: Any, required: set[str], optional: set[str] = frozenset()) -> dict[str, Any]:
    """`table` when it is a table holding every `required` key and no key outside `required` | `optional`."""
    if not isinstance(table, dict):
        raise ValueError(f"{where} must be a table, got {table!r}")
    missing, unknown = sorted(required - set(table)), sorted(set(table) - required - optional)
    if missing or unknown:
        raise ValueError(f"{where}: " + "; ".join(
            ([f"missing key(s) {', '.join(missing)}"] if missing else [])
            + ([f"unknown key(s) {', '.join(unknown)}; valid: {', '.join(sorted(required | optional))}"] if unknown else [])))
    return table


def check_case(table: Any, index: int) -> dict[str, Any]:
    """One `[[case]]` table, checked for its keys by its run kind (module docstring)."""
    if not isinstance(table, dict) or not isinstance(table.get("name"), str) or not table["name"]:
        raise ValueError(f"case {index} needs a name (a non-empty string), got {table!r}")
    where = f"case {table['name']!r}"
    if table.get("run") not in RUN_KEYS:
        raise ValueError(f"{where}: run must be one of {', '.join(RUN_KEYS)}, got {table.get('run')!r}")
    if table.get("rate") not in RATES:
        raise ValueError(f"{where}: rate must be one of {', '.join(RATES)}, got {table.get('rate')!r}")
    required, optional = RUN_KEYS[table["run"]]
    exactly(where, table, CASE_KEYS | required, optional)
    for key in ("fixed", "vary", "options"):
        if key in table and not isinstance(table[key], dict):
            raise ValueError(f"{where}: {key} must be a table, got {table[key]!r}")
    return table


def check_battery(data: dict[str, Any]) -> Battery:
    """The battery of a file's top-level table `data`; ValueError naming the first mistake (module docstring)."""
    exactly("the battery", data, TOP_KEYS)
    bench = exactly("[bench]", data["bench"], BENCH_KEYS)
    quick = exactly("[quick]", data["quick"], QUICK_KEYS)
    if not isinstance(data["case"], list) or not data["case"]:
        raise ValueError(f"the battery needs [[case]] tables, got {data['case']!r}")
    cases = tuple(check_case(table, i) for i, table in enumerate(data["case"]))
    names = [c["name"] for c in cases]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"case name(s) {', '.join(twice)} are given more than once")
    unknown = sorted(set(quick["skipped"]) - set(names))
    if unknown:
        raise ValueError(f"[quick.skipped] names no case: {', '.join(unknown)}")
    tasks = {(c["scenario"], c["task"]) for c in cases if "task" in c}
    for case in cases:
        if "task" in case and case["scenario"] not in bench["push_plants"]:
            raise ValueError(f"case {case['name']!r}: a contact task runs on one of {', '.join(bench['push_plants'])}, "
                             f"got {case['scenario']!r}")
        if "push" in case and (case["scenario"], case["push"]) not in tasks:
            raise ValueError(f"case {case['name']!r}: push must name a contact task of {case['scenario']}, got "
                             f"{case['push']!r}; tasks: {', '.join(t for s, t in sorted(tasks) if s == case['scenario'])}")
    return Battery(bench=bench, quick=quick, cases=cases)


def load_battery(path: str | Path = BATTERY_FILE) -> Battery:
    """Read and check the battery file at `path` (module docstring); errors name the file."""
    data = read_settings_file(path, "battery file")
    try:
        return check_battery(data)
    except ValueError as exc:
        raise ValueError(f"battery file {path}: {exc}") from None


def shown_value(value: Any) -> str:
    """A setting as the table shows it: a float without its noise in the last digit (12.276000000000002 → 12.276),
    a table as {k=v, ...}."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.12g}"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}={shown_value(v)}" for k, v in value.items()) + "}"
    return str(value)


def settings_text(case: dict[str, Any], tasks: dict[tuple[str, str], dict[str, Any]]) -> str:
    """A case's settings in the table: its fixed parameters (with those of its contact task `push`), its study's
    draws and varied parameters, the emulator's configuration, duration and options, each `in code`."""
    fixed = {**case.get("fixed", {}),
             **(tasks[case["scenario"], case["push"]]["fixed"] if case["run"] == "scenario" and "push" in case else {})}
    parts = [f"`{k}={shown_value(v)}`" for k, v in fixed.items() if k != "progress"]
    if case["run"] == "step":
        parts.insert(0, f"{case['starts']} starts")
    if case["run"] == "emulator":
        parts = [f"`{case['config']}`", f"{shown_value(case['duration'])} s"] + [
            f"`--{k} {v}`" for k, v in case["options"].items()]
    if case["run"] == "study":
        parts += [f"{case['draws']} draws (seed {case['seed']}) of " + ", ".join(
            f"`{name}` U({shown_value(d['low'])}, {shown_value(d['high'])})" for name, d in case["vary"].items())]
    if case["run"] == "box":
        parts = [f"the {case['push']} push, {case['draws']} draws of `{case['box']}`"]
    return ", ".join(parts)


def battery_markdown(battery: Battery) -> str:
    """The battery's table (docs/results.md): per case its run kind, scenario, rate, settings, asked force and what it
    is; then the filters' parameters per rate and --quick's cuts, all from `battery`."""
    tasks = {(c["scenario"], c["task"]): c for c in battery.cases if "task" in c}
    lines = ["| case | runs | scenario | rate | settings | asked (N) | what |", "|---|---|---|---|---|---|---|"]
    for case in battery.cases:
        asked = case.get("asked_N", tasks[case["scenario"], case["push"]]["asked_N"] if "push" in case else None)
        lines.append(f"| {case['name']} | {case['run']} | {case.get('scenario', 'softcbf hardware')} | "
                     f"{RATES[case['rate']]} | {settings_text(case, tasks)} | {'' if asked is None else shown_value(asked)} | "
                     f"{case['description']} |")
    bench, quick = battery.bench, battery.quick
    tunings = ", ".join(f"{tuning} in the {RATES[rate]} cases" for rate, tuning in bench["paper_tunings"].items())
    eerg = ", ".join(f"{k}={v}" for k, v in bench["eerg_params"].items())
    lines += ["", f"Per case: paper-cbf runs {tunings}; e-erg `{eerg}`; c-erg `contact_aware` as the plant is (false "
              f"on paper_sim, true elsewhere); a filter spec's own parameters win. `--quick` runs every case "
              f"{shown_value(quick['duration'])} s, a contact task {shown_value(quick['push_duration'])} s, the step case "
              f"{quick['step_starts']} starts of {shown_value(quick['step_duration'])} s, a study case "
              f"{quick['study_draws']} draws, a box case {quick['box_draws']} draws, and skips "
              f"{', '.join(quick['skipped'])}."]
    return "\n".join(lines)


def with_table(text: str, table: str) -> str:
    """`text` (docs/results.md) with the part between `BEGIN` and `END` replaced by `table`."""
    head, begin, rest = text.partition(BEGIN)
    _, end, tail = rest.partition(END)
    if not begin or not end:
        raise ValueError(f"the page holds no battery table between {BEGIN!r} and {END!r}")
    return f"{head}{BEGIN}\n{table}\n{END}{tail}"


def main(argv: list[str]) -> int:
    """`python -m softcbf.bench.battery PAGE`: rewrite PAGE's battery table from `BATTERY_FILE`."""
    if len(argv) != 1:
        print("usage: python -m softcbf.bench.battery PAGE (e.g. docs/results.md)", file=sys.stderr)
        return 2
    page = Path(argv[0])
    page.write_text(with_table(page.read_text(encoding="utf-8"), battery_markdown(load_battery())), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
