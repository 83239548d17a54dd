"""The diagnostics' flat layout: an internal fast path of the control step's output check and the recorder.

The plug-in contract asks a filter for its diagnostics as a plain mapping, str key → a real number, a bool or a
small array of them, with the same keys and shapes every call (`controllers.contract.safety_filter`). The control step
converts them once (`controllers.contract.safety_filter.OutputCheck`) into one flat list of plain values in a layout of its
own, `DiagnosticLayout` (key → shape, which keys are boolean, key → unit; each key's values row-major, in the keys'
order), and hands that `FlatDiagnostics` to the recorder (`closedloop.record`), which copies the list into its row
as it is.

A built-in filter called every control step may return its diagnostics already so (`FlatDiagnostics` in a layout it
made once): the check then copies the list (its values' types checked, its layout read once per run) instead of
reading each key, converting each array and flattening it. On the paper's two-segment robot, with the paper CBF's
diagnostics, a control step (the filter's return, the step, the recorder's row) costs 36 µs CPU with a plain dict of
arrays and 21 µs with the flat list, 19 µs without diagnostics; the paper CBF's own call is 15 µs, so the flat list
saves 0.4 of a paper-CBF step (`tools/bench_diagnostics.py`, side by side, AMD EPYC, 2 cores at load 12). That is
why the paper CBF, the standard CBF family and the backup CBF keep it. It is not part of the plug-in contract: a
user's filter returns a plain mapping, and a `FlatDiagnostics` is read like one (a key's array built when read).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np


class DiagnosticLayout:
    """The keys of a filter's diagnostics, fixed over a run: their shapes, which are boolean,
    and their units, in the order of a flat list of their values (each key's values row-major).
    Made once per filter; `FlatDiagnostics` of the same layout are recorded without unpacking."""

    __slots__ = ("shapes", "booleans", "units", "size", "_slices")

    def __init__(self, shapes: Mapping[str, tuple[int, ...]], units: Mapping[str, str],
                 booleans: frozenset[str] = frozenset()) -> None:
        missing = sorted(set(shapes) - set(units))
        if missing:
            raise ValueError(f"units must declare a unit for every diagnostic, missing {missing}")
        unknown = sorted(set(booleans) - set(shapes))
        if unknown:
            raise ValueError(f"booleans must be keys of shapes, got {unknown}")
        self.shapes = {key: tuple(int(d) for d in shape) for key, shape in shapes.items()}
        self.booleans, self.units = frozenset(booleans), units
        self._slices: dict[str, tuple[int, int]] = {}
        start = 0
        for key, shape in self.shapes.items():
            self._slices[key] = (start, start + math.prod(shape))
            start += math.prod(shape)
        self.size = start  # number of flat values

    def value(self, key: str, values: list) -> object:
        """The value of `key` in the flat `values`: the scalar itself for shape (), else an
        array of its shape (bool or float)."""
        start, stop = self._slices[key]
        shape = self.shapes[key]
        if not shape:
            return values[start]
        return np.array(values[start:stop], dtype=bool if key in self.booleans else float).reshape(shape)


class FlatDiagnostics(Mapping):
    """A filter's diagnostics as one flat list `values` in `layout`'s order (DiagnosticLayout):
    a read-only mapping whose arrays are built when read. Made every control call; nothing
    modifies it once returned."""

    __slots__ = ("layout", "values")

    def __init__(self, layout: DiagnosticLayout, values: list) -> None:
        if len(values) != layout.size:
            raise ValueError(f"values must hold the layout's {layout.size} values, got {len(values)}")
        self.layout, self.values = layout, values

    def __getitem__(self, key: str) -> object:
        return self.layout.value(key, self.values)

    def __iter__(self):
        return iter(self.layout.shapes)

    def __len__(self) -> int:
        return len(self.layout.shapes)
