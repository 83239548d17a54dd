"""What a hostile filter can and cannot do, per mode (docs/safety-filter.md#what-a-filter-cannot-do-per-mode).

Each hostile filter below attacks the step from inside: it patches the clip's kernel
(`closedloop.kernels.admit_and_run`), the step's admission (`BatchControlStep.decide`), the step's
limits array (found through `gc`), the verdict (`ForceSafeSet.margin_from_force`, `np.min`),
the context's limits (`object.__setattr__`), the working directory (`os.chdir`), or it raises
SystemExit, starts a non-daemon thread, calls os._exit or hangs. Isolated (closedloop.isolation):
the command sent stays within the limits, the measured ρ is the plant's, the fault is recorded
and the run ends, with no process left behind. In-process: the tests show what is NOT stopped
(in-process mode protects against careless code, not hostile code). Runs are short (≤ 1.5 s of
simulated time at 1 kHz); patches made in this process are undone by monkeypatch.
"""

from __future__ import annotations

import itertools
import json
import multiprocessing
import os
import pickle
import re
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import closedloop.kernels
from closedloop.isolation import IsolatedProcessError, decode, encode, isolate
from closedloop.step import BatchControlStep, ControlStep
from controllers.model.params import reference_robot
from controllers.registry import PluginLoadError, build_filter, build_nominal
from controllers.model.safe_set import ForceSafeSet, paper_safe_set
from controllers.contract.safety_filter import FilterContext
from scenarios.run import FILTER_FAULT, USAGE_ERROR, exit_code, run_scenario
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.physics.pcc_plant import PCCPlant
from softcbf_mj.outputs.runio import load_timeseries

REPO = Path(__file__).resolve().parents[1]
ROBOT, SAFE = reference_robot(), paper_safe_set()
LIMIT = 150.0  # hPa, the reference arm's pressure limits
NOMINAL = ("sinusoid", {"amplitude": 150.0, "frequency": 0.25, "t0": 1.0})  # 150 hPa at t = 0: the plate within 1 s

HOSTILE = textwrap.dedent('''
    import gc, importlib, os, signal, threading, time
    import numpy as np
    from closedloop.step import BatchControlStep
    from controllers.model.safe_set import ForceSafeSet

    HUGE = 1e6

    class PatchKernel:  # the clip's kernel told there are no limits; asks for 1e6 hPa
        def __init__(self, context):
            kernels = importlib.import_module("closedloop.kernels")
            original = kernels.admit_and_run
            def admit_and_run(u, limits, *rest):
                return original(u, np.array([[-np.inf] * u.shape[1], [np.inf] * u.shape[1]]), *rest)
            kernels.admit_and_run = admit_and_run
        def __call__(self, estimate, u_nom):
            return np.full(2, HUGE)

    class PatchDecide:  # the step's admission: 1e6 hPa written into what is sent
        def __init__(self, context):
            original = BatchControlStep.decide
            def decide(self, t, u_filter, rows, flags, sent, admitted, action):
                reasons = original(self, t, u_filter, rows, flags, sent, admitted, action)
                sent[:] = HUGE
                return reasons
            BatchControlStep.decide = decide
        def __call__(self, estimate, u_nom):
            return u_nom

    class GcLimits:  # at its first call: every step's limits array, found through gc, widened
        def __init__(self):
            self.done = False
        def __call__(self, estimate, u_nom):
            if not self.done:
                for obj in gc.get_objects():
                    if type(obj) is BatchControlStep:
                        obj.limits.setflags(write=True)  # an array that owns its data may be made writable again
                        obj.limits[0], obj.limits[1] = -10 * HUGE, 10 * HUGE
                self.done = True
            return np.full(2, HUGE)

    class PatchMargin:  # the verdict: every measured margin reported as 1
        def __init__(self):
            ForceSafeSet.margin_from_force = lambda self, force: np.ones(np.shape(force))
        def __call__(self, estimate, u_nom):
            return u_nom

    class PatchMin:  # the verdict: np.min reports |min|, a violation as a margin
        def __init__(self):
            original = np.min
            np.min = lambda a, *args, **kwargs: np.abs(original(a, *args, **kwargs))
        def __call__(self, estimate, u_nom):
            return u_nom

    class SetattrLimits:  # the frozen context's limits replaced at construction; asks for 1e6 hPa
        def __init__(self, context):
            object.__setattr__(context, "limits", ((-10 * HUGE,) * 2, (10 * HUGE,) * 2))
        def __call__(self, estimate, u_nom):
            return np.full(2, HUGE)

    class Chdir:  # moves the working directory at its first call
        def __init__(self, to: str = "/"):
            self.to = to
        def __call__(self, estimate, u_nom):
            os.chdir(self.to)
            return u_nom

    class Exit:  # raises SystemExit(3) at call `at`
        def __init__(self, at: int = 20):
            self.at, self.calls = at, 0
        def __call__(self, estimate, u_nom):
            self.calls += 1
            if self.calls >= self.at:
                raise SystemExit(3)
            return u_nom

    class HardExit:  # os._exit(3) at call `at`: the process it runs in ends at once
        def __init__(self, at: int = 20):
            self.at, self.calls = at, 0
        def __call__(self, estimate, u_nom):
            self.calls += 1
            if self.calls >= self.at:
                os._exit(3)
            return u_nom

    class Thread:  # a non-daemon thread that outlives the run; its process id written to `pid_file`
        def __init__(self, pid_file: str = "", seconds: float = 60.0):
            threading.Thread(target=time.sleep, args=(seconds,), name="hostile-non-daemon").start()
            if pid_file:
                with open(pid_file, "w") as f:
                    f.write(str(os.getpid()))
        def __call__(self, estimate, u_nom):
            return u_nom

    class Sleep:  # sleeps `seconds` at call `at` (ignoring SIGTERM); its process id written to `pid_file`
        def __init__(self, seconds: float = 1.0, at: int = 1, pid_file: str = "", ignore_term: bool = False):
            self.seconds, self.at, self.calls = seconds, at, 0
            if ignore_term:
                signal.signal(signal.SIGTERM, signal.SIG_IGN)
            if pid_file:
                with open(pid_file, "w") as f:
                    f.write(str(os.getpid()))
        def __call__(self, estimate, u_nom):
            self.calls += 1
            if self.calls == self.at:
                time.sleep(self.seconds)
            return u_nom

    class ExitAtLoad:
        def __init__(self):
            raise SystemExit(4)
''')


@pytest.fixture(scope="module")
def hostile(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plugins") / "hostile.py"
    path.write_text(HOSTILE, encoding="utf-8")
    return path


@pytest.fixture
def undo(monkeypatch):
    """Whatever an in-process filter patches here is put back after the test."""
    monkeypatch.setattr(closedloop.kernels, "admit_and_run", closedloop.kernels.admit_and_run)
    monkeypatch.setattr(BatchControlStep, "decide", BatchControlStep.decide)
    monkeypatch.setattr(ForceSafeSet, "margin_from_force", ForceSafeSet.margin_from_force)
    monkeypatch.setattr(np, "min", np.min)
    monkeypatch.chdir(os.getcwd())
    return monkeypatch


def closed_loop(spec: str, isolated: bool, duration: float = 0.2, limits: bool = True, deadline_s: float = 60.0,
                **params: object) -> tuple[dict, ControlStep]:
    """`spec`'s filter with the 150 hPa push on the paper's PCC plant for `duration` s: its time series and step."""
    plant = PCCPlant(ROBOT, SAFE)
    context = FilterContext.for_robot(ROBOT, SAFE, plant.control_dt, limits)
    if isolated:
        filters, nominals = isolate(context, [(spec, params)], [NOMINAL], deadline_s=deadline_s)
        step = ControlStep(filters[0], nominals[0], context)
    else:
        step = ControlStep(build_filter(spec, params, context), build_nominal(*NOMINAL, context), context)
    log, _ = run_closed_loop(plant, step, SAFE, duration, np.zeros(2))
    return log, step


def alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def gone(pid: int, within_s: float = 5.0) -> bool:
    end = time.monotonic() + within_s
    while alive(pid) and time.monotonic() < end:
        time.sleep(0.05)
    return not alive(pid)


# --- the clip: patched modules, the gc, the context -------------------------------------------------------------------


@pytest.mark.parametrize("factory", ["PatchKernel", "PatchDecide", "GcLimits", "SetattrLimits"])
def test_isolated_the_sent_command_stays_within_the_limits(factory, hostile, undo):
    kernel, decide = closedloop.kernels.admit_and_run, BatchControlStep.decide
    log, step = closed_loop(f"{hostile}:{factory}", isolated=True)
    assert step.fault is None and len(log["t"]) == 200
    assert np.all(np.abs(log["u"]) <= LIMIT) and np.all(np.abs(log["u_applied"]) <= LIMIT)
    assert closedloop.kernels.admit_and_run is kernel and BatchControlStep.decide is decide  # nothing patched here


@pytest.mark.slow
@pytest.mark.parametrize("factory", ["PatchKernel", "PatchDecide", "GcLimits"])
def test_in_process_a_patch_or_the_gc_sends_1e6_hPa(factory, hostile, undo):
    log, step = closed_loop(f"{hostile}:{factory}", isolated=False, duration=0.02)
    assert step.fault is None and np.all(log["u"] == 1e6)  # not stopped: in-process is no boundary for hostile code


# --- the verdict: the measured ρ -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def unfiltered_rho() -> float:
    log, _ = closed_loop("none", isolated=False, duration=1.5, limits=False)
    return min(log["rho_meas"].tolist())


@pytest.mark.slow
@pytest.mark.parametrize("factory", ["PatchMargin", "PatchMin"])
def test_isolated_the_measured_rho_is_the_plants(factory, hostile, undo, unfiltered_rho):
    log, step = closed_loop(f"{hostile}:{factory}", isolated=True, duration=1.5, limits=False)
    assert unfiltered_rho < -1.0  # the push breaks through the plate
    assert step.fault is None and min(log["rho_meas"].tolist()) == unfiltered_rho


@pytest.mark.slow
@pytest.mark.parametrize("factory", ["PatchMargin", "PatchMin"])
def test_in_process_a_patched_verdict_reports_a_violation_as_safe(factory, hostile, undo, unfiltered_rho):
    log, step = closed_loop(f"{hostile}:{factory}", isolated=False, duration=1.5, limits=False)
    assert unfiltered_rho < -1.0 and min(log["rho_meas"].tolist()) > 0.0  # not stopped (builtin min: np's is patched)


# --- faults: SystemExit, os._exit, a hang ---------------------------------------------------------------------------


def test_isolated_system_exit_is_a_recorded_fault(hostile):
    log, step = closed_loop(f"{hostile}:Exit", isolated=True, duration=1.0, at=20)
    fault = step.fault
    assert fault is not None and fault.type == "SystemExit" and fault.message == "3" and fault.where == "filter"
    assert fault.location.startswith(f"{hostile}:") and "raised in the isolated process" in fault.traceback
    assert np.all(log["action"][:19] == 0) and log["action"][-1] == 2 and len(log["t"]) == 19 + 500 + 1


def test_isolated_os_exit_is_a_recorded_fault_and_the_run_ends(hostile):
    log, step = closed_loop(f"{hostile}:HardExit", isolated=True, duration=1.0, at=20)
    fault = step.fault
    assert fault is not None and fault.type == "IsolatedProcessError" and "exit code 3" in fault.message
    assert np.all(log["action"][:19] == 0) and log["action"][-1] == 2 and np.all(np.abs(log["u"]) <= LIMIT)


def test_in_process_os_exit_ends_the_testbed_with_no_record(hostile, tmp_path):
    script = (f"from tests.test_hostile_isolation import closed_loop\n"
              f"closed_loop({str(hostile) + ':HardExit'!r}, isolated=False, at=5)\nprint('after the run')\n")
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 3 and "after the run" not in done.stdout  # not stopped


def test_isolated_a_hang_is_a_fault_after_the_deadline(hostile, tmp_path):
    pid_file = tmp_path / "pid"
    start = time.monotonic()
    log, step = closed_loop(f"{hostile}:Sleep", isolated=True, duration=0.6, deadline_s=0.5, seconds=1e6, at=10,
                            pid_file=str(pid_file), ignore_term=True)
    assert time.monotonic() - start < 60
    fault = step.fault
    assert fault is not None and fault.type == "IsolatedProcessError" and "no answer within 0.5 s" in fault.message
    assert log["action"][-1] == 2 and gone(int(pid_file.read_text()))  # the hung process (SIGTERM ignored) is ended


def test_in_process_a_slow_filter_has_no_deadline(hostile):
    log, step = closed_loop(f"{hostile}:Sleep", isolated=False, duration=0.02, seconds=0.7, at=2)
    assert step.fault is None and np.all(log["action"] == 0)  # waited for, not refused


# --- the process: threads, the working directory, no orphans ------------------------------------------------------------


def test_isolated_a_non_daemon_thread_ends_with_the_run(hostile, tmp_path):
    pid_file = tmp_path / "pid"
    before = set(threading.enumerate())
    log, step = closed_loop(f"{hostile}:Thread", isolated=True, pid_file=str(pid_file))
    pid = int(pid_file.read_text())
    assert step.fault is None and pid != os.getpid() and alive(pid)
    del step  # the run's end: its proxies go, and the isolated process with them
    assert gone(pid) and set(threading.enumerate()) == before


def test_in_process_a_non_daemon_thread_outlives_the_run(hostile):
    _, step = closed_loop(f"{hostile}:Thread", isolated=False, seconds=2.0)
    left = [t for t in threading.enumerate() if t.name == "hostile-non-daemon"]
    assert left and not left[0].daemon and step.fault is None  # not stopped: the interpreter waits for it at exit
    left[0].join()


def test_isolated_chdir_leaves_the_testbeds_working_directory(hostile, tmp_path, undo):
    here = os.getcwd()
    closed_loop(f"{hostile}:Chdir", isolated=True, to=str(tmp_path))
    assert os.getcwd() == here


def test_in_process_chdir_moves_the_testbeds_working_directory(hostile, tmp_path, undo):
    closed_loop(f"{hostile}:Chdir", isolated=False, duration=0.01, to=str(tmp_path))
    assert os.getcwd() == str(tmp_path)  # not stopped: relative paths opened later resolve there


ORPHAN = textwrap.dedent('''
    import os, sys, threading, time
    sys.path.insert(0, {repo!r})
    from tests.test_hostile_isolation import closed_loop
    threading.Thread(target=closed_loop, args=({spec!r}, True), daemon=True,
                     kwargs=dict(duration=1.0, seconds=1e6, at=5, pid_file={pid_file!r}, ignore_term=True)).start()
    while not os.path.exists({pid_file!r}):
        time.sleep(0.05)
    time.sleep({wait})
''')


@pytest.mark.parametrize("how", ["exit", "SIGKILL"])
def test_isolated_no_process_outlives_its_parent(hostile, tmp_path, how):
    """The child hangs in a call and ignores SIGTERM; its parent exits normally, or is killed."""
    pid_file = tmp_path / "pid"
    script = ORPHAN.format(repo=str(REPO), spec=f"{hostile}:Sleep", pid_file=str(pid_file),
                           wait=3 if how == "exit" else 600)
    parent = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO)})
    end = time.monotonic() + 240
    while not pid_file.exists() and time.monotonic() < end:
        time.sleep(0.1)
    time.sleep(1.0)  # the child is in its hung call
    child = int(pid_file.read_text())
    assert alive(child)
    if how == "SIGKILL":
        parent.kill()
    parent.wait(timeout=120)
    assert gone(child, 10.0)


def isolated_nominal_in(queue) -> None:
    """In a daemonic worker (as a Dask worker is): an isolated nominal's first command, into `queue`."""
    _, nominals = isolate(FilterContext.for_robot(ROBOT, SAFE, 1e-3), [("none", {})], [NOMINAL])
    queue.put(nominals[0](0.0, np.zeros(2), np.zeros(2)).tolist())


def test_a_daemonic_worker_can_run_isolated_code():
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    worker = context.Process(target=isolated_nominal_in, args=(queue,), daemon=True)
    worker.start()
    assert queue.get(timeout=240) == [150.0, 150.0]
    worker.join(60)


# --- load-time faults, the wiring: --isolate, isolate = true in studies ---------------------------------------------


def _run(tmp_path: Path, *tokens: str, scenario: str = "paper_sim") -> tuple[int, Path]:
    out = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
    code = exit_code(lambda: run_scenario(scenario, ["--progress", "false", "--isolate", "true", *tokens], out))
    return code, out


@pytest.mark.parametrize("tokens, text", [
    (("--filter", "{hostile}:ExitAtLoad"), "SystemExit: 4"),
    (("--filter", "{hostile}:Exit", "--filter-param", "nope=1"), "unknown parameter(s) nope"),
    (("--filter", "{hostile}:Missing"), "has no callable 'Missing'"),
])
def test_isolated_load_time_faults_exit_2_with_one_line(tmp_path, hostile, capsys, tokens, text):
    code, out = _run(tmp_path, *[t.format(hostile=hostile) for t in tokens], "--duration", "0.05")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == USAGE_ERROR and text in err[-1] and "Traceback" not in "\n".join(err) and not out.exists()


def test_isolated_the_parent_imports_no_user_module(tmp_path, hostile, undo):
    """The spec's check and label run isolated too: a module-level patch never reaches the testbed."""
    module = tmp_path / "patch_at_import.py"
    module.write_text("import importlib\nimportlib.import_module('closedloop.kernels').admit_and_run = None\n"
                      "import numpy as np\nclass Huge:\n    def __call__(self, estimate, u_nom):\n"
                      "        return np.full(2, 1e6)\n", encoding="utf-8")
    code, out = _run(tmp_path, "--filter", f"{module}:Huge", "--duration", "0.05", "--pressure-limits", "true")
    summary = json.loads((out / "summary.json").read_text())
    series, _ = load_timeseries(out / summary["runs"][0]["timeseries"])
    assert code == 0 and closedloop.kernels.admit_and_run is not None
    assert summary["runs"][0]["tuning"] == "Huge" and np.all(np.abs(series["u"]) == LIMIT)


@pytest.mark.parametrize("scenario, extra, fault_s", [
    ("paper_sim", (), "1.0"),
    ("mujoco_contact", ("--t0", "1"), "1.0"),
    ("camera_loop", ("--width", "640", "--height", "360", "--saved-frames-hz", "0"), "2.0"),
])
@pytest.mark.slow
def test_isolate_on_every_scenario_keeps_the_clip_and_records_the_fault(tmp_path, hostile, undo, scenario, extra,
                                                                         fault_s):
    code, out = _run(tmp_path, "--filter", f"{hostile}:PatchKernel", "--pressure-limits", "true", "--duration", "0.3",
                     *extra, scenario=scenario)
    summary = json.loads((out / "summary.json").read_text())
    series, _ = load_timeseries(out / summary["runs"][0]["timeseries"])
    assert code == 0 and summary["params"]["isolate"] is True and np.all(np.abs(series["u"]) <= LIMIT)
    code, out = _run(tmp_path, "--filter", f"{hostile}:Exit", "--filter-param", "at=3", "--duration", fault_s, *extra,
                     scenario=scenario)
    summary = json.loads((out / "summary.json").read_text())
    assert code == FILTER_FAULT and summary["fault"]["type"] == "SystemExit" and summary["fault"]["where"] == "filter"


def test_a_scenario_run_ends_its_isolated_process(tmp_path, hostile):
    pid_file = tmp_path / "pid"
    code, _ = _run(tmp_path, "--filter", f"{hostile}:Thread", "--filter-param", f"pid_file={pid_file}",
                   "--duration", "0.05")
    assert code == 0 and gone(int(pid_file.read_text()))  # its non-daemon thread did not keep it


def test_isolate_true_in_a_run_file_and_its_config_json_replay(tmp_path, hostile, undo):
    from softcbf.cli import main

    config = tmp_path / "run.toml"
    config.write_text(f'scenario = "paper_sim"\nisolate = true\nfilter = "{hostile}:GcLimits"\nduration = 0.05\n'
                      f'pressure_limits = true\nprogress = false\n', encoding="utf-8")
    for source, out in ((config, tmp_path / "first"), (tmp_path / "first" / "config.json", tmp_path / "replay")):
        assert main(["run", "--config", str(source), "--out", str(out)]) == 0
        summary = json.loads((out / "summary.json").read_text())
        series, _ = load_timeseries(out / summary["runs"][0]["timeseries"])
        assert summary["params"]["isolate"] is True and np.all(np.abs(series["u"]) <= LIMIT)


def test_a_study_with_isolate_true_runs_its_batch_isolated(tmp_path, hostile, undo):
    from softcbf.study.definition import Study

    study = Study.from_dict({"name": "hostile", "scenario": "paper_sim", "tunings": ["High"], "isolate": True,
                             "filter": f"{hostile}:GcLimits", "draws": 2,
                             "fixed": {"duration": 0.05, "pressure_limits": True}})
    assert study.fixed["isolate"] is True
    from scenarios.paper_sim import run_paper_batch

    rows = run_paper_batch([{**study.fixed, "seed": s} for s in range(2)])
    assert all(row.get("fault_type") is None and row["u_peak_abs_hPa"] <= LIMIT for row in rows)


# --- the reply format -----------------------------------------------------------------------------------------------


def test_a_reply_is_json_and_float64_buffers_and_anything_else_is_refused():
    header, arrays = decode(encode({"seq": 1, "status": "ok"}, [np.array([1.5, -2.0]), np.array(True)]))
    assert header["seq"] == 1 and arrays[0].tolist() == [1.5, -2.0] and arrays[1].dtype == bool and arrays[1]
    for bad in (b"", pickle.dumps({"status": "ok"}), encode({"seq": 1}, [np.zeros(3)])[:-8],
                encode({"seq": 1}, [np.zeros(3)]) + b"\0" * 8, b"\x05\x00\x00\x00[1,2]"):
        with pytest.raises(ValueError):
            decode(bad)


def test_a_reply_out_of_turn_is_a_fault_and_ends_the_process():
    filters, _ = isolate(FilterContext.for_robot(ROBOT, SAFE, 1e-3), [("none", {})], [NOMINAL])
    host = filters[0].host
    host.conn.send_bytes(pickle.dumps((99, "reset", 0, None)))  # an extra request: its reply comes first
    with pytest.raises(IsolatedProcessError, match="reply 99 to request"):
        host.request(("reset", 0, None))
    assert not host.alive and not alive(host.pid)
    with pytest.raises(IsolatedProcessError):  # every later call: the same fault
        filters[0].reset()


def test_every_statement_per_mode_names_a_hostile_test():
    """docs/safety-filter.md's table "What a filter cannot do, per mode": each row names tests, each one a test of
    a tests/test_hostile_*.py file."""
    text = (REPO / "docs" / "safety-filter.md").read_text(encoding="utf-8")
    lines = text.split("## What a filter cannot do, per mode", 1)[1].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| a filter that"))
    rows = [line for line in itertools.takewhile(lambda line: line.startswith("|"), lines[start + 2:])]
    named = [set(re.findall(r"`(test_\w+)", row.rsplit("|", 2)[1])) for row in rows]
    assert len(rows) >= 10 and all(named)
    hostile = {name for path in (REPO / "tests").glob("test_hostile_*.py")
               for name in re.findall(r"^def (test_\w+)", path.read_text(encoding="utf-8"), flags=re.M)}
    assert set().union(*named) <= hostile
