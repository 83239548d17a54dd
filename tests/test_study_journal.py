"""Search storage (softcbf.study.store: `search_storage`, `optuna_storage`): optuna's journal DIR/optuna.journal beside
SQLite DIR/optuna.db for `study falsify` and `study tune`, the default chosen by the backend, a resume on the kind the
folder holds (a folder with optuna.db resumes on it, as it always did), and a journal whose last line a driver
left incomplete resumes.

The searches: paper_sim, 0.2 s (falsify) or 1 s from the sinusoid's peak (tune, a user's clip filter), over the
sinusoid's amplitude; one local worker.
"""

from __future__ import annotations

import json
from pathlib import Path

import optuna
import pytest

from softcbf.study import Distribution, Study, StudyStore
from softcbf.study.cli import main
from softcbf.study.falsify import falsify
from softcbf.study.store import JOURNAL_FILE, SQLITE_FILE, cut_incomplete_line, optuna_storage, search_storage
from softcbf.study.tune import load_tune, tune
from softcbf_mj.outputs.runio import OutputDirError

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

STUDY = Study("journal", "paper_sim", ("Low",), draws=1, seed=4, fixed={"duration": 0.2},
              vary=(Distribution("amplitude", "uniform", low=20.0, high=150.0),))
STUDY_FILE = """name = "journal"
scenario = "paper_sim"
seed = 4
tunings = ["Low"]
draws = 1
[fixed]
duration = 0.2
[vary.amplitude]
dist = "uniform"
low = 20.0
high = 150.0
"""
SEARCH = dict(sampler="tpe", population=2, baseline=0, workers=1, progress=False)


def journal_trials(folder: Path, name: str) -> list[optuna.trial.FrozenTrial]:
    """The trials of optuna study `name` in the journal of `folder`."""
    return optuna.load_study(study_name=name, storage=optuna_storage(folder, "journal", resume=True)).trials


def test_the_default_storage_is_the_journal_on_dask_sqlite_locally_and_a_resume_takes_the_folders(tmp_path):
    new = tmp_path / "new"
    assert search_storage(new, None, resume=False, on_dask=True) == "journal"
    assert search_storage(new, None, resume=False, on_dask=False) is None  # None: SQLite in the folder
    assert search_storage(new, "sqlite", resume=False, on_dask=True) is None
    assert search_storage(new, "journal", resume=False, on_dask=False) == "journal"
    assert search_storage(new, "postgresql://host/db", resume=False, on_dask=True) == "postgresql://host/db"
    with pytest.raises(ValueError, match="--storage must be journal or sqlite .a file in the folder. or a database URL"):
        search_storage(new, "jounral", resume=False, on_dask=True)
    journal, sqlite, both = tmp_path / "j", tmp_path / "s", tmp_path / "b"
    for folder, names in ((journal, [JOURNAL_FILE]), (sqlite, [SQLITE_FILE]), (both, [JOURNAL_FILE, SQLITE_FILE])):
        folder.mkdir()
        for name in names:
            (folder / name).write_bytes(b"x")
    assert search_storage(journal, None, resume=True, on_dask=False) == "journal"
    assert search_storage(sqlite, None, resume=True, on_dask=True) is None  # an SQLite folder stays SQLite on Dask
    assert search_storage(tmp_path / "none", None, resume=True, on_dask=True) is None  # falsify names what is missing
    with pytest.raises(OutputDirError, match="holds its search in optuna.db, not in the --storage journal file; "
                                             "resume with --storage sqlite"):
        search_storage(sqlite, "journal", resume=True, on_dask=True)
    with pytest.raises(OutputDirError, match="holds its search in optuna.journal.*resume with --storage journal"):
        search_storage(journal, "sqlite", resume=True, on_dask=False)
    with pytest.raises(OutputDirError, match="holds both optuna.journal and optuna.db"):
        search_storage(both, None, resume=True, on_dask=False)


def test_a_resume_without_the_journal_is_one_line_and_writes_nothing(tmp_path):
    with pytest.raises(OutputDirError, match="optuna.journal is missing or empty"):
        optuna_storage(tmp_path, "journal", resume=True)
    assert not (tmp_path / JOURNAL_FILE).exists()


def test_an_incomplete_last_line_is_cut_and_nothing_else(tmp_path):
    path = tmp_path / JOURNAL_FILE
    path.write_bytes(b'{"a":1}\n{"b":2}\n{"op_code": 5, "wor')
    assert cut_incomplete_line(path) == len(b'{"op_code": 5, "wor')
    assert path.read_bytes() == b'{"a":1}\n{"b":2}\n'
    assert cut_incomplete_line(path) == 0 and path.read_bytes() == b'{"a":1}\n{"b":2}\n'
    path.write_bytes(b"x" * 70000)  # no newline at all, longer than one block read backwards
    assert cut_incomplete_line(path) == 70000 and path.read_bytes() == b""


def test_a_journal_falsification_resumes_after_a_driver_left_a_line_incomplete(tmp_path):
    """Without the cut, optuna glued the next operation onto the incomplete line and the resume failed."""
    out = tmp_path / "f"
    first = falsify(STUDY, out, budget=2, storage="journal", **SEARCH)
    assert first["storage"] == JOURNAL_FILE and (out / JOURNAL_FILE).is_file() and not (out / SQLITE_FILE).exists()
    before = StudyStore.open(out / "search").load_rows()
    with open(out / JOURNAL_FILE, "ab") as journal:  # a driver killed (or out of disk) while appending
        journal.write(b'{"op_code": 5, "worker_id": "gone", "tri')
    second = falsify(STUDY, out, budget=4, storage="journal", resume=True, **SEARCH)
    assert second["evaluations"] == 4 and (out / JOURNAL_FILE).read_bytes().endswith(b"\n")
    rows = StudyStore.open(out / "search").load_rows()
    assert [r["sample"] for r in rows] == [0, 1, 2, 3]
    assert rows[:2] == before  # the finished evaluations were not run again (worker, wall time as they were)
    trials = journal_trials(out, second["optuna_study"])
    assert [t.number for t in trials] == [0, 1, 2, 3]
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    assert [t.params["amplitude"] for t in trials] == [r["param.amplitude"] for r in rows]  # one trial per evaluation


def test_an_sqlite_folder_resumes_through_the_command_line_as_it_is(tmp_path, capsys):
    """An SQLite folder (the library's default) resumes through the command line without --storage, on SQLite."""
    out = tmp_path / "f"
    first = falsify(STUDY, out, budget=2, **SEARCH)
    assert first["storage"] == SQLITE_FILE
    study_file = tmp_path / "study.toml"
    study_file.write_text(STUDY_FILE, encoding="utf-8")
    args = ["falsify", str(study_file), "--out", str(out), "--budget", "3", "--sampler", "tpe", "--population", "2",
            "--baseline", "0", "--workers", "1", "--no-progress", "--resume"]
    assert main(args) == 0, capsys.readouterr().err
    assert not (out / JOURNAL_FILE).exists()
    search = optuna.load_study(study_name=first["optuna_study"], storage=f"sqlite:///{out / SQLITE_FILE}")
    assert len(search.trials) == 3 and all(t.state == optuna.trial.TrialState.COMPLETE for t in search.trials)
    assert main([*args, "--storage", "journal"]) == 2
    assert "holds its search in optuna.db, not in the --storage journal file" in capsys.readouterr().err


CLIP = '''
import numpy as np


class Clip:
    """Clips u_nom to +-limit_hPa."""

    def __init__(self, limit_hPa: float = 100.0):
        self.limit = limit_hPa

    def __call__(self, estimate, u_nom):
        return np.clip(u_nom, -self.limit, self.limit)
'''


def test_a_journal_tuning_keeps_its_trials_and_its_inner_searches_in_journals_and_resumes(tmp_path):
    plugin = tmp_path / "clip.py"
    plugin.write_text(CLIP, encoding="utf-8")
    path = tmp_path / "tune.toml"
    path.write_text(f'name = "tiny"\nscenario = "paper_sim"\nseed = 3\nfilter = "{plugin}:Clip"\ntunings = ["clip"]\n'
                    '[fixed]\nduration = 1.0\nt0 = 25.0\n[vary.amplitude]\ndist = "uniform"\nlow = 60.0\nhigh = 150.0\n'
                    '[tune.limit_hPa]\ndist = "uniform"\nlow = 5.0\nhigh = 80.0\n', encoding="utf-8")
    out = tmp_path / "out"
    first = tune(load_tune(path), out, budget=1, inner_budget=2, workers=1, storage="journal", progress=False)
    assert first["storage"] == JOURNAL_FILE and not (out / SQLITE_FILE).exists()
    inner = [p for p in sorted((out / "inner").iterdir())]
    assert all((p / JOURNAL_FILE).is_file() and not (p / SQLITE_FILE).exists() for p in inner) and inner
    second = tune(load_tune(path), out, budget=2, inner_budget=2, workers=1, storage="journal", resume=True,
                  progress=False)
    assert second["evaluations"][:1] == first["evaluations"] and len(second["evaluations"]) == 2
    assert [r["sample"] for r in StudyStore.open(out / "nominal").load_rows()] == [0, 1]
    trials = journal_trials(out, second["optuna_study"])
    assert len(trials) == 2 and all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    stored = json.loads((out / "tune.json").read_text(encoding="utf-8"))
    assert stored["storage"] == JOURNAL_FILE

