"""The plug-in boundary is a trust boundary (docs/safety-filter.md, issue 22): whatever a filter or nominal does,
the control step keeps the limits, the record and the run.

Each defect found in the trust boundary's review has a test here (N1 widening the clip, N2 rewriting the record, N3 a
fault losing the run, N4 broken files giving tracebacks, N10 complex/bool returns, unbounded
diagnostics, the hardware loop's burst after a stall), then property tests (hypothesis) of
random misbehaving filters in the serial and batched loops, and one misbehaviour in each of the
camera loop, the environment and the emulated hardware loop.
"""

from __future__ import annotations

import json
import math
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from closedloop.monitor import SafeAction, SafetyMonitor
from closedloop.step import ControlStep, fault_log_name
from controllers.core.errors import NonFiniteStateError
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot
from controllers.registry import PluginLoadError, build_filter
from controllers.model.safe_set import paper_safe_set
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import BatchOutput, DIAGNOSTIC_FLOATS_MAX, Estimate, FilterContext, FilterOutput
from scenarios.run import FILTER_FAULT, USAGE_ERROR, exit_code, run_scenario
from softcbf_mj.loops.batch_loop import run_batch_closed_loop
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.outputs.metrics import run_figures
from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant
from softcbf_mj.physics.pcc_plant import PCCPlant
from softcbf_mj.outputs.runio import load_timeseries

REPO = Path(__file__).resolve().parents[1]
ROBOT, SAFE = reference_robot(), paper_safe_set()
LIMIT = 150.0
BATCH_FIGURES = ("rho_min_pred", "rho_min_meas", "force_max_N", "t_violation_s", "infeasible_steps", "u_peak_abs_hPa")
PUSH = SinusoidNominal((150.0, 150.0), 0.25, (math.pi / 2, math.pi / 2))  # the full push: the plate within 1 s

HOSTILE = textwrap.dedent('''
    import numpy as np
    from controllers.contract.safety_filter import FilterOutput

    class Widen:  # N1: widens the limits it was told, in place, and asks for 1e6 hPa
        def __init__(self, context):
            context.u_max *= 1e4
        def __call__(self, estimate, u_nom):
            return np.array([1e6, 1e6])

    class WidenLater:  # N1: the same, at its first call
        def __init__(self, context):
            self.context = context
        def __call__(self, estimate, u_nom):
            self.context.u_max[:] = 1e6
            return np.array([1e6, 1e6])

    class Huge:  # asks for 1e6 hPa: clipped
        def __call__(self, estimate, u_nom):
            return np.array([1e6, -1e6])

    class RaiseAt:
        def __init__(self, at: int = 20, kind: str = "RuntimeError"):
            self.at, self.kind, self.calls = at, kind, 0
        def __call__(self, estimate, u_nom):
            self.calls += 1
            if self.calls >= self.at:
                raise {"RuntimeError": RuntimeError, "ValueError": ValueError, "TypeError": TypeError}[self.kind]("boom")
            return np.clip(u_nom, -100.0, 100.0)

    class WriteEstimate:  # N2
        def __call__(self, estimate, u_nom):
            estimate.q[0] = 5392.0
            return u_nom

    class WriteNominal:  # N2
        def __call__(self, estimate, u_nom):
            u_nom *= 3.0
            return u_nom

    class ResetRaises:
        def reset(self):
            raise RuntimeError("cannot reset")
        def __call__(self, estimate, u_nom):
            return u_nom

    class Returns:  # N3, N10: what it returns is set by `what`
        def __init__(self, what: str = "dict"):
            self.what = what
        def __call__(self, estimate, u_nom):
            w = self.what
            if w == "dict":
                return {"u": u_nom}
            if w == "overflow":
                return [10**400, 0]
            if w == "complex":
                return u_nom + 1j
            if w == "bool":
                return np.array([True, False])
            if w == "rho_none":
                return FilterOutput(u_nom, rho_pred=None)
            if w == "rho_array":
                return FilterOutput(u_nom, rho_pred=np.ones(2))
            if w == "nested":
                return FilterOutput(u_nom, diagnostics={"a": {"b": 1.0}}, diagnostic_units={"a": "1"})
            if w == "tuple_key":
                return FilterOutput(u_nom, diagnostics={("a", 1): 1.0}, diagnostic_units={("a", 1): "1"})
            if w == "huge_diagnostics":
                return FilterOutput(u_nom, diagnostics={"big": np.zeros(100_000)}, diagnostic_units={"big": "1"})
            if w == "shape":
                return np.zeros(3)
            raise AssertionError(w)
''')


@pytest.fixture(scope="module")
def hostile(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plugins") / "hostile.py"
    path.write_text(HOSTILE, encoding="utf-8")
    return path


def _run(tmp_path: Path, spec: str, *tokens: str, scenario: str = "paper_sim", duration: float = 1.0) -> tuple[int, Path]:
    out = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
    start = [] if scenario == "paper_sim" else ["--t0", "1"]  # paper_sim's sinusoid has no t0: 150 hPa peak at 1 s
    code = exit_code(lambda: run_scenario(scenario, ["--filter", spec, "--duration", str(duration), "--amplitude", "150",
                                                     "--frequency", "0.25", *start, "--progress", "false",
                                                     *tokens], out))
    return code, out


def _series(out: Path) -> tuple[dict, dict]:
    summary = json.loads((out / "summary.json").read_text())
    series, _ = load_timeseries(out / summary["runs"][0]["timeseries"])
    return summary, series


# --- N1: nothing a filter does widens the limits --------------------------------------------


def test_a_factory_that_widens_the_context_limits_is_refused_at_load(tmp_path, hostile, capsys):
    code, out = _run(tmp_path, f"{hostile}:Widen", "--pressure-limits", "true", duration=0.05)
    err = capsys.readouterr().err
    assert code == USAGE_ERROR and "read-only" in err and f"{hostile}:" in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("scenario", ["paper_sim", "mujoco_contact"])
def test_a_filter_asking_for_1e6_hPa_is_clipped_and_cannot_widen_the_clip(tmp_path, hostile, scenario):
    code, out = _run(tmp_path, f"{hostile}:Huge", "--pressure-limits", "true", scenario=scenario, duration=0.05)
    assert code == 0
    _, series = _series(out)
    assert np.array_equal(series["u"], np.tile([LIMIT, -LIMIT], (len(series["u"]), 1)))
    assert np.all(np.abs(series["u_applied"]) <= LIMIT)
    code, out = _run(tmp_path, f"{hostile}:WidenLater", "--pressure-limits", "true", duration=0.05)
    summary, series = _series(out)
    assert code == FILTER_FAULT and summary["fault"]["message"].endswith("read-only")
    assert np.all(np.abs(series["u"]) <= LIMIT) and np.all(np.abs(series["q"]) < 2.0)


def test_the_context_limits_are_read_only_copies():
    lo, hi = np.array(ROBOT.u_min), np.array(ROBOT.u_max)
    context = FilterContext(ROBOT, SAFE, lo, hi, 1e-3)
    lo[:] = -1e9  # the caller's arrays are not the context's
    assert context.limits == (tuple(ROBOT.u_min), tuple(ROBOT.u_max))
    with pytest.raises(ValueError, match="read-only"):
        context.u_max[0] = 1e6


# --- N2: a filter cannot rewrite the record --------------------------------------------------


@pytest.mark.parametrize("factory", ["WriteEstimate", "WriteNominal"])
def test_a_filter_writing_into_its_inputs_faults_and_leaves_the_record_true(factory, hostile):
    plant = PCCPlant(ROBOT, SAFE)
    context = FilterContext.for_robot(ROBOT, SAFE, plant.control_dt)
    step = ControlStep(build_filter(f"{hostile}:{factory}", {}, context), PUSH, context)
    log, _ = run_closed_loop(plant, step, SAFE, 0.05, np.zeros(2))
    assert step.fault is not None and step.fault.type == "ValueError" and "read-only" in step.fault.message
    assert np.all(log["q"] == 0.0)  # the plant's true state, untouched (the arm starts at rest and straight)
    np.testing.assert_array_equal(log["u_nom"][0], PUSH(0.0, np.zeros(2), np.zeros(2)))
    assert log["action"][0] == 2  # nothing was admitted: it vents at once, and the run ends there
    assert len(log["t"]) == 1


# --- N3: a filter fault keeps the run ---------------------------------------------------------


@pytest.mark.parametrize("kind", ["RuntimeError", "ValueError", "TypeError"])
def test_a_raising_filter_holds_then_vents_and_the_record_up_to_it_is_kept(tmp_path, hostile, capsys, kind):
    code, out = _run(tmp_path, f"{hostile}:RaiseAt", "--filter-param", "at=20", "--filter-param", f"kind={kind}")
    err = capsys.readouterr().err.strip().splitlines()
    summary, series = _series(out)
    assert code == FILTER_FAULT  # not a usage error, even for a ValueError
    assert err[-1].startswith("error: run ") and kind in err[-1] and "Traceback" not in "\n".join(err)
    fault = summary["fault"]
    assert fault["type"] == kind and fault["where"] == "filter" and fault["t_s"] == pytest.approx(0.019)
    assert fault["location"].startswith(str(hostile)) and summary["runs"][0]["fault_type"] == kind
    assert "Traceback" in (out / fault_log_name(summary["runs"][0]["tuning"])).read_text()
    action = series["action"]
    assert np.all(action[:19] == 0) and np.all(action[19:-1] == 1) and action[-1] == 2  # run, hold 0.5 s, vent
    assert len(action) == 19 + 500 + 1 and np.all(series["u"][19:-1] == series["u"][18])
    assert not np.any(series["u"][-1])


def test_the_record_before_a_fault_is_the_benign_run(tmp_path, hostile):
    _, faulty = _run(tmp_path, f"{hostile}:RaiseAt", "--filter-param", "at=300")
    _, benign = _run(tmp_path, f"{hostile}:RaiseAt", "--filter-param", "at=100000")
    faulty, benign = _series(faulty)[1], _series(benign)[1]
    for key in ("t", "q", "qd", "u_nom", "u_filter", "u", "u_applied", "contact_force"):
        np.testing.assert_array_equal(faulty[key][:299], benign[key][:299], err_msg=key)


@pytest.mark.parametrize("what", ["dict", "overflow", "complex", "bool", "rho_none", "rho_array", "nested",
                                  "tuple_key", "huge_diagnostics", "shape"])
def test_every_invalid_return_is_a_filter_fault(what, hostile):
    plant = PCCPlant(ROBOT, SAFE)
    context = FilterContext.for_robot(ROBOT, SAFE, plant.control_dt)
    step = ControlStep(build_filter(f"{hostile}:Returns", {"what": what}, context), PUSH, context)
    log, _ = run_closed_loop(plant, step, SAFE, 0.05, np.zeros(2))
    assert step.fault is not None and step.fault.where == "filter return", step.fault
    assert step.fault.location.startswith(str(hostile))
    assert len(log["t"]) == 1 and log["action"][0] == 2


def test_diagnostics_are_bounded_and_keep_their_layout():
    calls = iter([{"a": 1.0}, {"a": 2.0}, {"a": np.zeros(2)}])
    context = FilterContext.for_robot(ROBOT, SAFE, 1e-3)

    def changing(estimate, u_nom):
        return FilterOutput(u_nom, diagnostics=next(calls), diagnostic_units={"a": "1"})

    step = ControlStep(changing, lambda t, q, qd: np.zeros(2), context)
    for t in (0.0, 0.001):
        assert step(Estimate(t, np.zeros(2), np.zeros(2), t)).action is SafeAction.RUN
    step(Estimate(0.002, np.zeros(2), np.zeros(2), 0.002))
    assert "keep their keys and shapes" in step.fault.message
    assert DIAGNOSTIC_FLOATS_MAX < 100_000


def test_a_reset_that_raises_is_a_fault_before_the_first_command(tmp_path, hostile):
    code, out = _run(tmp_path, f"{hostile}:ResetRaises", duration=0.1)
    summary, series = _series(out)
    assert code == FILTER_FAULT and summary["fault"]["where"] == "reset" and summary["fault"]["t_s"] is None
    assert len(series["t"]) == 1 and series["action"][0] == 2


def test_a_nominal_that_raises_is_a_fault_of_the_nominal():
    context = FilterContext.for_robot(ROBOT, SAFE, 1e-3)

    def nominal(t, q, qd):
        if t > 0.0015:
            raise KeyError("gone")
        return np.ones(2)

    step = ControlStep(lambda e, u: u, nominal, context, SafetyMonitor(2, hold_s=0.002))
    actions = [step(Estimate(t, np.zeros(2), np.zeros(2), t)).action for t in (0.0, 0.001, 0.002, 0.003, 0.004)]
    assert actions == [SafeAction.RUN, SafeAction.RUN, SafeAction.HOLD, SafeAction.HOLD, SafeAction.VENT]
    assert step.fault.where == "nominal" and step.fault.type == "KeyError" and step.stopped


# --- N4: broken filter files are usage errors naming file:line --------------------------------


BROKEN = {
    "syntax.py": ("class F:\n    def __call__(self, e, u)\n        return u\n", "F", {}, "syntax.py:2: SyntaxError"),
    "imports.py": ("import no_such_module_anywhere\nclass F:\n    pass\n", "F", {}, "imports.py:1: ModuleNotFoundError"),
    "factory.py": ("class F:\n    def __init__(self):\n        raise RuntimeError('no')\n", "F", {},
                   "factory.py:3: RuntimeError: no"),
    "required.py": ("class F:\n    def __init__(self, gain: float):\n        self.gain = gain\n", "F", {},
                    "missing required parameter(s) gain"),
    "unknown.py": ("class F:\n    def __init__(self):\n        pass\n", "F", {"gain": "1"}, "unknown parameter(s) gain"),
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_a_broken_filter_file_is_one_line_and_exit_2(tmp_path, capsys, name):
    text, factory, params, expected = BROKEN[name]
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    tokens = [t for k, v in params.items() for t in ("--filter-param", f"{k}={v}")]
    code, out = _run(tmp_path, f"{path}:{factory}", *tokens, duration=0.05)
    err = capsys.readouterr().err.strip()
    assert code == USAGE_ERROR and expected in err and len(err.splitlines()) == 1 and not out.exists(), err


def test_a_non_factory_callable_is_a_load_error():
    with pytest.raises(PluginLoadError):
        build_filter("numpy:array", {}, FilterContext.for_robot(ROBOT, SAFE, 1e-3))


# --- the same faults in the batched loop ---------------------------------------------------------


def test_a_faulty_filter_gives_the_same_commands_and_figures_batched_and_serial(hostile):
    context = FilterContext.for_robot(ROBOT, SAFE, 1e-3)
    q0 = np.array([[0.0, 0.0], [0.1, -0.1], [0.2, 0.1]])
    filters = [build_filter(f"{hostile}:RaiseAt", {"at": at}, context) for at in (50, 10_000, 400)]
    batch = run_batch_closed_loop(PCCBatchPlant(ROBOT, SAFE, 3), filters, PUSH, context, 1.0, q0, record_commands=True)
    for b, at in enumerate((50, 10_000, 400)):
        step = ControlStep(build_filter(f"{hostile}:RaiseAt", {"at": at}, context), PUSH, context)
        log, _ = run_closed_loop(PCCPlant(ROBOT, SAFE), step, SAFE, 1.0, q0[b])
        rows = len(log["t"])
        assert batch.rows[b] == rows
        np.testing.assert_array_equal(batch.commands[:rows, b], log["u"])
        assert np.all(batch.commands[rows:, b] == 0.0)  # a stopped simulation's plant is vented
        assert batch.run(b)["rho_min_meas"] == float(np.min(SAFE.margin_from_force(log["contact_force"])))
        assert (batch.faults[b] is None) == (step.fault is None)
        if step.fault is not None:
            assert batch.run(b)["fault"] == {**step.fault.to_json()}


# --- property tests: random misbehaving filters --------------------------------------------------


MISBEHAVIOURS = ("raise", "nan", "inf", "huge", "shape", "type", "mutate_q", "mutate_u_nom", "complex", "rho_bad",
                 "diagnostics_change", "huge_diagnostics", "slow")


class Misbehaving:
    """Clips u_nom to ±100 hPa (the benign filter) until call `at`, then misbehaves as `how` for `burst` calls."""

    def __init__(self, how: str, at: int, burst: int) -> None:
        self.how, self.at, self.burst, self.calls = how, at, burst, 0

    def __call__(self, estimate, u_nom):
        self.calls += 1
        benign = FilterOutput(np.clip(u_nom, -100.0, 100.0), "benign", diagnostics={"d": 1.0},
                              diagnostic_units={"d": "1"})
        if not self.at <= self.calls < self.at + self.burst:
            return benign
        how = self.how
        if how == "raise":
            raise RuntimeError("misbehaving")
        if how in ("nan", "inf"):
            return np.array([math.nan if how == "nan" else math.inf, 0.0])
        if how == "huge":
            return np.array([1e300, -1e300])
        if how == "shape":
            return np.zeros(5)
        if how == "type":
            return "150,150"
        if how == "mutate_q":
            estimate.q[:] = 9.0
        if how == "mutate_u_nom":
            u_nom[:] = 9.0
        if how == "complex":
            return np.array([1j, 0.0])
        if how == "rho_bad":
            return FilterOutput(benign.u, rho_pred=math.inf)
        if how == "diagnostics_change":
            return FilterOutput(benign.u, diagnostics={"e": 1.0}, diagnostic_units={"e": "1"})
        if how == "huge_diagnostics":
            return FilterOutput(benign.u, diagnostics={"d": np.zeros(100_000)}, diagnostic_units={"d": "1"})
        if how == "slow":
            time.sleep(0.002)
        return benign


def _check_run(log: dict, how: str, at: int, benign: dict) -> None:
    u = log["u"]
    assert np.all(np.isfinite(u)) and np.all(np.abs(u) <= LIMIT), how
    before = at - 1
    for key in ("t", "q", "qd", "u_nom", "u", "contact_force"):
        np.testing.assert_array_equal(log[key][:before], benign[key][:before], err_msg=f"{how}: {key}")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(how=st.sampled_from(MISBEHAVIOURS), at=st.integers(1, 150), burst=st.integers(1, 40))
def test_property_serial_loop_keeps_its_promises(how, at, burst):
    context = FilterContext.for_robot(ROBOT, SAFE, 1e-3)
    runs = {}
    for name, filt in (("benign", Misbehaving(how, 10**9, 0)), ("hostile", Misbehaving(how, at, burst))):
        step = ControlStep(filt, PUSH, context, SafetyMonitor(2, hold_s=0.02))
        runs[name], _ = run_closed_loop(PCCPlant(ROBOT, SAFE), step, SAFE, 0.25, np.zeros(2))
        if name == "hostile":
            faulted = step.fault
    log = runs["hostile"]
    _check_run(log, how, at, runs["benign"])
    fatal = how not in ("nan", "inf", "huge", "slow")  # refused commands are held; huge ones clipped; slow is fine
    assert (faulted is not None) == fatal, (how, faulted)
    if fatal:
        # The fault is at call `at` (for a change of diagnostics at the first call, that layout is the run's and the
        # fault comes with the next benign call); hold 20 ms (20 or 21 rows: t − t_hold in floats), then vent, then
        # the run stops; a fault before anything was admitted vents at once.
        call = burst + 1 if how == "diagnostics_change" and at == 1 else at
        assert log["action"][-1] == 2 and len(log["t"]) in ((1,) if call == 1 else (call + 20, call + 21))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(hows=st.lists(st.sampled_from(MISBEHAVIOURS), min_size=3, max_size=3), at=st.integers(1, 100))
def test_property_batched_loop_is_the_serial_loop_sample_by_sample(hows, at):
    context = FilterContext.for_robot(ROBOT, SAFE, 1e-3)
    q0 = np.zeros((3, 2))
    batch = run_batch_closed_loop(PCCBatchPlant(ROBOT, SAFE, 3), [Misbehaving(h, at, 30) for h in hows], PUSH, context,
                                  0.6, q0, record_commands=True)
    for b, how in enumerate(hows):
        step = ControlStep(Misbehaving(how, at, 30), PUSH, context)
        log, _ = run_closed_loop(PCCPlant(ROBOT, SAFE), step, SAFE, 0.6, q0[b])
        rows = len(log["t"])
        np.testing.assert_array_equal(batch.commands[:rows, b], log["u"], err_msg=how)
        assert batch.rows[b] == rows and (batch.faults[b] is None) == (step.fault is None)


class BatchedMisbehaving:
    """A stateless filter with `filter_batch`: clips u_nom to ±100 hPa, but returns NaN where q_2 < 0 for
    t in [0.01, 0.03) s, 1e300 hPa for t in [0.1, 0.12) s, a 3-vector (a refused return) where the time is
    `bad_shape_at` (s) and raises from `raise_at` (s) on; with `refuse`, it refuses its input
    (NonFiniteStateError, a ControllerInputError) where q_2 < 0 for t in [0.002, 0.008) s: every row of the
    call, where a serial run refuses only that row."""

    capabilities = Capabilities(batched=True)

    def __init__(self, raise_at: float = math.inf, bad_shape_at: float = math.inf, refuse: bool = False) -> None:
        self.raise_at, self.bad_shape_at, self.refuse = raise_at, bad_shape_at, refuse

    def _rows(self, t: np.ndarray, q: np.ndarray, u_nom: np.ndarray) -> np.ndarray:
        if np.any(t >= self.raise_at):
            raise RuntimeError("misbehaving batch")
        if self.refuse and np.any((t >= 0.002) & (t < 0.008) & (q[:, 1] < 0.0)):
            raise NonFiniteStateError("refused: q_2 < 0")
        u = np.clip(u_nom, -100.0, 100.0)
        u[(t >= 0.01) & (t < 0.03) & (q[:, 1] < 0.0), 0] = math.nan
        u[(t >= 0.1) & (t < 0.12)] = 1e300
        return u

    def __call__(self, estimate, u_nom):
        if abs(estimate.t - self.bad_shape_at) < 1e-9:
            return np.zeros(3)
        return self._rows(np.array([estimate.t]), estimate.q[None], u_nom[None])[0]

    def filter_batch(self, batch, u_nom):
        if np.any(np.abs(batch.t - self.bad_shape_at) < 1e-9):
            return BatchOutput(np.zeros((len(batch), 3)), np.array(["user"] * len(batch)), np.zeros(len(batch), bool),
                               np.full(len(batch), math.nan))
        u = self._rows(batch.t, batch.q, u_nom)
        return BatchOutput(u, np.array(["user"] * len(batch)), np.zeros(len(batch), bool), np.full(len(batch), math.nan))


@pytest.mark.parametrize("raise_at, bad_shape_at, refuse", [(math.inf, math.inf, False), (0.3, math.inf, False),
                                                             (math.inf, 0.2, False), (math.inf, math.inf, True)])
def test_filter_batch_faults_and_refusals_are_the_serial_runs_row_by_row(raise_at, bad_shape_at, refuse):
    """One `filter_batch` call for all rows: a NaN row holds only that sample, huge values are clipped in every
    row, a refused input (ControllerInputError) is asked again row by row so that only the rows it refuses hold,
    and an exception or refused return is a fault of every row it was called for; each row is, bit for bit,
    the serial run of the same filter called state by state (commands, figures, fault)."""
    context = FilterContext.for_robot(ROBOT, SAFE, 1e-3)
    q0 = np.array([[0.1, 0.2], [0.1, -0.2], [0.0, -0.3]])
    batch = run_batch_closed_loop(PCCBatchPlant(ROBOT, SAFE, 3), BatchedMisbehaving(raise_at, bad_shape_at, refuse),
                                  PUSH, context, 0.4, q0, record_commands=True)
    for b in range(3):
        step = ControlStep(BatchedMisbehaving(raise_at, bad_shape_at, refuse), PUSH, context)
        log, _ = run_closed_loop(PCCPlant(ROBOT, SAFE), step, SAFE, 0.4, q0[b])
        rows = len(log["t"])
        assert batch.rows[b] == rows
        np.testing.assert_array_equal(batch.commands[:rows, b], log["u"])
        row = run_figures(log, 1e-3, True, 1.0)
        assert {k: batch.run(b)[k] for k in BATCH_FIGURES} == {k: row[k] for k in BATCH_FIGURES}
        assert batch.run(b)["refused_steps"] == int(np.count_nonzero(log["action"]))
        assert (batch.faults[b] is None) == (step.fault is None) == (raise_at == bad_shape_at == math.inf)
        if step.fault is not None:  # the same fault at the same time (a refused return's message names its contract)
            assert (batch.faults[b].type, batch.faults[b].t) == (step.fault.type, step.fault.t)
            assert batch.faults[b].where == ("filter return" if step.fault.where == "filter return" else "filter_batch")
    held = batch.run(1)["refused_steps"], batch.run(0)["refused_steps"]
    assert held[0] > 0 and (raise_at < math.inf or bad_shape_at < math.inf or held[1] == 0)  # q_2 < 0 rows only


# --- the other loops: the camera loop, the environment, the emulated hardware -------------------


@pytest.mark.slow
def test_camera_loop_keeps_the_record_of_a_raising_filter(tmp_path, hostile):
    code, out = _run(tmp_path, f"{hostile}:RaiseAt", "--filter-param", "at=5", "--width", "640", "--height", "360",
                     "--saved-frames-hz", "0",
                     scenario="camera_loop", duration=2.0)
    summary, series = _series(out)
    assert code == FILTER_FAULT and summary["fault"]["type"] == "RuntimeError"
    assert series["action"][-1] == 2 and series["t"][-1] < 1.5 and np.all(np.abs(series["u"]) <= LIMIT)


def test_environment_ends_the_episode_on_a_filter_fault(hostile):
    import gymnasium

    import softcbf_mj.env  # noqa: F401  (registers the environment)

    env = gymnasium.make("softcbf_mj/SoftArm-v1", filter=f"{hostile}:RaiseAt", filter_params={"at": 3}, hold_s=0.02)
    env.reset(seed=0)
    terminated, steps, info = False, 0, {}
    while not terminated and steps < 200:
        _, _, terminated, _, info = env.step(np.array([100.0, 100.0]))
        steps += 1
    env.close()
    assert terminated and info["fault"]["type"] == "RuntimeError" and info["monitor_action"] == "vent"


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")  # a real-time hardware loop: one at a time (the suite's addopts)
def test_hardware_run_whose_filter_raises_at_cycle_20_keeps_19_cycles_and_the_vent(tmp_path, hostile):
    from hardware.config import HardwareConfig
    from softcbf.hardware_cli import run_hardware
    from softcbf_mj.emulator.emulate import EmulatedHardware

    config = HardwareConfig.load(REPO / "examples" / "hardware_emulated.toml").with_overrides(
        {"filter": f"{hostile}:RaiseAt", "filter_params": {"at": 20}, "duration": 5.0})
    with EmulatedHardware(config) as emulation:
        (tmp_path / "hw").mkdir()
        row = run_hardware(config, tmp_path / "hw", emulation=emulation, report=False)
    series, _ = load_timeseries(tmp_path / "hw" / row["timeseries"])
    action = series["action"]
    assert row["fault"]["type"] == "RuntimeError" and row["fault"]["where"] == "filter"
    assert np.all(action[:19] == 0) and action[-1] == 2 and np.all(action[19:-1] == 1)
    assert row["cycles"] == len(action) < 50 and row["final_vent_acked"]
    assert (tmp_path / "hw" / fault_log_name(row["tuning"])).is_file()
    applied_t, applied_u = emulation.board.applied_arrays()
    assert np.all(applied_u[-1] == 0.0)  # the board vented


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")  # a real-time hardware loop: one at a time (the suite's addopts)
def test_hardware_loop_skips_the_cycles_a_stall_missed(tmp_path, tmp_path_factory):
    from hardware.config import HardwareConfig
    from softcbf.hardware_cli import run_hardware
    from softcbf_mj.emulator.emulate import EmulatedHardware

    stall = tmp_path_factory.mktemp("stall") / "stall.py"
    stall.write_text("import time\nclass Stall:\n    def __init__(self):\n        self.calls = 0\n"
                     "    def __call__(self, e, u):\n        self.calls += 1\n        if self.calls == 5:\n"
                     "            time.sleep(0.5)\n        return u\n", encoding="utf-8")
    config = HardwareConfig.load(REPO / "examples" / "hardware_emulated.toml").with_overrides(
        {"filter": f"{stall}:Stall", "duration": 2.0})
    with EmulatedHardware(config) as emulation:
        (tmp_path / "hw").mkdir()
        row = run_hardware(config, tmp_path / "hw", emulation=emulation, report=False)
    series, _ = load_timeseries(tmp_path / "hw" / row["timeseries"])
    assert 4 <= row["cycles_skipped"] <= 8 and row["cycles"] + row["cycles_skipped"] == 20
    # the board's watchdog vents during the stall (0.5 s > its 0.15 s) and says so in its next ACK: the loop counts them
    watchdog = [a for a in emulation.board.applied() if a.reason == "watchdog"]
    assert row["watchdog_vents"] == len(watchdog)
    gaps = np.diff(series["t_clock"])
    assert np.sum(gaps < 0.02) <= 1  # no burst (the old loop fired the missed cycles ~1 ms apart)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(how=st.sampled_from(MISBEHAVIOURS), at=st.integers(1, 20))
def test_property_environment_keeps_its_promises(how, at):
    import gymnasium

    import softcbf_mj.env  # noqa: F401  (registers the environment)

    env = gymnasium.make("softcbf_mj/SoftArm-v1", filter="test_trust_boundary:Misbehaving",
                         filter_params={"how": how, "at": at, "burst": 5}, hold_s=0.01)
    env.reset(seed=0)
    terminated, info = False, {}
    for _ in range(60):
        _, _, terminated, truncated, info = env.step(np.array([150.0, 150.0]))
        u = env.unwrapped.physics.last_record.u
        assert np.all(np.isfinite(u)) and np.all(np.abs(u) <= LIMIT), how
        if terminated or truncated:
            break
    env.close()
    fatal = how not in ("nan", "inf", "huge", "slow")
    assert (info["fault"] is not None) == fatal and (terminated if fatal else True), (how, info)


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")  # a real-time hardware loop: one at a time (the suite's addopts)
def test_hardware_loop_error_keeps_the_cycles_before_it_and_vents(tmp_path, monkeypatch):
    from hardware.config import HardwareConfig
    from hardware.link import ValveBoardLink
    from softcbf.hardware_cli import ERROR_LOG, run_hardware
    from softcbf_mj.emulator.emulate import EmulatedHardware

    original, calls = ValveBoardLink.send_setpoints, []

    def failing(self, u):
        calls.append(1)
        if len(calls) == 10:
            raise OSError("the serial port vanished")
        return original(self, u)

    monkeypatch.setattr(ValveBoardLink, "send_setpoints", failing)
    config = HardwareConfig.load(REPO / "examples" / "hardware_emulated.toml").with_overrides({"duration": 3.0})
    with EmulatedHardware(config) as emulation:
        (tmp_path / "hw").mkdir()
        row = run_hardware(config, tmp_path / "hw", emulation=emulation, report=False)
    assert row["error"] == "OSError: the serial port vanished" and row["cycles"] == 9
    assert "Traceback" in (tmp_path / "hw" / ERROR_LOG).read_text() and row["final_vent_acked"]
