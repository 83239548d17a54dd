"""The battery's data file (softcbf/bench/battery.toml, softcbf.bench.battery): what the runner passes for every case
(an explicit table here), its checks, its study cases as study files, and the table of cases in docs/results.md."""

from __future__ import annotations

import copy
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path

import pytest

import softcbf.bench.cases as cases
import softcbf.hardware_cli
from softcbf.bench import CASES, FilterSpec, RunOptions, mismatch_study, push_box_study
from softcbf.bench.battery import BATTERY_FILE, BEGIN, END, battery_markdown, check_battery, load_battery
from softcbf.study.definition import Study, load_study
from vocabulary.files import read_settings_file
from vocabulary.project_files import project_file

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

REPO = Path(__file__).resolve().parents[1]


def push(level: str, **extra):
    """A constant push's scenario parameters (both segments at `level` hPa, 6 s)."""
    return {"duration": 6.0, "nominal": "step", "nominal_params": {"seed": "0", "low_hPa": level, "high_hPa": level}, **extra}


CAMERA = {"saved_frames_hz": 0.0}
TARGET = {"duration": 6.0, "nominal": "force-target", "nominal_params": {"target_N": "0.096"}}
THREE_SEG = {"robot": "three-segment", **push("40")}
# The battery as it ran before its tables moved into battery.toml: case → (scenario, its parameters besides filter,
# filter_params and progress, c-erg's contact_aware there, the duration with --quick). The nominal's parameters were
# the deprecated text "seed=0;low_hPa=L;high_hPa=L", which the scenario read as the same mapping as these.
SCENARIO_RUNS = {
    "paper_sim_150": ("paper_sim", {"amplitude": 150.0}, "false", 1.0),
    "mujoco_contact": ("mujoco_contact", {}, "true", 1.0),
    "camera_loop": ("camera_loop", CAMERA, "true", 1.0),
    "camera_stiff_close": ("camera_loop", {"plate_stiffness": 1.1 * 11.16, "facet_offset": -1e-3, **CAMERA}, "true", 1.0),
    "mujoco_push_030": ("mujoco_contact", push("56.983"), "true", 3.0),
    "mujoco_push_060": ("mujoco_contact", push("62.516"), "true", 3.0),
    "mujoco_push_090": ("mujoco_contact", push("68.215"), "true", 3.0),
    "mujoco_push_120": ("mujoco_contact", push("74.018"), "true", 3.0),
    "mujoco_push_150hPa": ("mujoco_contact", push("150"), "true", 3.0),
    "mujoco_force_target": ("mujoco_contact", TARGET, "true", 3.0),
    "camera_push_030": ("camera_loop", push("57.015", **CAMERA), "true", 3.0),
    "camera_push_060": ("camera_loop", push("62.551", **CAMERA), "true", 3.0),
    "camera_push_090": ("camera_loop", push("68.258", **CAMERA), "true", 3.0),
    "camera_push_120": ("camera_loop", push("74.07", **CAMERA), "true", 3.0),
    "camera_push_150hPa": ("camera_loop", push("150", **CAMERA), "true", 3.0),
    "camera_force_target": ("camera_loop", {**TARGET, **CAMERA}, "true", 3.0),
    "mujoco_push_flexure": ("mujoco_contact", {"plate": "flexure", **push("150")}, "true", 3.0),
    "paper_sim_3seg": ("paper_sim", THREE_SEG, "false", 1.0),
    "mujoco_3seg": ("mujoco_contact", THREE_SEG, "true", 1.0),
}
ASKED_N = {"mujoco_push_030": 0.04823, "mujoco_push_060": 0.09584, "mujoco_push_090": 0.144, "mujoco_push_120": 0.192,
           "mujoco_push_150hPa": 0.63757, "mujoco_force_target": 0.0941, "camera_push_030": 0.04823,
           "camera_push_060": 0.09583, "camera_push_090": 0.144, "camera_push_120": 0.192, "camera_push_150hPa": 0.63433,
           "camera_force_target": 0.09405, "mujoco_push_box": 0.63757, "camera_push_box": 0.63433,
           "mujoco_push_flexure": 1.48154}
ORDER = ["paper_sim_150", "step", "mujoco_contact", "camera_loop", "camera_stiff_close", "hardware_emulator",
         "camera_mismatch", *[f"{p}_{t}" for p in ("mujoco", "camera") for t in (
             "push_030", "push_060", "push_090", "push_120", "push_150hPa", "force_target")],
         "mujoco_push_box", "camera_push_box", "mujoco_push_flexure", "paper_sim_3seg", "mujoco_3seg"]
RATE = {name: "camera" if name.startswith("camera") or name == "hardware_emulator" else "1kHz" for name in ORDER}
MISMATCH_FIXED = {"t0": 15.0, "saved_frames_hz": 0.0, "progress": False, "assumed_plate_stiffness": 11.16}
MISMATCH_VARY = {"plate_stiffness": {"dist": "uniform", "low": 0.9 * 11.16, "high": 1.1 * 11.16},
                 "true_gain_scale": {"dist": "uniform", "low": 0.9, "high": 1.1},
                 "facet_offset": {"dist": "uniform", "low": -1e-3, "high": 1e-3}}
BOX_FILES = {"mujoco_push_box": "studies/mismatch_box_contact.toml", "camera_push_box": "studies/mismatch_box_camera.toml"}


def plain(value):
    """`value` with mappings as dicts and tuples as lists (typed parameters compare as their items)."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def recorded_calls(monkeypatch, tmp_path: Path, spec: FilterSpec, quick: bool) -> dict[str, list]:
    """Per case, what its `run` passes to the scenario (["scenario", name, kwargs]), the study engine (["study",
    the study's file keys, run_study's options]) and the hardware mode (["hardware", argv]); nothing runs."""
    calls: list = []

    class Recorder:
        def __init__(self, name):
            self.name = name

        def run(self, out, **kwargs):
            calls.append(["scenario", self.name, plain(kwargs)])

    monkeypatch.setattr(cases, "get", Recorder)
    monkeypatch.setattr(cases, "run_figures", lambda folder: [])
    monkeypatch.setattr(cases, "pooled_figures", lambda *a, **k: {"fault": None, "f_max_N": 0.16})
    monkeypatch.setattr(cases, "f_max_of", lambda out: 0.16)
    monkeypatch.setattr(cases, "steady_force_of_folder", lambda out: 0.1)
    monkeypatch.setattr(cases, "run_study", lambda study, out, **kw: calls.append(["study", plain(study.to_dict()), kw]))
    monkeypatch.setattr(cases, "study_figures", lambda out: {})
    monkeypatch.setattr(cases, "study_draws", lambda out: ())
    monkeypatch.setattr(cases, "draw_figures", lambda *a: {})
    monkeypatch.setattr(softcbf.hardware_cli, "main", lambda argv: calls.append(["hardware", list(argv)]) or 0)
    out = {}
    for case in CASES:
        calls.clear()
        folder = tmp_path / f"{int(quick)}-{case.name}"
        case.run(case, spec, folder, RunOptions(quick=quick))
        out[case.name] = [["hardware", [a.replace(str(folder), "OUT") for a in call[1]]] if call[0] == "hardware"
                          else call for call in calls]
    return out


def expected_calls(quick: bool) -> dict[str, list]:
    """The calls of `recorded_calls` for c-erg, from the explicit tables above."""
    out: dict[str, list] = {}
    for name in ORDER:
        if name in SCENARIO_RUNS:
            scenario, params, aware, quick_s = SCENARIO_RUNS[name]
            kwargs = {**params, "filter": "c-erg", "filter_params": {"contact_aware": aware}, "progress": False}
            out[name] = [["scenario", scenario, {**kwargs, "duration": quick_s} if quick else kwargs]]
    starts, step_s = (3, 0.5) if quick else (20, 5.0)
    out["step"] = [["scenario", "paper_sim", {
        "duration": step_s, "filter": "c-erg", "filter_params": {"contact_aware": "false"}, "nominal": "step",
        "nominal_params": {"seed": str(seed), "low_hPa": "60", "high_hPa": "300"}, "progress": False}]
        for seed in range(starts)]
    out["hardware_emulator"] = [["hardware", [
        str(project_file("examples/hardware_emulated.toml")), "--robot", "reference", "--port", "emulated", "--camera",
        "virtual", "--filter", "c-erg", "--duration", "20.0", "--out", "OUT/run", "--filter-param", "contact_aware=true"]]]
    options = {"workers": 1, "keep_runs": True, "progress": not quick, "resume": False}
    out["camera_mismatch"] = [["study", {
        "name": "bench_camera_mismatch_c-erg", "scenario": "camera_loop", "seed": 2026, "sampling": "monte_carlo",
        "description": "softcbf bench: camera_loop with plate stiffness ±10 %, actuator gain ±10 %, facet offset ±1 mm",
        "tunings": ["c-erg"], "tuning_parameter": "filter", "objective": "rho_min_meas", "draws": 2 if quick else 100,
        "fixed": {**MISMATCH_FIXED, "duration": 1.0 if quick else 30.0, "filter_params": {"contact_aware": "true"}},
        "vary": MISMATCH_VARY}, options]]
    for name, file in BOX_FILES.items():
        box = load_study(project_file(file))
        plant = box.scenario
        out[name] = [["study", {
            "name": f"bench_{name}_c-erg", "scenario": plant, "seed": 2027, "sampling": "monte_carlo",
            "description": f"softcbf bench: the push_150hPa push on {plant} under the standard box ({file})",
            "tunings": ["c-erg"], "tuning_parameter": "filter", "objective": "rho_min_meas", "draws": 3 if quick else 100,
            "fixed": {**{k: v for k, v in box.fixed.items() if k != "t0"}, "duration": 3.0 if quick else 6.0,
                      "filter_params": {"contact_aware": "true"}, "nominal": "step",
                      "nominal_params": {"seed": "0", "low_hPa": "150", "high_hPa": "150"}, "progress": False,
                      **({"saved_frames_hz": 0.0} if plant == "camera_loop" else {})},
            "vary": plain(box.to_dict()["vary"])}, options]]
    return out


@pytest.mark.parametrize("quick", [False, True])
def test_the_runner_passes_every_case_the_settings_of_the_explicit_table(monkeypatch, tmp_path, quick):
    """The cases, their order, rates and asked forces, and everything each case's run passes to the scenario, the
    study engine or the hardware mode, full and --quick, are the explicit tables above (the battery before it moved
    into battery.toml: the same calls, compared when it moved)."""
    assert [c.name for c in CASES] == ORDER
    assert {c.name: c.rate for c in CASES} == RATE
    assert {c.name: c.asked_N for c in CASES if c.asked_N is not None} == ASKED_N
    assert [c.name for c in CASES if c.resumable] == ["camera_mismatch", "mujoco_push_box", "camera_push_box"]
    assert cases.QUICK_SKIPPED == {"hardware_emulator": "--quick: the emulator runs in real time after a start-up of "
                                                         "several seconds"}
    assert recorded_calls(monkeypatch, tmp_path, FilterSpec("c-erg"), quick) == expected_calls(quick)


def test_each_rate_gives_paper_cbf_its_tuning_and_e_erg_its_interval():
    for case in CASES:
        tuning = {"1kHz": "Low", "camera": "HW-High"}[RATE[case.name]]
        assert cases.case_filter_params(FilterSpec("paper-cbf"), case) == {"tuning": tuning}
        assert cases.case_filter_params(FilterSpec("e-erg"), case) == {
            "contact_aware": "true", "stiffness_lo_ratio": "0.9", "stiffness_hi_ratio": "1.1"}


def test_every_case_passes_a_study_files_checks():
    """Each case's scenario parameters, as a one-draw study of the filter "none", pass the study file's checks
    (the scenario's own); the study and box cases are `Study`s already."""
    for case in CASES:
        run = case.table["run"]
        if run in ("study", "box"):
            build = mismatch_study if run == "study" else push_box_study
            assert isinstance(build(FilterSpec("none"), case, 1, 1.0), Study)
        elif run != "emulator":
            fixed = {k: v for k, v in case.scenario_params.items() if k != "scenario"}
            if run == "step":
                fixed.update(nominal="step", nominal_params={"seed": "0", **fixed["nominal_params"]})
            Study.from_dict({"name": case.name, "scenario": case.scenario_params["scenario"], "tunings": ["none"],
                             "tuning_parameter": "filter", "draws": 1, "fixed": fixed})


def toml_value(value) -> str:
    """A TOML value of a bool, number or string."""
    if isinstance(value, bool):
        return str(value).lower()
    return f'"{value}"' if isinstance(value, str) else repr(value)


def test_a_study_case_copied_into_a_study_file_is_the_bench_s_study(tmp_path):
    """battery.toml's recipe: the case's table without name, rate and run, with a name, the filter as its one tuning."""
    table = next(t for t in tomllib.loads(BATTERY_FILE.read_text(encoding="utf-8"))["case"] if t["run"] == "study")
    study = {k: v for k, v in table.items() if k not in ("name", "rate", "run")}
    lines = ['name = "copied"', 'tunings = ["c-erg"]', 'tuning_parameter = "filter"',
             'filter_params = { contact_aware = "true" }']
    lines += [f"{key} = {toml_value(study[key])}" for key in ("scenario", "description", "seed", "sampling", "draws")]
    lines += ["[fixed]"] + [f"{k} = {toml_value(v)}" for k, v in study["fixed"].items()]
    for name, dist in study["vary"].items():
        lines += [f"[vary.{name}]"] + [f"{k} = {toml_value(v)}" for k, v in dist.items()]
    path = tmp_path / "copied.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    case = next(c for c in CASES if c.name == table["name"])
    bench = mismatch_study(FilterSpec("c-erg"), case, table["draws"], table["fixed"]["duration"]).to_dict()
    assert load_study(path).to_dict() == {**bench, "name": "copied"}


def battery_data() -> dict:
    return read_settings_file(BATTERY_FILE, "battery file")


def case_named(data: dict, name: str) -> dict:
    return next(c for c in data["case"] if c["name"] == name)


MISTAKES = [
    (lambda d: case_named(d, "step").update(draws=3), "case 'step': unknown key(s) draws; valid: "),
    (lambda d: case_named(d, "camera_mismatch").pop("seed"), "case 'camera_mismatch': missing key(s) seed"),
    (lambda d: case_named(d, "step").update(run="steps"), "case 'step': run must be one of scenario, step, emulator"),
    (lambda d: case_named(d, "step").update(rate="100Hz"), "case 'step': rate must be one of 1kHz, camera, got '100Hz'"),
    (lambda d: d["case"].append(copy.deepcopy(case_named(d, "step"))), "case name(s) step are given more than once"),
    (lambda d: case_named(d, "mujoco_push_box").update(push="push_140"), "case 'mujoco_push_box': push must name a "
                                                                          "contact task of mujoco_contact, got 'push_140'"),
    (lambda d: d["quick"]["skipped"].update(nope="x"), "[quick.skipped] names no case: nope"),
    (lambda d: d["bench"].pop("push_duration"), "[bench]: missing key(s) push_duration"),
    (lambda d: d.update(cases=[]), "the battery: unknown key(s) cases"),
]


@pytest.mark.parametrize("mistake, message", MISTAKES)
def test_a_mistake_in_the_battery_file_is_one_line_naming_it(mistake, message):
    data = battery_data()
    mistake(data)
    with pytest.raises(ValueError, match=re.escape(message)) as info:
        check_battery(data)
    assert "\n" not in str(info.value)


def test_load_battery_names_the_file(tmp_path):
    path = tmp_path / "battery.toml"
    path.write_text(BATTERY_FILE.read_text(encoding="utf-8").replace('run = "step"', 'run = "steps"'), encoding="utf-8")
    with pytest.raises(ValueError, match=f"battery file {re.escape(str(path))}: case 'step': run must be one of"):
        load_battery(path)


def test_the_results_page_shows_the_battery_table_generated_from_the_file():
    """docs/results.md's battery table is `battery_markdown` of battery.toml (python -m softcbf.bench.battery
    docs/results.md rewrites it), so the page and the data cannot disagree."""
    page = (REPO / "docs" / "results.md").read_text(encoding="utf-8")
    table = page.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n")
    assert table == battery_markdown(load_battery()), "run: python -m softcbf.bench.battery docs/results.md"
    for case in CASES:
        assert f"| {case.name} |" in table


def test_the_cases_module_names_only_constants_it_has():
    """The module docstring refers to the data by the names that hold it (no number of its own to go stale)."""
    doc = cases.__doc__
    assert "|" not in doc
    for name in re.findall(r"`([A-Z][A-Z0-9_]+)`", doc):
        assert hasattr(cases, name), name
