"""One fault policy for everything user code can raise or return (docs/safety-filter.md#the-plug-in-boundary-is-a-trust-boundary).

Each defect has its own test: a return whose conversion raises (a float subclass whose `__float__` raises, an int
subclass as rho_pred, diagnostics whose `keys()` raises) escaped the step (D1); the recorder read the diagnostics again
after the check (D2); SystemExit and other BaseExceptions from a filter, nominal or factory ended the command with exit
0 and no output (D3); a filter that changes the working folder lost the run (D7); u_nom's read-only flag could be set
back, and the serial record took the filter's values where the batched step faulted (D8); the command line's error
boundary took the testbed's own ValueErrors for usage errors and built the spec after the run folder; and the minor
items (a non-daemon thread kept `softcbf run` alive, a diagnostic named as a plant column was dropped, Ctrl-C at
start-up printed a traceback). Then a property test (hypothesis) of drawn misbehaviours at a drawn call, through the
serial step and the batched step, which must agree. The control step is driven directly (no plant) where it can be.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import scenarios.run
from closedloop.monitor import SafeAction, SafetyMonitor
from closedloop.record import Recorder
from closedloop.step import BatchControlStep, ControlStep
from controllers.model.params import reference_robot
from controllers.registry import PluginLoadError, build_filter
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext, FilterOutput
from scenarios.run import FILTER_FAULT, USAGE_ERROR, UsageError, exit_code, run_scenario
from softcbf_mj.outputs.runio import load_timeseries

REPO = Path(__file__).resolve().parents[1]
ROBOT, SAFE = reference_robot(), paper_safe_set()
CONTEXT = FilterContext.for_robot(ROBOT, SAFE, 1e-3)
LIMIT = 150.0
U_NOM = (120.0, -80.0)  # hPa: the nominal's constant command
DT = 1e-3


def nominal(t, q, qd):
    return np.array(U_NOM)


def benign(estimate, u_nom):
    return FilterOutput(np.clip(u_nom, -100.0, 100.0), "benign", diagnostics={"d": 1.0}, diagnostic_units={"d": "1"})


class BadFloat(float):
    def __float__(self):
        raise RuntimeError("float conversion refused")


class BadInt(int):
    def __float__(self):
        raise RuntimeError("int conversion refused")

    def __lt__(self, other):
        raise RuntimeError("int comparison refused")

    __gt__ = __lt__


class KeysRaise(Mapping):
    """A mapping that is fine while a FilterOutput is built, then whose keys() and items() raise."""

    def __init__(self):
        self.reads = 0

    def __getitem__(self, key):
        return 1.0

    def __iter__(self):
        return iter(["d"])

    def __len__(self):
        return 1

    def keys(self):
        self.reads += 1
        if self.reads > 1:
            raise RuntimeError("keys refused")
        return super().keys()

    def items(self):
        raise RuntimeError("items refused")


class Disagree(Mapping):
    """items() says d = 1.0, the key lookup says "x": the check reads items() once, nothing reads it again."""

    def __getitem__(self, key):
        return "x"

    def __iter__(self):
        return iter(["d"])

    def __len__(self):
        return 1

    def items(self):
        return [("d", 1.0)]


class Unprintable(Exception):
    def __str__(self):
        raise RuntimeError("no message")


class Custom(BaseException):
    pass


class Hostile:
    """The benign filter until call `at`, then `how` (`HOWS`) at that call and every later one."""

    def __init__(self, how: str, at: int) -> None:
        self.how, self.at, self.calls = how, at, 0

    def __call__(self, estimate, u_nom):
        self.calls += 1
        out = benign(estimate, u_nom)
        if self.calls < self.at:
            return out
        how = self.how
        if how in RAISES:
            raise RAISES[how]("hostile")
        if how == "bad_float_u":
            return [BadFloat(1.0), 0.0]
        if how == "bad_float_rho":
            return FilterOutput(out.u, rho_pred=BadFloat(0.5))
        if how == "bad_int_rho":
            return FilterOutput(out.u, rho_pred=BadInt(1))
        if how == "bad_float_diagnostic":
            return FilterOutput(out.u, diagnostics={"d": BadFloat(1.0)}, diagnostic_units={"d": "1"})
        if how == "keys_raise":
            out.diagnostics = KeysRaise()
            return out
        if how == "disagree":
            out.diagnostics = Disagree()
            return out
        if how == "setflags_u_nom":
            u_nom.setflags(write=True)
            u_nom[:] = 149.0
            return u_nom
        if how == "setflags_base":
            u_nom.base.setflags(write=True)
            return u_nom
        if how == "setflags_q":
            estimate.q.setflags(write=True)
            estimate.q[:] = 9.0
            return out
        if how == "nan":
            return np.array([math.nan, 0.0])
        if how == "inf":
            return np.array([math.inf, 0.0])
        if how == "huge":
            return np.array([1e300, -1e300])
        if how == "shape":
            return np.zeros(3)
        if how == "str":
            return "150,150"
        if how == "bad_units":
            return FilterOutput(out.u, diagnostics={"e": 1.0}, diagnostic_units={"e": 5})
        raise AssertionError(how)


RAISES = {"exception": RuntimeError, "system_exit": SystemExit, "generator_exit": GeneratorExit, "custom": Custom,
          "keyboard_interrupt": KeyboardInterrupt, "unprintable": Unprintable}
HOWS = (*RAISES, "bad_float_u", "bad_float_rho", "bad_int_rho", "bad_float_diagnostic", "keys_raise", "disagree",
        "setflags_u_nom", "setflags_base", "setflags_q", "nan", "inf", "huge", "shape", "str", "bad_units")
NOT_FAULTS = ("disagree", "nan", "inf", "huge")  # converted (disagree: items() read once) or refused then held


class HostileNominal:
    """The constant nominal until call `at`, then `how` (`NOMINAL_HOWS`) at that call and every later one."""

    def __init__(self, how: str, at: int) -> None:
        self.how, self.at, self.calls = how, at, 0

    def __call__(self, t, q, qd):
        self.calls += 1
        if self.calls < self.at:
            return np.array(U_NOM)
        how = self.how
        if how in RAISES:
            raise RAISES[how]("hostile nominal")
        if how == "bad_float":
            return [BadFloat(1.0), 0.0]
        if how == "setflags_q":
            q.setflags(write=True)
        if how == "shape":
            return np.zeros(3)
        raise AssertionError(how)


NOMINAL_HOWS = ("exception", "system_exit", "custom", "keyboard_interrupt", "bad_float", "setflags_q", "shape")


def _estimate(k: int) -> Estimate:
    q, qd = np.array([0.01 * k, -0.02]), np.array([0.1, 0.0])
    return Estimate(k * DT, q, qd, k * DT)


def _serial(safety_filter, calls: int = 40, hold_s: float = 0.005, nominal=nominal):
    """Run `calls` control calls of a ControlStep, recording each; (records, recorder columns, fault)."""
    step = ControlStep(safety_filter, nominal, CONTEXT, SafetyMonitor(2, hold_s=hold_s))
    recorder = Recorder(calls, 2, {"t": ()})
    step.reset()
    records = []
    for k in range(calls):
        record = step(_estimate(k))
        recorder.record(k, record, True, [k * DT])
        records.append(record)
        if step.stopped:
            break
    return records, recorder.columns(len(records)), step.fault


def _batched(filters, calls: int = 40, hold_s: float = 0.005, nominals=None):
    """The same calls through a BatchControlStep of one filter (and one nominal) per row; (u (calls, B, N), rows,
    faults, records)."""
    step = BatchControlStep(filters, nominals or [nominal] * len(filters), CONTEXT, len(filters), hold_s)
    step.reset()
    active = np.ones(len(filters), dtype=bool)
    rows, u, records = np.zeros(len(filters), dtype=int), [], []
    for k in range(calls):
        estimates = [_estimate(k)] * len(filters)
        record = step(np.array([e.t for e in estimates]), np.array([e.q for e in estimates]),
                      np.array([e.qd for e in estimates]), rows=active.copy())
        rows[active] += 1
        u.append(record.u.copy())
        records.append(record)
        active &= ~step.stopped
        if not active.any():
            break
    return np.array(u), rows, step.faults, records


# --- D1: a return whose conversion raises is a filter fault, in the serial and the batched step ---------------------


@pytest.mark.parametrize("how", ["bad_float_u", "bad_float_rho", "bad_int_rho", "keys_raise"])
def test_a_return_whose_conversion_raises_is_a_fault_not_an_escape(how):
    records, columns, fault = _serial(Hostile(how, 5))
    assert fault is not None and fault.where == "filter return" and fault.t == 4 * DT, fault
    assert fault.type in ("RuntimeError", "FilterReturnError")
    assert records[-1].action is SafeAction.VENT and np.isfinite(columns["u"]).all()
    np.testing.assert_array_equal(columns["u"][:4], [[100.0, -80.0]] * 4)  # the rows up to the fault are kept


def test_one_rows_conversion_escape_stops_only_that_row_of_the_batch():
    u, rows, faults, _ = _batched([Hostile("bad_float_rho", 5), Hostile("bad_float_rho", 10**6)], calls=30)
    assert faults[0] is not None and faults[0].where == "filter return" and faults[1] is None
    assert rows[0] < 30 and rows[1] == 30
    np.testing.assert_array_equal(u[:, 1], [[100.0, -80.0]] * 30)


VECTOR_FILTER = textwrap.dedent('''
    import numpy as np
    from controllers.contract.safety_filter import FilterOutput

    class BadFloat(float):
        def __float__(self):
            raise RuntimeError("float conversion refused")

    class BadRho:
        """rho_pred a float whose conversion raises once the first bending angle passes 0.05 rad."""
        def __call__(self, estimate, u_nom):
            return FilterOutput(u_nom, rho_pred=BadFloat(1.0) if estimate.q[0] > 0.05 else 1.0)
''')


def test_vector_env_one_arms_conversion_escape_ends_only_its_episode(tmp_path):
    import gymnasium

    from softcbf_mj.env import ENV_ID

    path = tmp_path / "badrho.py"
    path.write_text(VECTOR_FILTER, encoding="utf-8")
    envs = gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", control_rate=100.0,
                              physics_dt=2e-4, links_per_segment=5, filter=f"{path}:BadRho", hold_s=0.05,
                              episode_steps=40)
    envs.reset(seed=0)
    actions = np.array([[150.0, 0.0], [0.0, 0.0]])  # arm 0 bends past 0.05 rad, arm 1 stays straight
    for _ in range(40):
        _, _, terminated, _, info = envs.step(actions)  # raised out of step() before
        if terminated[0]:
            break
    assert terminated[0] and not terminated[1]
    assert info["fault"][0]["where"] == "filter return" and info["fault"][0]["type"] == "RuntimeError"
    assert info["fault"][1] is None


# --- D2: the diagnostics are copied once, at the check; the recorder reads that copy ----------------------------------


def test_the_recorder_reads_the_checks_copy_of_the_diagnostics_not_the_filters_mapping():
    records, columns, fault = _serial(Hostile("disagree", 3), calls=10)
    assert fault is None
    np.testing.assert_array_equal(columns["d"], [1.0] * 10)  # "could not convert string to float" before
    _, _, faults, batch = _batched([Hostile("disagree", 3)], calls=10)
    assert faults[0] is None and batch[5].outputs[0].diagnostics["d"] == 1.0


# --- D3: SystemExit and every other BaseException from user code is a fault; a real Ctrl-C an interrupt --------------


@pytest.mark.parametrize("how", ["system_exit", "generator_exit", "custom", "keyboard_interrupt"])
def test_a_filter_raising_a_base_exception_is_a_fault(how):
    records, columns, fault = _serial(Hostile(how, 5))
    assert fault is not None and fault.where == "filter" and fault.type == RAISES[how].__name__
    assert records[-1].action is SafeAction.VENT and len(records) >= 5
    _, _, faults, _ = _batched([Hostile(how, 5)])
    assert faults[0].to_json() == fault.to_json()


def test_a_nominal_and_a_reset_raising_system_exit_are_faults():
    def leaving(t, q, qd):
        raise SystemExit(0)

    step = ControlStep(benign, leaving, CONTEXT)
    step.reset()
    step(_estimate(0))
    assert step.fault.type == "SystemExit" and step.fault.where == "nominal"

    class ResetExits:
        def __call__(self, estimate, u_nom):
            return u_nom

        def reset(self):
            raise SystemExit(0)

    step = ControlStep(ResetExits(), nominal, CONTEXT)
    step.reset()
    assert step.fault.type == "SystemExit" and step.fault.where == "reset"


@pytest.fixture
def python_sigint():
    """SIGINT at Python's own handler for the test, whatever this process inherited (a test run started in the
    background of a script, `cmd &` or nohup, inherits SIGINT ignored, and then nothing is a Ctrl-C); the handler in
    place before the test, put back after it (the test's `watch()` installs the step's)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_real_ctrl_c_inside_the_filter_still_interrupts_the_run(python_sigint):
    from controllers.core.interrupts import watch

    assert watch()  # the step installs the same handler; pytest runs in the main thread

    def interrupted(estimate, u_nom):
        signal.raise_signal(signal.SIGINT)  # as a Ctrl-C landing while the filter runs
        return u_nom

    step = ControlStep(interrupted, nominal, CONTEXT)
    step.reset()
    with pytest.raises(KeyboardInterrupt):
        step(_estimate(0))
    assert step.fault is None


FACTORIES = textwrap.dedent('''
    import sys

    class ExitsAtBuild:
        def __init__(self):
            sys.exit(0)
        def __call__(self, estimate, u_nom):
            return u_nom

    class ExitsAtCall:
        def __init__(self, at: int = 1):
            self.at, self.calls = at, 0
        def __call__(self, estimate, u_nom):
            self.calls += 1
            if self.calls >= self.at:
                sys.exit(0)
            return u_nom
''')


@pytest.fixture(scope="module")
def plugins(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plugins") / "hostile_faults.py"
    path.write_text(FACTORIES + textwrap.dedent('''
        import os
        import threading
        import numpy as np

        class Chdir:
            """Changes the working folder at its first call."""
            def __init__(self, to: str):
                self.to = to
            def __call__(self, estimate, u_nom):
                os.chdir(self.to)
                return np.clip(u_nom, -100.0, 100.0)

        class Spawner:
            """Starts a non-daemon thread that never ends."""
            def __init__(self):
                threading.Thread(target=threading.Event().wait, name="never-ends").start()
            def __call__(self, estimate, u_nom):
                return u_nom
    '''), encoding="utf-8")
    return path


def test_a_factory_raising_system_exit_is_a_load_error(plugins):
    with pytest.raises(PluginLoadError, match="SystemExit"):
        build_filter(f"{plugins}:ExitsAtBuild", {}, CONTEXT)
    with pytest.raises(PluginLoadError, match="SystemExit"):
        build_filter("sys:exit", {}, CONTEXT)


def _run(tmp_path, spec, *tokens, out=None):
    out = out or tmp_path / "run"
    code = exit_code(lambda: run_scenario("paper_sim", ["--filter", spec, "--duration", "0.05", "--tunings", "None",
                                                        "--progress", "false", *tokens], out))
    return code, Path(out)


def test_a_run_whose_filter_raises_system_exit_ends_on_a_fault_with_its_record(tmp_path, plugins, capsys):
    code, out = _run(tmp_path, f"{plugins}:ExitsAtCall")
    assert code == FILTER_FAULT  # exit 0, no output, no folder before
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fault"]["type"] == "SystemExit" and summary["fault"]["where"] == "filter"
    assert "filter fault in the filter" in capsys.readouterr().err


@pytest.mark.parametrize("spec", ["sys:exit", "ExitsAtBuild"])
def test_a_factory_raising_system_exit_is_exit_2_with_one_line(tmp_path, plugins, capsys, spec):
    code, out = _run(tmp_path, spec if ":" in spec else f"{plugins}:{spec}")
    err = capsys.readouterr().err
    assert code == USAGE_ERROR and "SystemExit" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")  # a real-time hardware loop: one at a time (the suite's addopts)
def test_a_hardware_run_whose_filter_raises_system_exit_keeps_its_cycles_and_vents(tmp_path, plugins):
    from hardware.config import HardwareConfig
    from softcbf.hardware_cli import run_hardware
    from softcbf_mj.emulator.emulate import EmulatedHardware

    config = HardwareConfig.load(REPO / "examples" / "hardware_emulated.toml").with_overrides(
        {"filter": f"{plugins}:ExitsAtCall", "filter_params": {"at": 5}, "duration": 2.0})
    with EmulatedHardware(config) as emulation:
        (tmp_path / "hw").mkdir()
        row = run_hardware(config, tmp_path / "hw", emulation=emulation, report=False)  # SystemExit escaped before
    series, _ = load_timeseries(tmp_path / "hw" / row["timeseries"])
    assert row["fault"]["type"] == "SystemExit" and row["fault"]["where"] == "filter"
    # the cycles before the fault ran; a HOLD there is only the monitor's own (a frame late on a loaded machine: a
    # stale estimate, or a lost link), never the fault's
    before = series["action"][:4]
    assert np.all((before == 0) | ((before == 1) & (series["est_stale"][:4] | series["link_lost"][:4])))
    assert series["action"][-1] == 2 and row["final_vent_acked"]


# --- D7: the run folder is absolute; a filter that changes the working folder keeps the run -------------------------


def test_a_filter_that_changes_the_working_folder_keeps_the_runs_outputs(tmp_path, plugins, monkeypatch):
    work, elsewhere = tmp_path / "work", tmp_path / "elsewhere"
    work.mkdir()
    elsewhere.mkdir()
    monkeypatch.chdir(work)
    code, _ = _run(tmp_path, f"{plugins}:Chdir", "--filter-param", f"to={elsewhere}", out="run")
    assert code == 0
    summary = json.loads((work / "run" / "summary.json").read_text())
    series, _ = load_timeseries(work / "run" / summary["runs"][0]["timeseries"])
    assert len(series["t"]) == 50 and not list(elsewhere.iterdir())


# --- D8: what the filter is handed cannot be made writable; run and batch agree -------------------------------------


@pytest.mark.parametrize("how", ["setflags_u_nom", "setflags_base", "setflags_q"])
def test_setting_the_read_only_flag_back_is_refused_alike_in_run_and_batch(how):
    records, columns, fault = _serial(Hostile(how, 5))
    assert fault is not None and fault.type == "ValueError" and fault.where == "filter"
    np.testing.assert_array_equal(columns["u_nom"][:5], [U_NOM] * 5)  # the filter's 149 hPa recorded as u_nom before
    u, rows, faults, _ = _batched([Hostile(how, 5)])
    assert faults[0].to_json() == fault.to_json() and rows[0] == len(records)
    np.testing.assert_array_equal(u[: rows[0], 0], columns["u"])


# --- the command line's error boundary ------------------------------------------------------------------------------


def test_a_bug_in_the_testbed_is_a_traceback_and_keeps_the_folder(tmp_path, monkeypatch):
    import scenarios.common

    def broken(*args, **kwargs):
        raise ValueError("a metric went wrong")

    monkeypatch.setattr(scenarios.common, "run_figures", broken)
    with pytest.raises(ValueError, match="a metric went wrong") as info:
        _run(tmp_path, "none")  # exit 2 "error: a metric went wrong", folder deleted, before
    assert (tmp_path / "run").is_dir() and any((tmp_path / "run").iterdir())
    assert any("is kept as it was" in note for note in info.value.__notes__)


def test_a_system_exit_outside_the_step_is_an_error_never_exit_0(tmp_path, monkeypatch):
    import scenarios.common

    def leaving(*args, **kwargs):
        raise SystemExit(0)  # as a filter's `enabled` property would, read outside the control step

    monkeypatch.setattr(scenarios.common, "run_figures", leaving)
    with pytest.raises(RuntimeError, match="SystemExit raised while the scenario ran"):
        _run(tmp_path, "none")
    assert (tmp_path / "run").is_dir()


def test_the_spec_is_built_before_the_run_folder_is_made(tmp_path, monkeypatch):
    made = []
    monkeypatch.setattr(scenarios.run, "prepare_out_dir", lambda *a, **k: made.append(a) or a[0])
    with pytest.raises(UsageError, match="f_max"):
        run_scenario("paper_sim", ["--f-max", "-1"], tmp_path / "run")
    assert made == [] and not (tmp_path / "run").exists()


# --- minor items -------------------------------------------------------------------------------------------------


def _cli(*args: str, **kwargs) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "softcbf.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, **kwargs)


def test_a_filter_left_running_in_a_thread_does_not_keep_the_command_alive(tmp_path, plugins):
    process = _cli("run", "paper_sim", "--filter", f"{plugins}:Spawner", "--duration", "0.05", "--tunings", "None",
                   "--progress", "false", "--out", str(tmp_path / "run"))
    try:
        _, err = process.communicate(timeout=240)  # never ended before
    except subprocess.TimeoutExpired:
        process.kill()
        pytest.fail("softcbf run waited for the filter's thread")
    assert process.returncode == 0, err
    assert "non-daemon thread(s) still running" in err and "never-ends" in err
    assert (tmp_path / "run" / "summary.json").is_file()


SLOW_IMPORT = textwrap.dedent('''
    import sys, time

    class SlowTestbedImport:  # the command line's start-up imports, held for 5 s: a Ctrl-C lands inside them
        def find_spec(self, name, path=None, target=None):
            if name == "softcbf_mj":
                time.sleep(5.0)
            return None

    sys.meta_path.insert(0, SlowTestbedImport())
''')


def test_ctrl_c_at_start_up_is_one_line(tmp_path, python_sigint):
    (tmp_path / "sitecustomize.py").write_text(SLOW_IMPORT, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    # started with a Python handler in place: the command starts with SIGINT's default, as from a terminal
    process = subprocess.Popen([sys.executable, "-m", "softcbf.cli", "list"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, env=env)
    time.sleep(2.0)  # inside the held import (the interpreter's own start-up takes well under that)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert "Traceback" not in err and err.strip() == "interrupted" and process.returncode == 130, err


def test_the_interrupt_tests_pass_in_a_test_run_started_with_sigint_ignored():
    """A test run started in the background of a script inherits SIGINT ignored: the two Ctrl-C tests above failed
    there (watch() installs nothing, and the command they start inherits the ignored signal). They set Python's
    handler for themselves and put back the one they found."""
    def ignore_sigint() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    done = subprocess.run([sys.executable, "-m", "pytest", __file__, "-q", "-n", "0", "-p", "no:cacheprovider", "-k",
                           "real_ctrl_c_inside or ctrl_c_at_start_up"], cwd=REPO, capture_output=True, text=True,
                          timeout=600, preexec_fn=ignore_sigint,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])})
    assert done.returncode == 0 and "2 passed" in done.stdout, done.stdout[-3000:]


def test_a_diagnostic_named_as_a_plant_column_is_kept_beside_it():
    def named(estimate, u_nom):
        return FilterOutput(u_nom, diagnostics={"plate_displacement_m": 7.0}, diagnostic_units={"plate_displacement_m": "m"})

    step = ControlStep(named, nominal, CONTEXT)
    recorder = Recorder(3, 2, {"t": ()})
    step.reset()
    for k in range(3):
        recorder.record(k, step(_estimate(k)), True, [k * DT], extras={"plate_displacement_m": np.array([0.5])})
    columns, units = recorder.columns(), recorder.units()
    np.testing.assert_array_equal(columns["plate_displacement_m"], [[0.5]] * 3)  # the plant's column
    np.testing.assert_array_equal(columns["filter.plate_displacement_m"], [7.0] * 3)  # dropped before
    assert units["filter.plate_displacement_m"] == "m"


# --- the property: drawn misbehaviours at a drawn call, serial and batched alike -------------------------------------


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(who=st.sampled_from(["filter", "nominal"]), data=st.data(), at=st.integers(1, 25))
def test_property_every_misbehaviour_is_the_same_fault_serial_and_batched(who, data, at):
    """A filter (or nominal) misbehaving as drawn from call `at` on: the serial step and row 0 of the batched step give
    the same commands and the same fault; u finite and within the limits; the rows before the fault those of the
    benign filter; the recorded u_nom the nominal's; row 1 of the batch (benign) unaffected."""
    how = data.draw(st.sampled_from(HOWS if who == "filter" else NOMINAL_HOWS), label="how")

    def pair():
        return (Hostile(how, at), nominal) if who == "filter" else (benign, HostileNominal(how, at))

    safety_filter, own_nominal = pair()
    records, columns, fault = _serial(safety_filter, nominal=own_nominal)
    u = columns["u"]
    assert np.isfinite(u).all() and (np.abs(u) <= LIMIT).all(), how
    np.testing.assert_array_equal(u[: at - 1], np.tile([100.0, -80.0], (at - 1, 1)))  # the rows up to the fault are kept
    kept = min(at if who == "filter" else at - 1, len(u))  # the rows whose nominal returned (NaN after a fault)
    np.testing.assert_array_equal(columns["u_nom"][:kept], np.tile(U_NOM, (kept, 1)))  # the nominal's, never the filter's
    assert (fault is None) == (who == "filter" and how in NOT_FAULTS), (how, fault)
    if fault is not None:
        assert fault.t == (at - 1) * DT and fault.where.startswith(who) and records[-1].action is SafeAction.VENT
    safety_filter, own_nominal = pair()
    batch_u, rows, faults, _ = _batched([safety_filter, benign], nominals=[own_nominal, nominal])
    assert rows[0] == len(u) and rows[1] == 40 and faults[1] is None
    np.testing.assert_array_equal(batch_u[: rows[0], 0], u, err_msg=how)
    np.testing.assert_array_equal(batch_u[:, 1], np.tile([100.0, -80.0], (40, 1)))
    assert (faults[0] is None) == (fault is None) and (fault is None or faults[0].to_json() == fault.to_json())
