"""`softcbf study falsify`'s printed summary without a uniform baseline, and its Dask scheduler refused as
`softcbf study run` and `tune` refuse one (softcbf.study.execute.connect_scheduler: one line, within its 5 s).

The screened search is replaced by a canned result (its own tests: tests/test_falsify_screen.py), so the summary
line is checked without running a simulation; the refused scheduler stops the search before its first evaluation.
"""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

import softcbf.study.report
import softcbf.study.screen
from softcbf.cli import main as softcbf_main
from softcbf.study import Distribution, Study
from softcbf.study.falsify import falsify, summary
from softcbf.study.screen import falsify_screened

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

ROOT = Path(__file__).resolve().parents[1]


def box() -> Study:
    return Study(name="box", scenario="mujoco_contact", tunings=("Low",), draws=4, seed=5,
                 fixed={"t0": 25.0, "duration": 0.05, "f_max": 0.16, "assumed_plate_stiffness": 11.16},
                 vary=(Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),))


def free_port() -> int:
    """A local TCP port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_screened_search_prints_that_it_has_no_uniform_baseline(tmp_path, capsys, monkeypatch):
    best = {"value": -0.25, "params": {"plate_stiffness": 12.5}, "tuning": "Low", "evaluation": 3, "fault": None}
    canned = {"best": best, "evaluations": 4, "faulted": 0, "first_violation": 3, "objective": "rho_min_meas",
              "random_baseline": summary([], "rho_min_meas"),
              "screen": {"evaluations": 40, "first_violation": 7}, "confirmed": [{}] * 4, "expensive_evaluations": 5}
    monkeypatch.setattr(softcbf.study.screen, "falsify_screened", lambda *a, **k: canned)
    monkeypatch.setattr(softcbf.study.report, "write_report", lambda out: Path(out) / "report.md")
    study = str(ROOT / "studies" / "paper_low_plate_corner.toml")
    assert softcbf_main(["study", "falsify", study, "--out", str(tmp_path / "f"), "--screen", "pcc_contact",
                         "--no-progress"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("falsify "))
    assert "best None" not in line and "in 0 (" not in line
    assert "; no uniform baseline; folder " in line


@pytest.mark.parametrize("search", [falsify, falsify_screened])
def test_an_unreachable_scheduler_is_refused_in_one_line_naming_it(search, tmp_path):
    address = f"tcp://127.0.0.1:{free_port()}"
    options = {"screen": "pcc_contact"} if search is falsify_screened else {"baseline": 0}
    with pytest.raises(ValueError, match=f"^cannot connect to the Dask scheduler '{address}': "):
        search(box(), tmp_path / "f", budget=4, population=4, scheduler=address, progress=False, **options)
