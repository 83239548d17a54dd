"""The filters under test: `--filters` specs (`FilterSpec`, `parse_filters`) and the bench's default selection.

`--filters` is a comma list of specs `NAME` or `NAME(param=value,...)` (NAME: a registry spec,
`controllers.registry`: "paper-cbf", "none", "qsg", "e-erg", "c-erg", FILE.py:Factory, package.module:Factory),
e.g. `"e-erg(contact_aware=true),paper-cbf(tuning=HW-High)"`; a filter's parameter may be given once, and a
filter (its label) once.

Default (`DEFAULT_FILTERS`): the recommended filter beside the baselines. The recommended filter is the preset
`c-erg:recommended` (`RECOMMENDED_FILTER`; `controllers.registry.PRESETS`: the setting the README names and
`softcbf list` lists), the baselines e-erg and the paper's CBF (paper-cbf). The bench adds to a filter only what
the plant decides (softcbf.bench.cases: `case_filter_params`), never an interval of its own to the recommended one.

A spec's label (`FilterSpec.label`) names it in bench.json, bench.md and the case folders; a long one (a filter
given with many parameters) is shortened in the plots (`softcbf_mj.outputs.palette.plot_labels`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from controllers.registry import FILTERS, resolve


@dataclass(frozen=True)
class FilterSpec:
    """A filter under test: a registry spec and the parameters given for it ({name: text})."""

    name: str
    params: dict[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        args = ",".join(f"{k}={v}" for k, v in self.params.items())
        return f"{self.name}({args})" if args else self.name


RECOMMENDED_FILTER = FilterSpec("c-erg:recommended")
BASELINES = ("e-erg", "paper-cbf")
DEFAULT_FILTERS = ",".join((RECOMMENDED_FILTER.label, *BASELINES))


def split_items(text: str) -> list[str]:
    """`text` split at the commas outside parentheses, each item stripped; ValueError on unbalanced parentheses."""
    items, depth, start = [], 0, 0
    for i, char in enumerate(text + ","):
        depth += {"(": 1, ")": -1}.get(char, 0)
        if depth < 0:
            raise ValueError(f"--filters has an unmatched ')' at position {i}: {text!r}")
        if char == "," and depth == 0:
            items.append(text[start:i].strip())
            start = i + 1
    if depth:
        raise ValueError(f"--filters has an unclosed '(': {text!r}")
    return items


def parse_filter(item: str, text: str) -> FilterSpec:
    """One item `NAME` or `NAME(param=value,...)` of the --filters list `text`; ValueError naming the bad item."""
    match = re.fullmatch(r"([^()]+?)\s*(?:\((.*)\))?", item)
    if not item or match is None:
        raise ValueError(f"--filters takes NAME or NAME(param=value,...) separated by commas, got {item!r} in {text!r}")
    params = {}
    for pair in filter(None, (p.strip() for p in (match.group(2) or "").split(","))):
        name, sep, value = pair.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"filter parameters must be name=value, got {pair!r} in {item!r}")
        if name.strip() in params:
            raise ValueError(f"filter parameter {name.strip()} is given twice in {item!r}; give it once")
        params[name.strip()] = value.strip()
    resolve(match.group(1), FILTERS)
    return FilterSpec(match.group(1), params)


def parse_filters(text: str) -> list[FilterSpec]:
    """`"NAME,NAME(param=value,...),..."` → filter specs (module docstring); ValueError naming the bad item."""
    specs = [parse_filter(item, text) for item in split_items(text)]
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise ValueError(f"--filters names a filter twice: {text!r}")
    return specs
