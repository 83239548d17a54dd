"""A resumed search draws new candidates: optuna keeps no sampler's random state, so a sampler seeded as at the
start drew again the candidates of the search's first trials (seen in a resumed `study tune`: evaluations 5-8 were
1-4 again). `falsify.make_sampler` seeds a resumed search from (seed, trials so far)."""

from __future__ import annotations

import pytest

from softcbf.study import Distribution, Study, StudyStore
from softcbf.study.falsify import falsify

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")


def test_a_resumed_tpe_falsification_asks_new_candidates(tmp_path):
    study = Study("resume_tpe", "paper_sim", ("Low",), draws=1, seed=4, fixed={"duration": 0.2},
                  vary=(Distribution("amplitude", "uniform", low=20.0, high=150.0),))
    out = tmp_path / "f"
    falsify(study, out, budget=2, sampler="tpe", population=2, initial="random", baseline=0, workers=1,
            progress=False)
    falsify(study, out, budget=4, sampler="tpe", population=2, initial="random", baseline=0, workers=1,
            resume=True, progress=False)
    amplitudes = [r["param.amplitude"] for r in StudyStore.open(out / "search").load_rows()]
    assert len(amplitudes) == 4 and len(set(amplitudes)) == 4, amplitudes
