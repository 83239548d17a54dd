"""The controller under test is a plug-in (docs/safety-filter.md): the registry, the one control step, and
user filters through every front end (softcbf run in MuJoCo and the camera loop, a study,
the hardware emulator)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from closedloop.monitor import SafeAction, SafetyFlags, SafetyMonitor
from closedloop.step import ControlStep
from controllers.cbf.barrier import get_tuning
from controllers.cbf.paper_filter import CBFFilter, paper_cbf
from controllers.model.params import reference_robot
from controllers.registry import FILTERS, NOMINALS, build_filter, build_nominal, label, parameters, parse_params
from controllers.model.safe_set import paper_safe_set
from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
from controllers.contract.safety_filter import Estimate, FilterContext, FilterOutput
from softcbf.cli import list_text, main
from softcbf_mj.outputs.runio import load_timeseries, read_run_folder

REPO = Path(__file__).resolve().parents[1]
EXAMPLE_FILTER = REPO / "examples" / "clip_filter.py"
SPEC_CLIP_FILTER = '''import numpy as np
class ClipFilter:
    def __init__(self, limit_hPa: float = 100.0):
        self.limit = limit_hPa
    def __call__(self, estimate, u_nom):
        return np.clip(u_nom, -self.limit, self.limit)
'''
ROBOT, SAFE = reference_robot(), paper_safe_set()
CONTEXT = FilterContext.for_robot(ROBOT, SAFE, 1e-3)
FAST = ["--amplitude", "150", "--frequency", "0.25", "--t0", "1", "--progress", "false"]


@pytest.fixture(scope="module")
def clip_file(tmp_path_factory) -> Path:
    """The docs/safety-filter.md ClipFilter, verbatim, in a file outside the project."""
    path = tmp_path_factory.mktemp("user") / "clip.py"
    path.write_text(SPEC_CLIP_FILTER, encoding="utf-8")
    return path


def _estimate(t=0.0):
    return Estimate(t, np.array([0.3, 0.1]), np.zeros(2), t)


# --- registry ------------------------------------------------------------------------------


def test_builtins_document_every_parameter_with_a_unit():
    for table in (FILTERS, NOMINALS):
        for name, factory in table.items():
            for p in parameters(factory):
                assert p.doc.endswith("]") and "[" in p.doc, (name, p.name)
    text = list_text()
    assert "paper-cbf" in text and "gamma" in text and "[1/s]" in text and "tip-tracker" in text and "sinusoid" in text


def test_user_factory_gets_converted_parameters_and_the_context_when_it_asks(tmp_path):
    (tmp_path / "f.py").write_text(
        "class F:\n"
        "    def __init__(self, context, gain: float = 1.0, steps: int = 2, on: bool = False, cap: float | None = None):\n"
        "        self.context, self.args = context, (gain, steps, on, cap)\n"
        "    def __call__(self, estimate, u_nom):\n"
        "        return u_nom\n", encoding="utf-8")
    f = build_filter(f"{tmp_path}/f.py:F", {"gain": "2.5", "steps": "7", "on": "yes", "cap": "none"}, CONTEXT)
    assert f.context is CONTEXT and f.args == (2.5, 7, True, None)
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) bogus for F; valid: cap, gain, on, steps"):
        build_filter(f"{tmp_path}/f.py:F", {"bogus": "1"}, CONTEXT)
    with pytest.raises(ValueError, match="parameter steps must be int, got 'x'"):
        build_filter(f"{tmp_path}/f.py:F", {"steps": "x"}, CONTEXT)
    with pytest.raises(ValueError, match=r"unknown name 'nope' \(did you mean 'none'\?\); built-ins: paper-cbf, none"):
        build_filter("nope", {}, CONTEXT)
    with pytest.raises(ValueError, match="has no callable 'G'"):
        build_filter(f"{tmp_path}/f.py:G", {}, CONTEXT)
    assert parse_params("a=1; b = x ;") == {"a": "1", "b": "x"}
    with pytest.raises(ValueError, match="NAME=VALUE"):
        parse_params("a")


def test_paper_filter_presets_and_custom_tunings_are_the_same_filter():
    estimate, u_nom = Estimate(0.0, np.array([0.3, 0.2]), np.array([1.0, 1.0]), 0.0), np.array([150.0, 150.0])
    preset = build_filter("paper-cbf", {"tuning": "Low"}, CONTEXT)(estimate, u_nom)
    custom = build_filter("paper-cbf", {"tuning": "custom", "a_E": "2", "b_E": "2", "gamma": "2"}, CONTEXT)(estimate, u_nom)
    direct = CBFFilter(ROBOT, SAFE, get_tuning("Low"))(estimate, u_nom)
    assert preset.action == "qp" and np.array_equal(preset.u, custom.u) and np.array_equal(preset.u, direct.u)
    assert label("paper-cbf", {"tuning": "custom", "a_E": 5, "b_E": 5, "gamma": 5}) == "custom(a_E=5,b_E=5,gamma=5)"
    with pytest.raises(ValueError, match="tuning 'custom' needs a_E, b_E and gamma"):
        paper_cbf(CONTEXT, "custom", a_E=1.0)
    with pytest.raises(ValueError, match="a_E set a custom tuning"):
        paper_cbf(CONTEXT, "Low", a_E=1.0)


def test_nominals_by_name():
    sinusoid = build_nominal("sinusoid", {"amplitude": "100", "frequency": "0.25", "t0": "1"}, CONTEXT)
    np.testing.assert_allclose(sinusoid(0.0, np.zeros(2), np.zeros(2)), [100.0, 100.0], rtol=1e-15)
    tracker = build_nominal("tip-tracker", {"x_m": "0.2", "y_m": "0.15"}, CONTEXT)
    u = tracker(0.0, np.zeros(2), np.zeros(2))
    assert u.shape == (2,) and np.all(np.isfinite(u)) and np.any(np.abs(u) > 1.0)


# --- the one control step -----------------------------------------------------------------


class Scripted:
    """A filter returning scripted commands (and a diagnostic)."""

    def __init__(self, commands):
        self.commands = list(commands)

    def __call__(self, estimate, u_nom):
        u = np.asarray(self.commands.pop(0), dtype=float)
        return FilterOutput(u, "scripted", diagnostics={"gain": 2.0, "hit": True}, diagnostic_units={"gain": "1", "hit": "bool"})


def test_step_clips_refuses_non_finite_commands_and_records_both():
    step = ControlStep(Scripted([[400.0, -10.0], [math.nan, 0.0], [20.0, 30.0]]), lambda t, q, qd: np.zeros(2), CONTEXT,
                       SafetyMonitor(2, hold_s=0.5))
    first = step(_estimate(0.0))
    assert first.action is SafeAction.RUN and np.array_equal(first.u, [150.0, -10.0])  # clipped to u_max
    assert np.array_equal(first.output.u, [400.0, -10.0])  # what the filter returned
    second = step(_estimate(0.1))
    assert second.action is SafeAction.HOLD and "command_nonfinite" in second.reasons and np.array_equal(second.u, first.u)
    third = step(_estimate(0.2))
    assert third.action is SafeAction.RUN and np.array_equal(third.u, [20.0, 30.0])
    wrong = ControlStep(Scripted([[1.0, 2.0, 3.0]]), lambda t, q, qd: np.zeros(2), CONTEXT)
    record = wrong(_estimate())
    assert record.action is SafeAction.VENT and record.reasons == ("filter_fault",)  # nothing admitted yet: vent at once
    assert wrong.stopped and wrong.fault.where == "filter return" and "shape (2,), got (3,)" in wrong.fault.message


def test_step_reset_restarts_the_monitor_for_a_new_run():
    step = ControlStep(Scripted([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]), lambda t, q, qd: np.zeros(2), CONTEXT,
                       SafetyMonitor(2, hold_s=0.5))
    step(_estimate(0.0))
    step(_estimate(1.0))
    step.monitor.step(1.0, None, SafetyFlags(interrupted=True))  # the run ends vented
    step.reset()  # a new run: its clock starts at 0 s again
    again = step(_estimate(0.0))
    assert again.action is SafeAction.RUN and np.array_equal(again.u, [5.0, 6.0]) and not step.monitor.vent_latched


def test_step_keeps_its_own_copy_of_a_command_the_filter_may_reuse():
    buffer = np.array([1.0, 2.0])

    def reuse(estimate, u_nom):
        return buffer

    unbounded = FilterContext.for_robot(ROBOT, SAFE, 1e-3, pressure_limits=False)
    first = ControlStep(reuse, lambda t, q, qd: np.zeros(2), unbounded)(_estimate(0.0))
    buffer[:] = np.nan  # the filter overwrites its array after the call
    assert np.array_equal(first.u, [1.0, 2.0])


FLAT_LAYOUT = DiagnosticLayout({"gain": (), "rows": (2, 2), "hit": (), "mask": (3,)},
                               {"gain": "1", "rows": "m", "hit": "bool", "mask": "bool"}, frozenset({"hit", "mask"}))
FLAT_VALUES = [[2.0, 1.0, 2.0, 3.0, 4.0, True, True, False, True], [0.5, -1.0, -2.0, -3.0, -4.0, False, False, True, False]]


class FlatScripted:
    """Scripted commands with FlatDiagnostics (`as_dict`: the same diagnostics as a plain dict)."""

    def __init__(self, as_dict):
        self.calls, self.as_dict = 0, as_dict

    def __call__(self, estimate, u_nom):
        values = FLAT_VALUES[self.calls % 2]
        self.calls += 1
        flat = FlatDiagnostics(FLAT_LAYOUT, values)
        diagnostics = {key: flat[key] for key in flat} if self.as_dict else flat
        return FilterOutput(np.array([values[0], -values[0]]), diagnostics=diagnostics, diagnostic_units=FLAT_LAYOUT.units)


def test_flat_diagnostics_read_as_their_arrays_and_check_their_layout():
    flat = FlatDiagnostics(FLAT_LAYOUT, FLAT_VALUES[0])
    assert list(flat) == ["gain", "rows", "hit", "mask"] and len(flat) == 4 and "rows" in flat and "b" not in flat
    assert flat["gain"] == 2.0 and flat["hit"] is True
    assert flat["rows"].dtype == float and flat["rows"].tolist() == [[1.0, 2.0], [3.0, 4.0]]
    assert flat["mask"].dtype == bool and flat["mask"].tolist() == [True, False, True]
    with pytest.raises(ValueError, match="values must hold the layout's 9 values, got 8"):
        FlatDiagnostics(FLAT_LAYOUT, FLAT_VALUES[0][:-1])
    with pytest.raises(ValueError, match=r"units must declare a unit for every diagnostic, missing \['mask'\]"):
        DiagnosticLayout({"mask": (3,)}, {})
    with pytest.raises(ValueError, match=r"booleans must be keys of shapes, got \['hit'\]"):
        DiagnosticLayout({"gain": ()}, {"gain": "1"}, frozenset({"hit"}))


def test_recorder_stores_flat_diagnostics_as_it_stores_a_plain_mapping():
    from closedloop.record import Recorder

    runs = []
    for as_dict in (False, True):
        step = ControlStep(FlatScripted(as_dict), lambda t, q, qd: np.ones(2), CONTEXT)
        recorder = Recorder(5, 2, {"t": ()})
        record = None
        for k, called in enumerate([True, False, True, True, False]):
            if called:
                record = step(_estimate(0.1 * k))
            recorder.record(k, record, called, [0.1 * k])
        runs.append((recorder.columns(), recorder.units()))
    (flat, flat_units), (plain, plain_units) = runs
    assert flat_units == plain_units and flat.keys() == plain.keys()
    for key in plain:
        assert flat[key].dtype == plain[key].dtype, key
        if key != "filter_us":  # a measured time
            np.testing.assert_array_equal(flat[key], plain[key], err_msg=key)
    assert np.isnan(flat["filter_us"]).tolist() == [False, True, False, False, True]
    assert flat["hit"].tolist() == [True, False, False, True, False]  # an event on its call's row only
    assert flat["mask"].tolist() == [[True, False, True]] * 2 + [[False, True, False]] + [[True, False, True]] * 2
    assert flat["rows"][2].tolist() == [[-1.0, -2.0], [-3.0, -4.0]] and flat["gain"].tolist() == [2.0, 2.0, 0.5, 2.0, 2.0]


def test_recorder_keeps_diagnostics_with_their_units_and_counts_events_per_call():
    from closedloop.record import Recorder

    step = ControlStep(Scripted([[1.0, 2.0], [3.0, 4.0]]), lambda t, q, qd: np.ones(2), CONTEXT)
    recorder = Recorder(4, 2, {"t": ()})
    a = step(_estimate(0.0))
    recorder.record(0, a, True, [0.0])
    recorder.record(1, a, False, [0.1])  # held between calls
    b = step(_estimate(0.2))
    recorder.record(2, b, True, [0.2])
    recorder.record(3, b, False, [0.3])
    c, units = recorder.columns(), recorder.units()
    assert units["gain"] == "1" and units["hit"] == "bool" and c["hit"].dtype == bool
    assert c["hit"].tolist() == [True, False, True, False] and c["gain"].tolist() == [2.0] * 4
    assert c["u_filter"].tolist() == [[1, 2], [1, 2], [3, 4], [3, 4]] and np.isnan(c["filter_us"][[1, 3]]).all()


# --- front ends ----------------------------------------------------------------------------


def _clip_run(tmp_path, scenario, clip_file, *extra):
    out = tmp_path / scenario
    assert main(["run", scenario, "--filter", f"{clip_file}:ClipFilter", "--filter-param", "limit_hPa=100",
                 "--out", str(out), *FAST, *extra]) == 0
    folder = read_run_folder(out)
    assert folder.labels == ["ClipFilter(limit_hPa=100)"]
    row = folder.summary["runs"][0]
    assert row["filter"] == f"{clip_file}:ClipFilter" and row["filter_params"] == {"limit_hPa": 100.0}
    assert row["recovery_steps"] == 0 and row["active_steps"] is None
    series, units = load_timeseries(out / row["timeseries"])
    assert units["u_filter"].startswith("hPa") and "b" not in series
    return series


def test_spec_clip_filter_runs_in_mujoco_contact(tmp_path, clip_file):
    series = _clip_run(tmp_path, "mujoco_contact", clip_file, "--duration", "0.3")
    np.testing.assert_array_equal(series["u"], np.clip(series["u_nom"], -100.0, 100.0))
    assert series["u_nom"].max() > 140.0 and series["u"].max() == 100.0  # the clip is active


def test_spec_clip_filter_runs_in_the_camera_loop(tmp_path, clip_file):
    series = _clip_run(tmp_path, "camera_loop", clip_file, "--duration", "0.5", "--width", "640", "--height", "360",
                       "--saved-frames-hz", "0")
    run = series["action"] == 0
    assert np.any(run) and np.all(np.abs(series["u"][run]) <= 100.0)


def test_cli_refuses_an_unknown_filter_parameter(tmp_path, clip_file, capsys):
    code = main(["run", "paper_sim", "--filter", f"{clip_file}:ClipFilter", "--filter-param", "limit=1",
                 "--duration", "0.1", "--out", str(tmp_path / "x"), "--progress", "false"])
    assert code == 2 and "unknown parameter(s) limit for ClipFilter; valid: limit_hPa" in capsys.readouterr().err


def test_paper_sim_custom_tuning_matches_its_preset(tmp_path):
    common = ["--duration", "0.3", "--amplitude", "150", "--frequency", "0.5", "--progress", "false", "--data-only"]
    assert main(["run", "paper_sim", "--tunings", "Low", "--out", str(tmp_path / "a"), *common]) == 0
    assert main(["run", "paper_sim", "--tuning", "custom", "--filter-param", "a_E=2", "--filter-param", "b_E=2",
                 "--filter-param", "gamma=2", "--out", str(tmp_path / "b"), *common]) == 0
    a, _ = load_timeseries(tmp_path / "a" / "timeseries" / "Low.npz")
    (row,) = read_run_folder(tmp_path / "b").summary["runs"]
    assert row["tuning"] == "custom(a_E=2,b_E=2,gamma=2)"
    b, _ = load_timeseries(tmp_path / "b" / row["timeseries"])
    assert np.any(a["active"]) and np.array_equal(a["u"], b["u"])


def test_example_filter_runs_in_a_study(tmp_path):
    from softcbf.study.definition import load_study
    from softcbf.study.execute import run_study
    from softcbf.study.store import StudyStore

    text = (REPO / "examples" / "clip_filter_study.toml").read_text(encoding="utf-8")
    text = text.replace('"examples/clip_filter.py:ClipFilter"', json.dumps(f"{EXAMPLE_FILTER}:ClipFilter"))
    text = text.replace("duration = 5.0", "duration = 0.3")
    (tmp_path / "s.toml").write_text(text, encoding="utf-8")
    study = load_study(tmp_path / "s.toml")
    assert study.n_samples == 3 and study.sample(2).kwargs["filter_params"] == {"limit_hPa": 150.0}
    outcome = run_study(study, tmp_path / "out", workers=1, progress=False)
    assert outcome.ran == 3 and outcome.failed == 0
    rows = sorted(StudyStore.open(tmp_path / "out").load_rows(), key=lambda r: r["sample"])
    assert [r["status"] for r in rows] == ["ok"] * 3, [r.get("error") for r in rows]
    assert [r["u_peak_abs_hPa"] for r in rows] == [50.0, 100.0, pytest.approx(150.0, abs=1.0)]


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")  # a real-time hardware loop: one at a time (the suite's addopts)
def test_example_filter_runs_on_the_hardware_emulator(tmp_path):
    from hardware.config import HardwareConfig
    from softcbf.hardware_cli import run_hardware
    from softcbf_mj.emulator.emulate import EmulatedHardware

    config = HardwareConfig.load(REPO / "examples" / "hardware_emulated.toml").with_overrides(
        {"filter": f"{EXAMPLE_FILTER}:ClipFilter", "filter_params": {"limit_hPa": 40.0}, "duration": 2.0})
    with EmulatedHardware(config) as emulation:
        (tmp_path / "hw").mkdir()
        row = run_hardware(config, tmp_path / "hw", emulation=emulation, report=False)
    assert row["tuning"] == "ClipFilter(limit_hPa=40)" and row["cycles"] + row["cycles_skipped"] == 20
    series, _ = load_timeseries(tmp_path / "hw" / row["timeseries"])
    assert np.all(np.abs(series["u_sent"]) <= 40.0 + 0.05) and series["u_nom"].max() > 0
    np.testing.assert_array_equal(series["u_filter"], np.clip(series["u_nom"], -40.0, 40.0))


def test_hardware_cli_takes_a_filter_and_refuses_a_bad_parameter(tmp_path, capsys):
    import argparse

    from softcbf.hardware_cli import add_arguments, configure, main as hardware_main

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    example = REPO / "examples" / "hardware_emulated.toml"
    args = parser.parse_args([str(example), "--filter", f"{EXAMPLE_FILTER}:ClipFilter", "--filter-param", "limit_hPa=60"])
    config = configure(args)
    assert config.control.filter == f"{EXAMPLE_FILTER}:ClipFilter" and config.control.filter_arguments() == {"limit_hPa": "60"}
    assert hardware_main([str(example), "--filter", f"{EXAMPLE_FILTER}:ClipFilter", "--filter-param", "limit=1",
                          "--out", str(tmp_path / "o")]) == 2
    assert "filter: unknown parameter(s) limit for ClipFilter" in capsys.readouterr().err
