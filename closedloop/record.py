"""The one recorder of every loop's time series, and the one table of their units.

One row per loop row k (a plant tick, a control period or a hardware cycle), preallocated.
A row holds:
- the loop's own columns (its clock and I/O: the plant's state, the estimate it formed,
  the hardware link's results), declared at construction by key and shape, all keys of
  TIMESERIES_UNITS;
- the control step's columns (`StepRecord` in force at that row): u_nom, u_filter (what the
  filter returned), u (what was sent), rho_pred, infeasible, action (ACTION_CODES) and
  filter_us;
- the filter's diagnostics (`FilterOutput.diagnostics`), one column per key with the
  unit the filter declares in `diagnostic_units` (`units()`); their shapes are fixed by
  the first output of the run (the control step's `OutputCheck` has checked that they
  keep them, stay within `DIAGNOSTIC_FLOATS_MAX` floats and take no loop column's name; an
  output without diagnostics, e.g. a bare array, records NaN in them). A filter returns a plain
  mapping; the step hands the recorder the check's plain copy, flat in the check's layout
  (`controllers.contract.diagnostics.FlatDiagnostics`), which it copies as it is: nothing of the filter's own objects is read here. A diagnostic whose name is also
  one of the plant's extras (which a plant may add at any row, e.g. a solver warning's count)
  keeps the plant's column under that name and is stored as "filter.<name>" (`columns`, `units`).

Rows between control calls (a multi-rate loop passes `called=False`) repeat the step in
force. The filter's columns (u_filter, rho_pred, diagnostics) hold the last output the
filter returned (NaN / False before the first), also on calls where it was not called
(a stale estimate) or raised; `infeasible`, the scalar boolean diagnostics (events such
as the CBF's `recovery`) and `filter_us` are set only on the row of the call that
produced them (False / NaN elsewhere), so their counts are counts of filter calls.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from closedloop.columns import TIMESERIES_UNITS
from closedloop.step import ACTION_CODES, StepRecord
from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
from controllers.contract.safety_filter import FilterOutput



class Recorder:
    """Preallocated time series of `n_steps` rows (module docstring), one float matrix.

    loop_columns: key → shape of the loop's float columns, in the order `record` gets
    their values; loop_flags: keys of the loop's boolean columns, likewise. Booleans and
    the action code are stored as floats and typed back by `columns`.
    """

    def __init__(self, n_steps: int, n_segments: int, loop_columns: Mapping[str, tuple[int, ...]],
                 loop_flags: Sequence[str] = ()) -> None:
        unknown = [key for key in (*loop_columns, *loop_flags) if key not in TIMESERIES_UNITS]
        if unknown:
            raise ValueError(f"loop columns must be keys of TIMESERIES_UNITS, got {unknown}")
        n = n_segments
        self.n_steps, self.n_segments = n_steps, n
        # (key, shape, dtype) in row order: the loop's floats, the loop's flags, the step's columns, then diagnostics
        self._layout: list[tuple[str, tuple[int, ...], type]] = [
            *((key, tuple(shape), float) for key, shape in loop_columns.items()),
            *((key, (), bool) for key in loop_flags),
            ("u_nom", (n,), float), ("u_filter", (n,), float), ("u", (n,), float), ("rho_pred", (), float),
            ("infeasible", (), bool), ("filter_us", (), float), ("action", (), np.int8),
        ]
        self._floats = np.full((n_steps, sum(math.prod(s) for _, s, _ in self._layout)), math.nan)
        self._step: StepRecord | None = None  # the step whose filter values below are in force
        self._u_filter, self._rho_pred, self._infeasible = [math.nan] * n, math.nan, False  # of the output in force
        self._diag_layout: list[tuple[str, tuple[int, ...], bool]] | None = None  # key, shape, bool
        self._diag_units: dict[str, str] = {}
        self._diag_plan: list[tuple[str, tuple[int, ...], bool]] = []  # key, shape, 1-D
        self._flat_layout: DiagnosticLayout | None = None  # FlatDiagnostics of this layout are copied as they are
        self._diag: list = []  # the diagnostics in force, flattened
        self._row_held: list | None = None  # the step's columns on rows without its call
        self._extras: dict[str, np.ndarray] = {}

    @staticmethod
    def bytes_needed(n_steps: int, n_segments: int, loop_columns: Mapping[str, tuple[int, ...]],
                     loop_flags: Sequence[str] = (), diagnostic_floats: int = 0, extra_floats: int = 0) -> int:
        """Peak memory of `n_steps` rows: the float matrix twice (widened once by the filter's
        `diagnostic_floats` columns, and copied again by `columns`) plus `extra_floats` a row."""
        n = n_segments
        width = (sum(math.prod(shape) for shape in loop_columns.values()) + len(loop_flags)
                 + 3 * n + 4 + diagnostic_floats)
        return 8 * n_steps * (2 * width + extra_floats)

    def record(self, k: int, step: StepRecord, called: bool, values: Sequence[float], flags: Sequence[bool] = (),
               extras: Mapping[str, object] | None = None) -> None:
        """Row k: the loop's values (floats, then flags, in their declared order), the step in
        force and whether this row made the call; `extras`: further float columns by key
        (a plant's own signals; the caller declares their units)."""
        if step is not self._step:
            self._take_output(step)
        if called and step.output is not None:  # the row in one pass (the common case: every row of the simulated loop)
            self._floats[k] = [*values, *flags, *step.u_nom.tolist(), *self._u_filter, *step.u.tolist(), self._rho_pred,
                               self._infeasible, step.filter_us, ACTION_CODES[step.action], *self._diag]
        else:
            if self._row_held is None:
                self._row_held = self._held_row(step)
            self._floats[k] = [*values, *flags, *self._row_held]
        if extras:
            for key, value in extras.items():
                if key not in self._extras:
                    self._extras[key] = np.zeros((self.n_steps,) + np.shape(value))
                self._extras[key][k] = value

    def _take_output(self, step: StepRecord) -> None:
        """A new step: its output's values are in force from now on (the last output's when it has none)."""
        self._step, self._row_held = step, None
        output = step.output
        if output is None:
            self._infeasible = False
            return
        u = output.u
        self._u_filter = (u if type(u) is np.ndarray else np.asarray(u, dtype=float)).tolist()
        self._rho_pred, self._infeasible = float(output.rho_pred), bool(output.infeasible)
        diagnostics = output.diagnostics
        if type(diagnostics) is FlatDiagnostics and diagnostics.layout is self._flat_layout:
            self._diag = diagnostics.values
        elif diagnostics:
            if self._diag_layout is None:
                self._add_diagnostics(output)
            self._diag = self._flatten(output)
        elif self._diag_layout is not None:  # an output without diagnostics (a bare array): NaN this row
            self._diag = [math.nan] * len(self._diag)

    def _held_row(self, step: StepRecord) -> list:
        """The step's columns on a row without its call: the output in force, no infeasible, no
        filter time, scalar boolean diagnostics False."""
        diag = list(self._diag)
        if self._diag_layout is not None:
            i = 0
            for _, shape, is_bool in self._diag_layout:
                if not shape and is_bool:
                    diag[i] = False
                i += math.prod(shape)
        return [*step.u_nom.tolist(), *self._u_filter, *step.u.tolist(), self._rho_pred, False, math.nan,
                ACTION_CODES[step.action], *diag]

    def _add_diagnostics(self, output: FilterOutput) -> None:
        """Columns for the filter's diagnostics, NaN on the rows before its first output: those of
        its FlatDiagnostics' layout (the control step's copy), else of the mapping's values."""
        flat = output.diagnostics
        if type(flat) is FlatDiagnostics:
            layout = flat.layout
            self._diag_layout = [(key, shape, key in layout.booleans) for key, shape in layout.shapes.items()]
            self._diag_units = {key: str(layout.units[key]) for key in layout.shapes}
            self._flat_layout = layout
        else:
            self._diag_layout = [(key, np.shape(value), np.asarray(value).dtype == bool) for key, value in flat.items()]
            self._diag_units = {key: str(output.diagnostic_units[key]) for key in flat}
        self._diag_plan = [(key, shape, len(shape) == 1) for key, shape, _ in self._diag_layout]  # key, shape, 1-D
        self._layout += [(key, shape, bool if is_bool else float) for key, shape, is_bool in self._diag_layout]
        size = sum(math.prod(s) for _, s, _ in self._diag_layout)
        self._floats = np.hstack((self._floats, np.full((self.n_steps, size), math.nan)))

    def _flatten(self, output: FilterOutput) -> list:
        """The diagnostics' values on the call's row, flattened in their layout's order."""
        diagnostics = output.diagnostics
        flat: list = []
        for key, shape, vector in self._diag_plan:
            value = diagnostics[key]
            if not shape:
                flat.append(value)
            elif vector and type(value) is np.ndarray and value.shape == shape:
                flat += value.tolist()
            else:
                flat += np.asarray(value, dtype=float).reshape(shape).ravel().tolist()
        return flat

    def _names(self) -> list[str]:
        """The column names of `_layout`'s entries: a diagnostic named as one of the plant's extras
        becomes "filter.<name>" (module docstring; repeated while that is taken too)."""
        taken = {key for key, _, _ in self._layout} | self._extras.keys()
        names = []
        for key, _, _ in self._layout:
            name = key
            if key in self._diag_units and key in self._extras:
                while name in taken:
                    name = f"filter.{name}"
                taken.add(name)
            names.append(name)
        return names

    def units(self) -> dict[str, str]:
        """The units of every column `columns` returns except the extras."""
        return {name: self._diag_units.get(key) or TIMESERIES_UNITS[key]
                for name, (key, _, _) in zip(self._names(), self._layout)}

    def columns(self, n_rows: int | None = None, first_row: int = 0) -> dict[str, np.ndarray]:
        """Rows first_row .. n_rows - 1 (default: from the first to the last) as arrays by key."""
        rows = self.n_steps if n_rows is None else n_rows
        columns, start = {}, 0
        for name, (key, shape, dtype) in zip(self._names(), self._layout):
            size = math.prod(shape)
            block = self._floats[first_row:rows, start : start + size].reshape((rows - first_row,) + shape)
            columns[name] = np.nan_to_num(block, nan=0.0).astype(dtype) if dtype is not float else block.copy()
            start += size
        columns.update({key: value[first_row:rows].copy() for key, value in self._extras.items()})
        return columns


class LiveRows(Protocol):
    """A live view of a run's rows (softcbf_mj.outputs.recording.LiveRun): a loop calls `send` every
    `period_steps` rows with its recorder and the number of rows recorded so far, and once
    at its end with `force=True`; the view decides what to send when."""

    period_steps: int

    def send(self, recorder: Recorder, n_rows: int, force: bool = False) -> None: ...
