"""A filter's capabilities are declared, never guessed (controllers.contract.safety_filter: `Capabilities`,
`filter_capabilities`; docs/safety-filter.md#capabilities).

Each capability declared and used by the batched control step (batched, rows, reset_rows) and the reports
(passthrough); a filter that declares nothing runs per row whatever methods it has (the old sniffing of
`filter_batch`, of a `rows` keyword and of `enabled` is gone); a filter that declares what it lacks is refused at
setup in one line (the step, the registry, the isolated process, the command line); the built-ins declare theirs.
"""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

from closedloop.isolation import IsolatedBatchFilter, isolate
from closedloop.step import BatchControlStep, ControlStep
from controllers.model.params import reference_robot
from controllers.registry import PluginLoadError, build_filter
from controllers.model.safe_set import paper_safe_set
from controllers.contract.capabilities import MINIMAL, Capabilities, CapabilityError, filter_capabilities
from controllers.contract.safety_filter import BatchOutput, FilterContext
from scenarios.common import filter_enabled
from scenarios.run import USAGE_ERROR, exit_code, run_scenario

CONTEXT = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3)
B = 3
DOCS = Path(__file__).resolve().parents[1] / "docs"


def _nominal(t, q, qd):
    return np.array([50.0, -50.0])


def _states(b: int = B) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros(b), np.full((b, 2), 0.1), np.zeros((b, 2))


class Logged:
    """Passes u_nom through and logs what it is asked: calls (`__call__`), batches (`filter_batch`'s rows
    argument, None when not given) and resets (`reset`'s rows, None when not given). Declares nothing."""

    def __init__(self) -> None:
        self.calls, self.batches, self.resets = 0, [], []

    def __call__(self, estimate, u_nom):
        self.calls += 1
        return u_nom

    def filter_batch(self, estimates, u_nom, rows=None):
        self.batches.append(None if rows is None else list(rows))
        n = len(estimates)
        return BatchOutput(np.array(u_nom), np.array(["batch"] * n), np.zeros(n, dtype=bool), np.full(n, np.nan))

    def reset(self, rows=None):
        self.resets.append(None if rows is None else list(rows))


class Batched(Logged):
    capabilities = Capabilities(batched=True)


class BatchedRows(Logged):
    capabilities = Capabilities(batched=True, rows=True)


class ResetRows(Logged):
    capabilities = Capabilities(batched=True, reset_rows=True)


class PassThrough(Logged):
    capabilities = Capabilities(passthrough=True)


def test_a_filter_that_declares_nothing_runs_per_row_whatever_methods_it_has():
    """filter_batch(rows=), reset(rows=) and `enabled` present, nothing declared: the minimal contract."""
    shared = Logged()
    shared.enabled = False  # once read as "passes u_nom through"
    assert filter_capabilities(shared) is MINIMAL
    step = BatchControlStep(shared, _nominal, CONTEXT, B)
    step.reset()
    step(*_states())
    step.reset(np.array([True, False, False]))  # shared, no reset_rows: not reset while rows 1 and 2 go on
    assert shared.calls == B and shared.batches == [] and shared.resets == [None]
    assert filter_enabled(ControlStep(shared, _nominal, CONTEXT))


def test_batched_is_one_filter_batch_call_without_rows():
    shared = Batched()
    step = BatchControlStep(shared, _nominal, CONTEXT, B)
    step.reset()
    record = step(*_states())
    assert shared.calls == 0 and shared.batches == [None] and record.filter_action == ["batch"] * B
    step.reset(np.array([False, True, False]))  # no reset_rows: not reset while rows 0 and 2 go on
    assert shared.resets == [None]


def test_rows_tells_filter_batch_the_rows_it_serves():
    shared = BatchedRows()
    step = BatchControlStep(shared, _nominal, CONTEXT, B)
    step.reset()
    step(*_states())
    step(*_states(), rows=np.array([True, False, True]))
    assert shared.batches == [[0, 1, 2], [0, 2]]


def test_reset_rows_restarts_only_the_rows_that_restart():
    shared = ResetRows()
    step = BatchControlStep(shared, _nominal, CONTEXT, B)
    step.reset()
    step.reset(np.array([False, True, True]))
    assert shared.resets == [None, [1, 2]]


@pytest.mark.parametrize("kind", [Logged, Batched, BatchedRows])
def test_a_shared_filter_without_reset_rows_is_reset_only_when_every_row_restarts(kind):
    """A reset() would restart the rows that go on in the middle of their runs (closedloop.step.BatchControlStep.reset):
    a partial restart leaves such a filter alone, a restart of every row (given as rows, or None) resets it once."""
    shared = kind()
    step = BatchControlStep(shared, _nominal, CONTEXT, B)
    step.reset(np.array([True, True, False]))
    step.reset(np.array([False, False, True]))
    assert shared.resets == []
    step.reset(np.ones(B, dtype=bool))
    step.reset()
    assert shared.resets == [None, None]
    per_row = [kind() for _ in range(B)]  # each row's own filter: reset with its row
    step = BatchControlStep(per_row, [_nominal] * B, CONTEXT, B)
    step.reset(np.array([False, True, False]))
    assert [f.resets for f in per_row] == [[], [None], []]


def test_passthrough_reports_no_filter_times():
    assert not filter_enabled(ControlStep(PassThrough(), _nominal, CONTEXT))
    assert filter_enabled(ControlStep(Logged(), _nominal, CONTEXT))


class NoBatch:
    capabilities = Capabilities(batched=True)

    def __call__(self, estimate, u_nom):
        return u_nom


class NoRowsKeyword(Logged):
    capabilities = Capabilities(batched=True, rows=True)

    def filter_batch(self, estimates, u_nom):
        return super().filter_batch(estimates, u_nom)


class NoResetRows:
    capabilities = Capabilities(reset_rows=True)

    def __call__(self, estimate, u_nom):
        return u_nom

    def reset(self):
        pass


class NotCapabilities(Logged):
    capabilities = {"batched": True}


@pytest.mark.parametrize("culprit, message", [
    (NoBatch(), "NoBatch declares batched=True but has no method filter_batch"),
    (NoRowsKeyword(), "NoRowsKeyword declares rows=True but its filter_batch takes no keyword rows"),
    (NoResetRows(), r"NoResetRows declares reset_rows=True but has no method reset\(rows=...\)"),
    (NotCapabilities(), "NotCapabilities.capabilities must be a controllers.contract.capabilities.Capabilities, got dict"),
])
def test_a_declared_capability_the_filter_lacks_is_refused_when_the_step_is_built(culprit, message):
    with pytest.raises(CapabilityError, match=message):
        BatchControlStep(culprit, _nominal, CONTEXT, B)
    with pytest.raises(CapabilityError, match=message):  # per-row filters are checked too
        BatchControlStep([Logged(), culprit, Logged()], [_nominal] * B, CONTEXT, B)
    with pytest.raises(CapabilityError, match=message):
        ControlStep(culprit, _nominal, CONTEXT)


def test_capabilities_are_checked_at_construction():
    with pytest.raises(CapabilityError, match="Capabilities.batched must be True or False, got 1"):
        Capabilities(batched=1)
    with pytest.raises(CapabilityError, match=r"Capabilities\(rows=True\) needs batched=True"):
        Capabilities(rows=True)


def test_the_built_ins_declare_theirs():
    def declared(spec, **params):
        return filter_capabilities(build_filter(spec, params, CONTEXT))

    history = Capabilities(batched=True, rows=True, reset_rows=True)
    assert declared("paper-cbf") == Capabilities(batched=True)
    assert declared("paper-cbf", tuning="None") == Capabilities(batched=True, passthrough=True)
    assert declared("qsg") == declared("e-erg") == declared("c-erg") == history
    assert declared("ecbf") == declared("sdcbf") == declared("isscbf") == declared("backup-cbf") == MINIMAL
    assert declared("none") == MINIMAL


LIARS = textwrap.dedent('''
    import numpy as np
    from controllers.contract.capabilities import Capabilities
    from controllers.contract.safety_filter import BatchOutput

    class Lies:
        """Declares batched without filter_batch."""
        capabilities = Capabilities(batched=True)

        def __call__(self, estimate, u_nom):
            return u_nom

    class Undeclared:
        """Has filter_batch, declares nothing."""
        def __call__(self, estimate, u_nom):
            return u_nom

        def filter_batch(self, estimates, u_nom):
            raise AssertionError("never called: not declared")

    class Declared(Undeclared):
        capabilities = Capabilities(batched=True, rows=True)

        def filter_batch(self, estimates, u_nom, rows=None):
            n = len(estimates)
            return BatchOutput(np.array(u_nom), np.array(["batch"] * n), np.zeros(n, dtype=bool), np.full(n, np.nan))
''')


@pytest.fixture(scope="module")
def liars(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("capabilities") / "liars.py"
    path.write_text(LIARS, encoding="utf-8")
    return path


def test_the_registry_refuses_a_filter_that_lacks_what_it_declares(liars):
    with pytest.raises(PluginLoadError, match=r"^filter '.*liars.py:Lies': Lies declares batched=True but has no "
                                              r"method filter_batch\(estimates, u_nom\)$"):
        build_filter(f"{liars}:Lies", {}, CONTEXT)


def test_an_isolated_filter_declares_what_its_hosted_filter_declares(liars):
    (undeclared, declared), _ = isolate(CONTEXT, [(f"{liars}:Undeclared", {}), (f"{liars}:Declared", {})], [])
    assert filter_capabilities(undeclared) == MINIMAL and not isinstance(undeclared, IsolatedBatchFilter)
    assert filter_capabilities(declared) == Capabilities(batched=True, rows=True)
    step = BatchControlStep(undeclared, _nominal, CONTEXT, B)  # per row: its filter_batch is never called
    step.reset()
    assert step(*_states()).filter_action == ["user"] * B and not step.faulted.any()
    step = BatchControlStep(declared, _nominal, CONTEXT, B)
    step.reset()
    assert step(*_states(), rows=np.array([True, False, True])).filter_action == ["batch", None, "batch"]
    with pytest.raises(PluginLoadError, match="Lies declares batched=True but has no method filter_batch"):
        isolate(CONTEXT, [(f"{liars}:Lies", {})], [])


@pytest.mark.parametrize("isolated", ["false", "true"])
def test_a_run_whose_filter_lacks_what_it_declares_exits_2_with_one_line(tmp_path, liars, capsys, isolated):
    code = exit_code(lambda: run_scenario("paper_sim", ["--progress", "false", "--isolate", isolated, "--filter",
                                                        f"{liars}:Lies", "--duration", "0.05"], tmp_path / "run"))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == USAGE_ERROR and "Traceback" not in "\n".join(err)
    assert err[-1].endswith("Lies declares batched=True but has no method filter_batch(estimates, u_nom)"), err


def test_the_docs_batched_example_is_called_once_for_all_rows():
    """docs/safety-filter.md#capabilities: the example declares batched and runs as one filter_batch call."""
    block, = re.findall(r"<!-- run: capabilities -->\n```python\n(.*?)```", (DOCS / "safety-filter.md").read_text(
        encoding="utf-8"), re.S)
    namespace: dict = {}
    exec(compile(block, "safety-filter.md", "exec"), namespace)  # noqa: S102 - the page's own example
    example = namespace["BatchedClip"]()
    calls = []
    batch = example.filter_batch
    example.filter_batch = lambda estimates, u_nom: calls.append(len(estimates)) or batch(estimates, u_nom)
    step = BatchControlStep(example, lambda t, q, qd: np.array([150.0, -20.0]), CONTEXT, B)
    step.reset()
    record = step(*_states())
    assert calls == [B] and record.u_filter.tolist() == [[100.0, -20.0]] * B
