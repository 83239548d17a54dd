"""A nominal controller's capabilities are declared, never guessed (controllers.contract.safety_filter: `Capabilities`,
`nominal_capabilities`, the filters' reader with the nominal's kind; controllers.nominal; docs/safety-filter.md).

A shared nominal that declares batched has its `nominal_batch` called once for every row; one that declares
nothing runs per row whatever methods it has (the old sniffing of `nominal_batch` is gone); one that declares what
it lacks, or a filter's capability, is refused at setup in one line (the step, the registry, the command line); the
built-ins declare theirs.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from closedloop.step import BatchControlStep, ControlStep
from controllers.model.params import reference_robot
from controllers.registry import PluginLoadError, build_nominal
from controllers.model.safe_set import paper_safe_set
from controllers.contract.capabilities import MINIMAL, Capabilities, CapabilityError, nominal_capabilities
from controllers.contract.safety_filter import FilterContext
from scenarios.run import USAGE_ERROR, exit_code, run_scenario

CONTEXT = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3)
B = 3


def _filter(estimate, u_nom):
    return u_nom


def _states(b: int = B) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.arange(b) * 0.1, np.full((b, 2), 0.1), np.zeros((b, 2))


class Logged:
    """u_nom = (10 t, -10 t) hPa; logs its calls and its `nominal_batch` calls (their row counts). Declares nothing."""

    def __init__(self) -> None:
        self.calls, self.batches = 0, []

    def __call__(self, t, q, qd):
        self.calls += 1
        return np.array([10.0 * t, -10.0 * t])

    def nominal_batch(self, t, q, qd):
        self.batches.append(len(t))
        return np.stack([10.0 * t, -10.0 * t], axis=1)


class Batched(Logged):
    capabilities = Capabilities(batched=True)


def test_a_nominal_that_declares_nothing_runs_per_row_whatever_methods_it_has():
    shared = Logged()
    assert nominal_capabilities(shared) is MINIMAL
    step = BatchControlStep(_filter, shared, CONTEXT, B)
    step.reset()
    record = step(*_states())
    assert shared.calls == B and shared.batches == []
    np.testing.assert_array_equal(record.u_nom, [[0.0, 0.0], [1.0, -1.0], [2.0, -2.0]])


def test_a_shared_nominal_that_declares_batched_is_one_nominal_batch_call():
    shared = Batched()
    step = BatchControlStep(_filter, shared, CONTEXT, B)
    step.reset()
    record = step(*_states(), rows=np.array([True, False, True]))
    assert shared.calls == 0 and shared.batches == [2]
    np.testing.assert_array_equal(record.u_nom[[0, 2]], [[0.0, 0.0], [2.0, -2.0]])
    per_row = [Batched() for _ in range(B)]  # one per row: each called for its own row
    step = BatchControlStep(_filter, per_row, CONTEXT, B)
    step.reset()
    step(*_states())
    assert [(n.calls, n.batches) for n in per_row] == [(1, [])] * B


class NoBatch:
    capabilities = Capabilities(batched=True)

    def __call__(self, t, q, qd):
        return np.zeros(2)


class Rows(Batched):
    capabilities = Capabilities(batched=True, rows=True)

    def nominal_batch(self, t, q, qd, rows=None):
        return super().nominal_batch(t, q, qd)


class Passthrough(Logged):
    capabilities = Capabilities(passthrough=True)


class NotCapabilities(Logged):
    capabilities = {"batched": True}


@pytest.mark.parametrize("culprit, message", [
    (NoBatch(), r"^NoBatch declares batched=True but has no method nominal_batch\(t, q, qd\)$"),
    (Rows(), "^Rows declares rows=True, which a nominal controller cannot: it may declare batched only$"),
    (Passthrough(), "^Passthrough declares passthrough=True, which a nominal controller cannot"),
    (NotCapabilities(), "^NotCapabilities.capabilities must be a controllers.contract.capabilities.Capabilities, got dict$"),
])
def test_a_nominal_that_declares_what_it_lacks_is_refused_when_the_step_is_built(culprit, message):
    with pytest.raises(CapabilityError, match=message):
        BatchControlStep(_filter, culprit, CONTEXT, B)
    with pytest.raises(CapabilityError, match=message):  # per-row nominals are checked too
        BatchControlStep(_filter, [Logged(), culprit, Logged()], CONTEXT, B)
    with pytest.raises(CapabilityError, match=message):
        ControlStep(_filter, culprit, CONTEXT)


def test_the_built_in_nominals_declare_theirs():
    def declared(spec, **params):
        return nominal_capabilities(build_nominal(spec, params, CONTEXT))

    assert declared("sinusoid") == Capabilities(batched=True)
    assert declared("tip-tracker") == declared("step") == declared("force-target") == MINIMAL


LIAR = textwrap.dedent('''
    import numpy as np
    from controllers.contract.capabilities import Capabilities

    class Lies:
        """Declares batched without nominal_batch."""
        capabilities = Capabilities(batched=True)

        def __call__(self, t, q, qd):
            return np.zeros(2)
''')


@pytest.fixture(scope="module")
def liar(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("nominal_capabilities") / "liar.py"
    path.write_text(LIAR, encoding="utf-8")
    return path


def test_the_registry_refuses_a_nominal_that_lacks_what_it_declares(liar):
    with pytest.raises(PluginLoadError, match=r"^nominal '.*liar.py:Lies': Lies declares batched=True but has no "
                                              r"method nominal_batch\(t, q, qd\)$"):
        build_nominal(f"{liar}:Lies", {}, CONTEXT)


def test_a_run_whose_nominal_lacks_what_it_declares_exits_2_with_one_line(tmp_path, liar, capsys):
    code = exit_code(lambda: run_scenario("paper_sim", ["--progress", "false", "--nominal", f"{liar}:Lies",
                                                        "--duration", "0.05"], tmp_path / "run"))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == USAGE_ERROR and "Traceback" not in "\n".join(err)
    assert err[-1].endswith("Lies declares batched=True but has no method nominal_batch(t, q, qd)"), err
