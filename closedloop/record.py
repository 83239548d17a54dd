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
  the first output of the run.

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

import numpy as np

from closedloop.step import ACTION_CODES, StepRecord
from controllers.safety_filter import FilterOutput

TIMESERIES_UNITS = {
    "t": "s (the loop's control time: simulated, or since the hardware run started)",
    "q": "rad (true)",
    "qd": "rad/s (true)",
    "q_est": "rad",
    "qd_est": "rad/s",
    "tip": "m (true)",
    "segment_ends": "m (true)",
    "u_nom": "hPa",
    "u_filter": "hPa (the filter's return, before clipping)",
    "u": "hPa (the command sent: clipped, or the safety monitor's hold / vent)",
    "u_applied": "hPa (at the plant's valves)",
    "contact_force": "N (measured)",
    "rho_pred": "1 (the filter's predicted margin; NaN: no prediction)",
    "rho_meas": "1 (from the measured contact force)",
    "infeasible": "bool (the filter said so, on its call's row)",
    "action": "0 run, 1 hold, 2 vent (the safety monitor)",
    "filter_us": "us (the filter call's wall time; NaN on rows without a call)",
    "t_clock": "s (monotonic clock)",
    "est_age_s": "s (t - t_capture of the estimate)",
    "est_stale": "bool",
    "u_sent": "hPa (what the link sent)",
    "u_measured": "hPa (the board's measured pressure)",
    "link_acked": "bool",
    "link_latency_s": "s",
    "link_lost": "bool",
    "late_s": "s (cycle start after its scheduled time)",
}
STEP_COLUMNS = ("u_nom", "u_filter", "u", "rho_pred", "filter_us", "action")  # float columns of the step, in row order


class Recorder:
    """Preallocated time series of `n_steps` rows (module docstring).

    loop_columns: key → shape of the loop's float columns, in the order `record` gets
    their values; loop_flags: keys of the loop's boolean columns, likewise.
    """

    def __init__(self, n_steps: int, n_segments: int, loop_columns: Mapping[str, tuple[int, ...]],
                 loop_flags: Sequence[str] = ()) -> None:
        unknown = [key for key in (*loop_columns, *loop_flags) if key not in TIMESERIES_UNITS]
        if unknown:
            raise ValueError(f"loop columns must be keys of TIMESERIES_UNITS, got {unknown}")
        n = n_segments
        self.n_steps, self.n_segments = n_steps, n
        self._float_shapes = dict(loop_columns)
        self._float_shapes.update({"u_nom": (n,), "u_filter": (n,), "u": (n,), "rho_pred": (), "filter_us": (), "action": ()})
        self._flag_keys = (*loop_flags, "infeasible")
        self._floats = np.full((n_steps, sum(math.prod(s) for s in self._float_shapes.values())), math.nan)
        self._flags = np.zeros((n_steps, len(self._flag_keys)), dtype=bool)
        self._nan_n = [math.nan] * n
        self._held_filter = [*self._nan_n, math.nan]  # u_filter, rho_pred of the output in force
        self._diag_layout: list[tuple[str, tuple[int, ...], bool]] | None = None  # key, shape, bool
        self._diag_units: dict[str, str] = {}
        self._diag: np.ndarray | None = None
        self._diag_called: list = []
        self._diag_held: list = []
        self._cached_step: StepRecord | None = None
        self._extras: dict[str, np.ndarray] = {}

    def record(self, k: int, step: StepRecord, called: bool, values: Sequence[float], flags: Sequence[bool] = (),
               extras: Mapping[str, object] | None = None) -> None:
        """Row k: the loop's values (floats, then flags, in their declared order), the step in
        force and whether this row made the call; `extras`: further float columns by key
        (a plant's own signals; the caller declares their units)."""
        if step is not self._cached_step:
            self._cache(step)
        self._floats[k] = [*values, *step.u_nom.tolist(), *self._held_filter[:-1], *step.u.tolist(),
                           self._held_filter[-1], step.filter_us if called else math.nan, ACTION_CODES[step.action]]
        output = step.output
        self._flags[k] = [*flags, called and output is not None and bool(output.infeasible)]
        if self._diag is not None:
            self._diag[k] = self._diag_called if called and output is not None else self._diag_held
        if extras:
            for key, value in extras.items():
                if key not in self._extras:
                    self._extras[key] = np.zeros((self.n_steps,) + np.shape(value))
                self._extras[key][k] = value

    def _cache(self, step: StepRecord) -> None:
        """The filter's values of a new step: its own output's, or the last output's when it has none."""
        self._cached_step = step
        output = step.output
        if output is None:
            return
        self._held_filter = [*np.asarray(output.u, dtype=float).tolist(), float(output.rho_pred)]
        if output.diagnostics or self._diag_layout is not None:
            if self._diag_layout is None:
                self._layout(output)
            self._diag_called, self._diag_held = self._flatten(output)

    def _layout(self, output: FilterOutput) -> None:
        clash = sorted(set(output.diagnostics) & (set(TIMESERIES_UNITS) | set(self._float_shapes)))
        if clash:
            raise ValueError(f"filter diagnostics must not reuse the loop's column names, got {clash}")
        self._diag_layout = [(key, np.shape(value), np.asarray(value).dtype == bool)
                             for key, value in output.diagnostics.items()]
        self._diag_units = {key: str(output.diagnostic_units[key]) for key in output.diagnostics}
        self._diag = np.full((self.n_steps, sum(math.prod(s) for _, s, _ in self._diag_layout)), math.nan)

    def _flatten(self, output: FilterOutput) -> tuple[list, list]:
        """(values on the call's row, values held on later rows): scalar booleans only on the call's row."""
        diagnostics = output.diagnostics
        if [key for key, _, _ in self._diag_layout] != list(diagnostics):
            raise ValueError(f"filter diagnostics must keep their keys over a run: first "
                             f"{[key for key, _, _ in self._diag_layout]}, now {list(diagnostics)}")
        called, held = [], []
        for key, shape, is_bool in self._diag_layout:
            value = diagnostics[key]
            if shape:
                flat = np.asarray(value, dtype=float).ravel().tolist()
                if len(flat) != math.prod(shape):
                    raise ValueError(f"filter diagnostic {key!r} must keep its shape {shape} over a run, got {np.shape(value)}")
                called += flat
                held += flat
            else:
                called.append(float(value))
                held.append(0.0 if is_bool else float(value))
        return called, held

    def units(self) -> dict[str, str]:
        """The units of every column `columns` returns except the extras."""
        units = {key: TIMESERIES_UNITS[key] for key in (*self._float_shapes, *self._flag_keys)}
        units.update(self._diag_units)
        return units

    def columns(self, n_rows: int | None = None) -> dict[str, np.ndarray]:
        """The first `n_rows` rows (default all) as arrays by key."""
        rows = self.n_steps if n_rows is None else n_rows
        columns, start = {}, 0
        for key, shape in self._float_shapes.items():
            size = math.prod(shape)
            columns[key] = self._floats[:rows, start : start + size].reshape((rows,) + shape).copy()
            start += size
        columns["action"] = columns["action"].astype(np.int8)
        for i, key in enumerate(self._flag_keys):
            columns[key] = self._flags[:rows, i].copy()
        if self._diag is not None:
            start = 0
            for key, shape, is_bool in self._diag_layout:
                size = math.prod(shape)
                block = self._diag[:rows, start : start + size].reshape((rows,) + shape)
                columns[key] = np.nan_to_num(block, nan=0.0).astype(bool) if is_bool else block.copy()
                start += size
        columns.update({key: value[:rows].copy() for key, value in self._extras.items()})
        return columns
