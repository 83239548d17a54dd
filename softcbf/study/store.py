"""Study folder: the definition, one Parquet part per finished sample, crash-safe and resumable.

Layout of a study folder DIR:

    DIR/study.json                       the study (`Study.to_dict`), its sample count, versions
    DIR/results/sample-0000042.parquet   one row per finished sample (Parquet, one row group)
    DIR/results.parquet                  all rows in sample order (written by `compact`, e.g. by
                                         `report`; a convenience copy, the parts stay the truth)
    DIR/runs/sample-0000042/             the scenario's own outputs, only with keep_runs

Each part is written to a hidden temporary file and renamed, so a crash leaves either a
complete part or none. Damage after the fact (a bad disk, a truncated copy, a flipped bit)
is detected: every part carries in its Parquet key-value metadata `softcbf.row_sha256`,
the SHA-256 of its row as canonical JSON (`row_digest`), and `read_part` decodes the
file, checks that it holds one row whose `sample` is the index in its name and that the
row's digest matches. A part that fails is corrupted (`CorruptPartError`, naming the
file). Resume (`scan`) reads and checks every part (≈ 1 ms each): a sample with a sound
part is done (failed ones too: delete a failed sample's part to run it again), a
sample with a corrupted part is run again and its part replaced. Read the folder with
`load_rows` (a list of dicts in sample order) or `load_table` (a pyarrow Table; parts
whose columns differ, e.g. failed rows without results, are merged with nulls); both
raise `CorruptPartError` for a corrupted part.

Columns (one row per sample):

| column              | type    | meaning                                                          |
|---------------------|---------|------------------------------------------------------------------|
| sample              | int64   | sample index (draw-major: draw · T + tuning position)            |
| draw                | int64   | parameter draw                                                   |
| tuning              | string  | tuning name                                                      |
| scenario_seed       | int64   | the draw's seed for the scenario's own randomness                |
| param.<name>        | per     | the drawn value of every varied parameter, in its own unit       |
| status              | string  | "ok"; "fault": the filter or nominal faulted (its run stopped    |
|                     |         | there, `faulted`); "error": the sample failed outside the filter |
| error               | string  | "" when ok; the fault's one line; the exception and the end of   |
|                     |         | its traceback for an error                                       |
| fault_type, fault_where, fault_message | string | a faulted sample's fault (closedloop.step.FilterFault):  |
|                     |         | exception class, "filter", "nominal", …, first line; else absent |
| <run field>         | per     | every scalar field of the scenario's run row (docs/run-outputs.md: |
|                     |         | rho_min_pred, rho_min_meas, force_max_N [N], t_violation_s [s],  |
|                     |         | infeasible_steps, …, plus the scenario's extras); null on error  |
| sample_wall_s       | float64 | wall time of the whole sample in the worker (s)                  |
| worker              | string  | host:pid that ran it                                             |

A faulted sample's figures cover only the rows up to its fault (a filter that raises at its first
call leaves ρ_min_meas 1.0 over one period): they are no verdict, and every statistic counts the
sample as a violation (`softcbf.study.analysis.violated`). `faulted(row)` also knows a row stored
with status "ok" and a `fault_type` (folders written before the "fault" status).

`WALL_CLOCK_COLUMNS` depend on the machine, not on the study: leave them out when
comparing runs for determinism.

Search storage (`study falsify`, `study tune`: `search_storage`, `optuna_storage`). The driver alone
reads and writes a search's optuna trials (the workers only run samples), in DIR beside the parts:

- "sqlite": DIR/optuna.db (`SQLITE_FILE`), optuna's RDB storage. SQLite serialises writers with
  fcntl() locks, which many network file systems (NFS, some Lustre set-ups) do not honour (the
  SQLite FAQ): there a database can be damaged, e.g. by a resumed driver on another node while the
  first one is still alive. Safe on a machine's own disk, where it stays the default.
- "journal": DIR/optuna.journal (`JOURNAL_FILE`), optuna's journal storage: an append-only log of
  operations, one JSON line each, written under a lock file that a symlink makes (optuna's
  JournalFileSymlinkLock, exclusive on NFS too; a lock left by a killed driver is taken over after
  optuna's 30 s grace period). The default on Dask, where DIR is a shared disk. A line that a driver
  left incomplete (killed or out of disk space while appending) was never applied, since optuna
  skips an unterminated last line; the next append would glue onto it and make the log unreadable,
  so `optuna_storage` cuts it off (under the lock) before the search goes on.
- a database URL (postgresql://…): a server database, never written to the folder.

Default (`search_storage`): on resume the kind the folder holds (DIR/optuna.journal: journal; else
SQLite, so a folder with DIR/optuna.db resumes on it whatever the backend); for a new
search "journal" on Dask (a scheduler: the driver's folder is on a disk shared between machines)
and "sqlite" on the local pool.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Mapping

import pyarrow as pa
import pyarrow.parquet as pq

from softcbf_mj.outputs.runio import OutputDirError, versions, write_json
from softcbf.study.definition import Study

STUDY_FILE = "study.json"
FALSIFY_FILE = "falsify.json"  # a falsification folder's figures (softcbf.study.falsify)
TUNE_FILE = "tune.json"  # a tune folder's figures (softcbf.study.tune)
SQLITE_FILE = "optuna.db"  # a search's optuna trials in SQLite (module docstring: search storage)
JOURNAL_FILE = "optuna.journal"  # a search's optuna trials in optuna's journal (module docstring)
STORAGES = ("journal", "sqlite")  # the storages in the search folder; else a database URL
SERVER_STORAGE = "server database (--storage)"  # how a folder names a URL's storage (never written to it)
RESULTS_DIR = "results"
COMPACT_FILE = "results.parquet"
RUNS_DIR = "runs"
PARAM_PREFIX = "param."
FAULT_STATUS = "fault"  # a sample whose filter or nominal faulted (module docstring)
WALL_CLOCK_COLUMNS = frozenset({"wall_s", "filter_us_median", "filter_us_p99", "realtime_factor", "sample_wall_s", "worker"})
DIGEST_KEY = b"softcbf.row_sha256"
_PART = re.compile(r"sample-(\d+)\.parquet")


class CorruptPartError(ValueError):
    """A stored part cannot be read or does not match its digest; the message names the file."""


def faulted(row: Mapping[str, Any]) -> bool:
    """Whether the sample of `row` ended on a filter fault: status "fault", or a `fault_type` (module docstring)."""
    return row.get("status") == FAULT_STATUS or bool(row.get("fault_type"))


def fault_of(row: Mapping[str, Any]) -> dict[str, str] | None:
    """A faulted row's fault as {type, message, where} (None: the row did not fault)."""
    if not faulted(row):
        return None
    return {"type": row.get("fault_type") or "", "message": row.get("fault_message") or "",
            "where": row.get("fault_where") or ""}


def part_name(index: int) -> str:
    return f"sample-{index:07d}.parquet"


def row_digest(row: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of `row` as canonical JSON (sorted keys; NaN and ±inf as JSON's extensions; a value
    of another type, e.g. the bytes of a damaged string column, by its repr)."""
    return hashlib.sha256(json.dumps(dict(row), sort_keys=True, default=repr).encode("utf-8")).hexdigest()


def read_part(path: Path) -> pa.Table:
    """The one-row table of part `path`, checked (module docstring); CorruptPartError naming the file otherwise."""
    match = _PART.fullmatch(path.name)
    if match is None:
        raise ValueError(f"{path} is not a study part (sample-<index>.parquet)")
    try:
        table = pq.read_table(path)
        problem = None
        if table.num_rows != 1 or "sample" not in table.column_names:
            problem = f"expected one row with a 'sample' column, got {table.num_rows} row(s), columns {table.column_names}"
        elif table.column("sample")[0].as_py() != int(match.group(1)):
            problem = f"its row is sample {table.column('sample')[0].as_py()!r}, its name says {int(match.group(1))}"
        else:
            stored = (table.schema.metadata or {}).get(DIGEST_KEY)
            if stored is not None and stored.decode("ascii", "replace") != row_digest(table.to_pylist()[0]):
                problem = "its row does not match the digest stored with it (the file was altered after it was written)"
    except (pa.ArrowException, OSError, ValueError, UnicodeDecodeError) as exc:
        problem = f"{type(exc).__name__}: {exc}".splitlines()[0]
    if problem is not None:
        raise CorruptPartError(f"study part {path} is corrupted ({problem}); `study run --resume` runs its sample again")
    return table.replace_schema_metadata(None)


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
        root = Path(os.path.abspath(root))  # absolute: a filter that changes the working folder cannot move it
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

    def part_paths(self) -> list[Path]:
        """The stored parts, in sample order."""
        if not self.results.is_dir():
            return []
        indexed = [(int(m.group(1)), m.group(0)) for m in map(_PART.fullmatch, os.listdir(self.results)) if m]
        return [self.results / name for _, name in sorted(indexed)]

    def scan(self) -> tuple[set[int], list[Path]]:
        """(indices of the samples with a sound part — finished, ok or failed —, the corrupted parts)."""
        done, corrupted = set(), []
        for path in self.part_paths():
            try:
                read_part(path)
            except CorruptPartError:
                corrupted.append(path)
            else:
                done.add(int(_PART.fullmatch(path.name).group(1)))
        return done, corrupted

    def write(self, row: Mapping[str, Any]) -> Path:
        """Store one sample's row atomically as results/sample-<index>.parquet, with its digest."""
        path = self.results / part_name(int(row["sample"]))
        fd, tmp = tempfile.mkstemp(dir=self.results, prefix=f".{path.stem}.", suffix=".tmp")
        os.close(fd)
        try:
            table = pa.Table.from_pylist([dict(row)])
            table = table.replace_schema_metadata({DIGEST_KEY: row_digest(table.to_pylist()[0]).encode("ascii")})
            pq.write_table(table, tmp)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    def load_table(self) -> pa.Table:
        """Every stored row, in sample order (empty table when none)."""
        paths = self.part_paths()
        if not paths:
            return pa.table({})
        return pa.concat_tables([read_part(p) for p in paths], promote_options="permissive")

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


def stored_search(root: Path, state_file: str, kind: str, settings: Mapping[str, Any], keys: tuple[str, ...],
                  resume: bool) -> dict[str, Any]:
    """The stored state (`state_file`, JSON) of a search folder to resume, checked against `settings` on `keys`;
    {} for a new or empty folder. `kind` names the search in the messages ("falsification", "tuning"). A folder
    that is not one, holds another search, or is not empty without --resume: OutputDirError, one line."""
    state = root / state_file
    if resume:
        if not state.is_file():
            raise OutputDirError(f"{root} is not a {kind} folder (no {state_file}); drop --resume to start one")
        stored = json.loads(state.read_text(encoding="utf-8"))
        differ = [k for k in keys if stored.get(k) != settings[k]]
        if differ:
            raise OutputDirError(f"{root} holds a {kind} with other {', '.join(differ)} (e.g. {differ[0]} = "
                                 f"{stored.get(differ[0])!r}, now {settings[differ[0]]!r}); --resume needs the same")
        return stored
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        hint = "pass --resume to continue it" if state.is_file() else "choose another --out"
        raise OutputDirError(f"{root} exists and is not empty; {hint}")
    return {}


def search_storage(root: str | Path, storage: str | None, resume: bool, on_dask: bool) -> str | None:
    """The storage a search in folder `root` runs on (module docstring): "journal", None for SQLite in the folder,
    or a database URL. `storage`: "journal", "sqlite", a URL, or None for the default (the folder's own on
    `resume`, else journal `on_dask` and SQLite on the local pool). ValueError for another value, OutputDirError
    when a resume names the kind that the folder does not hold."""
    if storage is not None and storage not in STORAGES and "://" not in storage:
        raise ValueError(f"--storage must be {' or '.join(STORAGES)} (a file in the folder) or a database URL such as "
                         f"postgresql://host/db, got {storage!r}")
    root = Path(root)
    held = [kind for kind, name in zip(STORAGES, (JOURNAL_FILE, SQLITE_FILE)) if (root / name).is_file()]
    if resume:
        if storage is None:
            if len(held) > 1:
                raise OutputDirError(f"{root} holds both {JOURNAL_FILE} and {SQLITE_FILE}; say which one the search "
                                     "is stored in with --storage journal or --storage sqlite")
            storage = held[0] if held else "sqlite"  # none: falsify names what is missing
        elif storage in STORAGES and held and storage not in held:
            raise OutputDirError(f"{root} holds its search in {JOURNAL_FILE if held[0] == 'journal' else SQLITE_FILE}, "
                                 f"not in the --storage {storage} file; resume with --storage {held[0]} (or without "
                                 "--storage)")
    elif storage is None:
        storage = "journal" if on_dask else "sqlite"
    return None if storage == "sqlite" else storage


def storage_name(storage: str | None) -> str:
    """How a search folder names its storage (`search_storage`'s value): its file, or `SERVER_STORAGE` for a URL
    (which is never written to the folder)."""
    if storage is None:
        return SQLITE_FILE
    return JOURNAL_FILE if storage == "journal" else SERVER_STORAGE


def optuna_storage(root: str | Path, storage: str | None, resume: bool) -> Any:
    """What optuna opens for `search_storage`'s value `storage` in folder `root`: the URL of DIR/optuna.db (None),
    a JournalStorage on DIR/optuna.journal ("journal"; on `resume` it must be there: OutputDirError, one line, and
    an incomplete last line is cut off, module docstring), or the URL given."""
    root = Path(root)
    if storage is None:
        return f"sqlite:///{(root / SQLITE_FILE).resolve()}"
    if storage != "journal":
        return storage
    from optuna.storages.journal import JournalFileBackend, JournalFileSymlinkLock, JournalStorage  # +0.45 s: journal only

    path = root / JOURNAL_FILE
    if resume and (not path.is_file() or path.stat().st_size == 0):
        raise OutputDirError(f"{path} is missing or empty (or the search is stored elsewhere: resume with its "
                             "--storage); without it the search's trials are lost: start a new one in another --out")
    lock = JournalFileSymlinkLock(str(path))
    if resume:
        lock.acquire()
        try:
            cut_incomplete_line(path)
        finally:
            lock.release()
    try:
        return JournalStorage(JournalFileBackend(str(path), lock_obj=lock))
    except (ValueError, KeyError, TypeError) as exc:  # a line that is not an optuna operation
        raise OutputDirError(f"{path} is not a readable optuna journal ({type(exc).__name__}: "
                             f"{str(exc).splitlines()[0] if str(exc) else ''}); start a new search in another "
                             "--out") from None


def cut_incomplete_line(path: Path) -> int:
    """Cut off the unterminated last line of the journal `path` (module docstring; the caller holds its lock);
    the bytes cut."""
    size = path.stat().st_size
    with open(path, "rb+") as f:
        end, keep = size, 0
        while end > 0:  # the last newline, read backwards in blocks
            start = max(0, end - 65536)
            f.seek(start)
            block = f.read(end - start)
            if b"\n" in block:
                keep = start + block.rindex(b"\n") + 1
                break
            end = start
        if keep < size:
            f.truncate(keep)
            f.flush()
            os.fsync(f.fileno())
    return size - keep
