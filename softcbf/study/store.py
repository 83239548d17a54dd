"""Study folder: the definition, one Parquet part per finished sample, crash-safe and resumable.

Layout of a study folder DIR:

    DIR/study.json                       the study (`Study.to_dict`), its sample count, versions
    DIR/results/sample-0000042.parquet   one row per finished sample (Parquet, one row group)
    DIR/results.parquet                  all rows in sample order (written by `compact`, e.g. by
                                         `report`; a convenience copy, the parts stay the truth)
    DIR/runs/sample-0000042/             the scenario's own outputs, only with keep_runs

Each part is written to a hidden temporary file and renamed, so a crash leaves either a
complete part or none; a Parquet file without its footer cannot arise. Resume reads the
part names: a sample with a part is done (failed ones too: delete a failed sample's part
to run it again). Read the folder with `load_rows` (a list of dicts in sample order) or
`load_table` (a pyarrow Table; parts whose columns differ, e.g. failed rows without
results, are merged with nulls).

Columns (one row per sample):

| column              | type    | meaning                                                          |
|---------------------|---------|------------------------------------------------------------------|
| sample              | int64   | sample index (draw-major: draw · T + tuning position)            |
| draw                | int64   | parameter draw                                                   |
| tuning              | string  | tuning name                                                      |
| scenario_seed       | int64   | the draw's seed for the scenario's own randomness                |
| param.<name>        | per     | the drawn value of every varied parameter, in its own unit       |
| status              | string  | "ok" or "error"                                                  |
| error               | string  | "" when ok; the exception and the end of its traceback otherwise |
| <run field>         | per     | every scalar field of the scenario's run row (docs/run-outputs.md: |
|                     |         | rho_min_pred, rho_min_meas, force_max_N [N], t_violation_s [s],  |
|                     |         | infeasible_steps, …, plus the scenario's extras); null on error  |
| sample_wall_s       | float64 | wall time of the whole sample in the worker (s)                  |
| worker              | string  | host:pid that ran it                                             |

`WALL_CLOCK_COLUMNS` depend on the machine, not on the study: leave them out when
comparing runs for determinism.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Mapping

import pyarrow as pa
import pyarrow.parquet as pq

from softcbf_mj.runio import OutputDirError, versions, write_json
from softcbf.study.definition import Study

STUDY_FILE = "study.json"
RESULTS_DIR = "results"
COMPACT_FILE = "results.parquet"
RUNS_DIR = "runs"
PARAM_PREFIX = "param."
WALL_CLOCK_COLUMNS = frozenset({"wall_s", "filter_us_median", "filter_us_p99", "realtime_factor", "sample_wall_s", "worker"})
_PART = re.compile(r"sample-(\d+)\.parquet")


def part_name(index: int) -> str:
    return f"sample-{index:07d}.parquet"


class StudyStore:
    """The folder of one study: `create` a new one, `open` an existing one (resume, report)."""

    def __init__(self, root: Path, study: Study) -> None:
        self.root = Path(root)
        self.study = study
        self.results = self.root / RESULTS_DIR

    @classmethod
    def create(cls, root: str | Path, study: Study, resume: bool = False) -> "StudyStore":
        """A fresh folder for `study`, or with `resume` the existing folder of the same study.

        An existing non-empty folder is refused without `resume`; with it, the stored study
        must equal `study` (else the rows would mix two studies).
        """
        root = Path(root)
        if root.exists() and not root.is_dir():
            raise OutputDirError(f"{root} exists and is not a folder")
        stored = root / STUDY_FILE
        if resume and stored.is_file():
            store = cls.open(root)
            if store.study.to_dict() != study.to_dict():
                raise OutputDirError(f"{root} holds a different study ({store.study.name!r}); --resume needs the same "
                                     "study file (same seed, draws, distributions, tunings)")
            return store
        if root.is_dir() and any(root.iterdir()):
            hint = "pass --resume to continue it" if stored.is_file() else "choose another --out"
            raise OutputDirError(f"{root} exists and is not empty; {hint}")
        (root / RESULTS_DIR).mkdir(parents=True, exist_ok=True)
        write_json(stored, {"study": study.to_dict(), "n_samples": study.n_samples, "versions": versions()})
        return cls(root, study)

    @classmethod
    def open(cls, root: str | Path) -> "StudyStore":
        root = Path(root)
        path = root / STUDY_FILE
        if not path.is_file():
            raise OutputDirError(f"{root} is not a study folder (no {STUDY_FILE}); run `study run` first")
        data = json.loads(path.read_text(encoding="utf-8"))
        return cls(root, Study.from_dict(data["study"]))

    def done(self) -> set[int]:
        """Indices of the samples that have a part (finished, ok or failed)."""
        if not self.results.is_dir():
            return set()
        return {int(m.group(1)) for m in map(_PART.fullmatch, os.listdir(self.results)) if m}

    def write(self, row: Mapping[str, Any]) -> Path:
        """Store one sample's row atomically as results/sample-<index>.parquet."""
        path = self.results / part_name(int(row["sample"]))
        fd, tmp = tempfile.mkstemp(dir=self.results, prefix=f".{path.stem}.", suffix=".tmp")
        os.close(fd)
        try:
            pq.write_table(pa.Table.from_pylist([dict(row)]), tmp)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    def load_table(self) -> pa.Table:
        """Every stored row, in sample order (empty table when none)."""
        names = sorted(n for n in os.listdir(self.results) if _PART.fullmatch(n)) if self.results.is_dir() else []
        if not names:
            return pa.table({})
        tables = [pq.read_table(self.results / n) for n in names]
        return pa.concat_tables(tables, promote_options="permissive")

    def load_rows(self) -> list[dict[str, Any]]:
        return self.load_table().to_pylist()

    def compact(self) -> Path:
        """Write every row to DIR/results.parquet (one file, sample order) and return its path."""
        path = self.root / COMPACT_FILE
        tmp = self.root / f".{COMPACT_FILE}.tmp"
        pq.write_table(self.load_table(), tmp)
        os.replace(tmp, path)
        return path

    def run_dir(self, index: int) -> Path:
        """Where a kept run's scenario outputs go (keep_runs)."""
        return self.root / RUNS_DIR / Path(part_name(index)).stem
