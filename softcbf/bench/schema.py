"""bench.json: its fields and their check (`check_bench_json`), which `--resume` applies before it keeps anything.

    {"battery": [case, ...], "quick": bool, "mismatch_draws": int, "filters": [label, ...],
     "skipped": {case or "FILTER x CASE": reason}, "results": [row, ...], "falsify": {...} | null,
     "worst_found": [entry, ...], "contact_under_error": [entry, ...]}

Every result row holds `RESULT_KEYS` (the figures: softcbf.bench.figures; `force_asked_N` and
`force_delivered_N`, `force_delivered_ratio` = delivered / min(asked, F_max) in a contact task, null in the
other cases; `force_budget_used` = F max / F_max and `f_max_N`, the scenario's F_max, in every row;
`nominal_acceptance`, the fraction of calls that returned u_nom; wall_s: the case's wall time), every
worst_found entry `WORST_KEYS` (softcbf.study.worst_found, and `beyond_certified`: softcbf.bench.certified),
every contact_under_error entry `CONTACT_KEYS` (softcbf.bench.cases: `contact_under_error`, derived from the rows).
A pooled row's `violations` and `violation_cp95_upper` (softcbf.bench.figures) join its other violation fields
(`VIOLATION_KEYS`, null together); `force_delivered_min_ratio` and `force_delivered_median_ratio` are a push-draw
case's (null elsewhere).

The check (`check_bench_json`): the fields and types of docs/beyond-the-paper.md#filter-benchmark, numbers
finite, times, RMS and compute times >= 0, probabilities and fractions in [0, 1], known cases, filters of its
own list, each (filter, case) once; the same for "worst_found". A row's fault fields agree: fault set exactly
when faulted > 0, the verdict (`VERDICT_KEYS`) null exactly then, the call figures (`CALL_KEYS`) numbers when
no run faulted; "contact_under_error" is what its rows give. A file that fails is refused with one line naming the field.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from softcbf.bench.cases import CASES, CONTACT_KEYS, contact_under_error
from vocabulary.settings import Bound, check_number, non_negative

RESULT_KEYS = ("filter", "case", "rho_min_meas", "t_violation_s", "force_max_N", "violation_probability", "violation_ci95",
               "draws", "u_dev_rms_hPa", "blocked_s", "switches_per_s", "filter_us_median", "filter_us_p99",
               "nominal_acceptance", "wall_s", "force_asked_N", "force_delivered_N", "force_delivered_ratio",
               "force_budget_used", "f_max_N", "faulted", "fault", "violations", "violation_cp95_upper",
               "force_delivered_min_ratio", "force_delivered_median_ratio")
VIOLATION_KEYS = ("violation_probability", "violation_ci95", "draws", "violations", "violation_cp95_upper")
"""A pooled row's violation fields: null together (a single run)."""
VERDICT_KEYS = ("rho_min_meas", "t_violation_s")  # null exactly when a run of the row faulted (module docstring)
CALL_KEYS = ("u_dev_rms_hPa", "blocked_s", "switches_per_s", "filter_us_median", "filter_us_p99",
             "nominal_acceptance")  # null only then
WORST_KEYS = ("filter", "rho_worst_found", "params", "evaluation", "evaluations", "failed", "first_violation", "wall_s",
              "faulted", "fault", "beyond_certified")


_FRACTION = Bound(0.0, 1.0)
ROW_SCHEMA: dict[str, Callable[[str, Any], None]] = {  # bench.json's row fields (docs/beyond-the-paper.md#filter-benchmark), each checked by key and value
    "filter": lambda key, v: _check_text(key, v),
    "case": lambda key, v: _check_text(key, v, [c.name for c in CASES]),
    "rho_min_meas": lambda key, v: v is None or _check_finite(key, v),
    **{name: (lambda key, v: check_number(key, v, non_negative())) for name in ("force_max_N", "wall_s")},
    **{name: (lambda key, v: v is None or check_number(key, v, non_negative()))  # null: `_check_row_fault`
       for name in ("t_violation_s", *CALL_KEYS) if name != "nominal_acceptance"},
    **{name: (lambda key, v: v is None or check_number(key, v, _FRACTION))
       for name in ("violation_probability", "nominal_acceptance", "violation_cp95_upper")},
    "violation_ci95": lambda key, v: v is None or _check_interval(key, v),
    "draws": lambda key, v: v is None or check_number(key, v, Bound(1), integer=True),
    "violations": lambda key, v: v is None or check_number(key, v, non_negative(), integer=True),
    **{name: (lambda key, v: v is None or check_number(key, v, non_negative()))
       for name in ("force_asked_N", "force_delivered_N", "force_delivered_ratio", "force_delivered_min_ratio",
                    "force_delivered_median_ratio")},
    "force_budget_used": lambda key, v: check_number(key, v, non_negative()),
    "f_max_N": lambda key, v: check_number(key, v, Bound(0.0, low_open=True, unit="N")),
    "faulted": lambda key, v: check_number(key, v, non_negative(), integer=True),
    "fault": lambda key, v: _check_fault(key, v),
}


_COUNT = Bound(1)
WORST_SCHEMA: dict[str, Callable[[str, Any], None]] = {  # bench.json's worst_found entries, checked by key and value
    "filter": lambda key, v: _check_text(key, v),
    "rho_worst_found": lambda key, v: v is None or _check_finite(key, v),
    "params": lambda key, v: v is None or _check_params(key, v),
    "evaluation": lambda key, v: v is None or check_number(key, v, _COUNT, integer=True),
    "evaluations": lambda key, v: check_number(key, v, _COUNT, integer=True),
    "failed": lambda key, v: check_number(key, v, non_negative(), integer=True),
    "first_violation": lambda key, v: v is None or check_number(key, v, _COUNT, integer=True),
    "wall_s": lambda key, v: check_number(key, v, non_negative()),
    "faulted": lambda key, v: check_number(key, v, non_negative(), integer=True),
    "fault": lambda key, v: _check_fault(key, v),
    "beyond_certified": lambda key, v: _check_names(key, v),
}
FALSIFY_TEXT = ("box", "box_file", "scenario", "objective", "sampler")
FALSIFY_COUNTS = ("budget", "population", "seed", "baseline")


def _check_fault(key: str, value: Any) -> None:
    if value is None:
        return
    if not (isinstance(value, dict) and set(value) == {"type", "message", "where"}
            and all(isinstance(v, str) for v in value.values())):
        raise ValueError(f"{key} must be null or {{\"type\", \"message\", \"where\"}} (texts), got {value!r}")


def _check_row_fault(where: str, row: Mapping[str, Any]) -> None:
    """A result row's fault fields agree (module docstring): fault set exactly when faulted > 0, the verdict
    (`VERDICT_KEYS`) null exactly then, the call figures (`CALL_KEYS`) set when no run faulted."""
    if (row["fault"] is None) != (row["faulted"] == 0):
        raise ValueError(f"{where}: fault must be set exactly when faulted > 0, got faulted {row['faulted']!r}, "
                         f"fault {row['fault']!r}")
    for key in VERDICT_KEYS:
        if row["faulted"] and row[key] is not None:
            raise ValueError(f"{where}.{key} must be null in a row whose filter faulted (no verdict), got {row[key]!r}")
    for key in (*VERDICT_KEYS, *CALL_KEYS) if not row["faulted"] else ():
        if row[key] is None:
            raise ValueError(f"{where}.{key} must be a number (null only in a row whose filter faulted), got None")


def _check_names(key: str, value: Any) -> None:
    if not (isinstance(value, list) and all(isinstance(v, str) and v for v in value)):
        raise ValueError(f"{key} must be a list of the box's parameter names, got {value!r}")


def _check_params(key: str, value: Any) -> None:
    if not (isinstance(value, dict) and all(isinstance(k, str) and k for k in value)):
        raise ValueError(f"{key} must be null or {{parameter: value}}, got {value!r}")
    for name, v in value.items():
        if not isinstance(v, str):
            _check_finite(f"{key}.{name}", v)


def _check_falsify(data: Mapping[str, Any]) -> None:
    """bench.json's "falsify" (null, or the searches' settings) and "worst_found" (one entry per filter)."""
    settings, entries = data["falsify"], data["worst_found"]
    if settings is None:
        if entries != []:
            raise ValueError(f"worst_found must be [] when falsify is null (no search ran), got {entries!r}")
        return
    if not isinstance(settings, dict):
        raise ValueError(f"falsify must be null or an object of the searches' settings, got {settings!r}")
    missing = [k for k in (*FALSIFY_TEXT, *FALSIFY_COUNTS, "duration_s") if k not in settings]
    if missing:
        raise ValueError(f"falsify lacks {', '.join(missing)}")
    for key in FALSIFY_TEXT:
        _check_text(f"falsify.{key}", settings[key])
    for key in FALSIFY_COUNTS:
        check_number(f"falsify.{key}", settings[key], _COUNT if key in ("budget", "population") else non_negative(),
                     integer=True)
    check_number("falsify.duration_s", settings["duration_s"], Bound(0.0, low_open=True, unit="s"))
    for where, entry in _checked_items(data, "worst_found", WORST_SCHEMA, ("an entry", "entries"), lambda e: e["filter"]):
        _null_together(where, entry, ("params", "evaluation"))
        if (entry["rho_worst_found"] is None) != (entry["params"] is None or entry["fault"] is not None):
            raise ValueError(f"{where}: rho_worst_found must be null exactly when no evaluation finished or the worst "
                             f"one faulted (fault set), got {entry['rho_worst_found']!r} with params "
                             f"{entry['params']!r}, fault {entry['fault']!r}")
        if entry["fault"] is not None and not entry["faulted"]:
            raise ValueError(f"{where}: a fault needs faulted >= 1, got {entry['faulted']!r}")
        if entry["evaluations"] > settings["budget"] or entry["failed"] > entry["evaluations"]:
            raise ValueError(f"{where}: needs failed <= evaluations <= falsify.budget, got {entry['failed']}, "
                             f"{entry['evaluations']}, {settings['budget']}")
        for key in ("evaluation", "first_violation"):
            if entry[key] is not None and entry[key] > entry["evaluations"]:
                raise ValueError(f"{where}.{key} must be <= evaluations ({entry['evaluations']}), got {entry[key]}")


def _check_finite(key: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{key} must be a finite number, got {value!r}")


def _check_text(key: str, value: Any, known: Sequence[str] | None = None) -> None:
    if not isinstance(value, str) or not value or (known is not None and value not in known):
        raise ValueError(f"{key} must be {'one of ' + ', '.join(known) if known else 'a non-empty string'}, got {value!r}")


def _check_interval(key: str, value: Any) -> None:
    if not (isinstance(value, list) and len(value) == 2):
        raise ValueError(f"{key} must be null or [lo, hi], got {value!r}")
    lo, hi = (check_number(f"{key}[{i}]", v, _FRACTION) for i, v in enumerate(value))
    if lo > hi:
        raise ValueError(f"{key} must have lo <= hi, got {value!r}")


def check_bench_json(data: Any) -> None:
    """ValueError naming the first field of `data` (a parsed bench.json) that does not hold the module docstring's
    schema: "battery" and "filters" lists of names, "quick" true/false, "mismatch_draws" an integer >= 1, "skipped"
    {case: reason}, "results" rows with every `RESULT_KEYS` field of its type (numbers finite, counts, durations,
    RMS and compute times >= 0, probabilities in [0, 1]; the three violation fields null together), a known case,
    a filter of "filters", each (filter, case) once; "falsify" null or the searches' settings and "worst_found"
    entries with every `WORST_KEYS` field (`WORST_SCHEMA`), a filter of "filters" each once (none when falsify
    is null), failed <= evaluations <= budget."""
    if not isinstance(data, dict):
        raise ValueError(f"it must be a JSON object, got {type(data).__name__}")
    missing = [k for k in ("battery", "quick", "mismatch_draws", "filters", "skipped", "results", "falsify", "worst_found",
                           "contact_under_error") if k not in data]
    if missing:
        raise ValueError(f"it lacks {', '.join(missing)}")
    for key in ("battery", "filters"):
        if not isinstance(data[key], list):
            raise ValueError(f"{key} must be a list of names, got {data[key]!r}")
        for i, name in enumerate(data[key]):
            _check_text(f"{key}[{i}]", name)
    if not isinstance(data["quick"], bool):
        raise ValueError(f"quick must be true or false, got {data['quick']!r}")
    check_number("mismatch_draws", data["mismatch_draws"], Bound(1), integer=True)
    if not (isinstance(data["skipped"], dict) and all(isinstance(v, str) for v in data["skipped"].values())):
        raise ValueError(f"skipped must be an object {{case or 'FILTER x CASE': reason}}, got {data['skipped']!r}")
    for where, row in _checked_items(data, "results", ROW_SCHEMA, ("a row", "rows"), lambda r: f"({r['filter']}, {r['case']})"):
        _null_together(where, row, VIOLATION_KEYS)
        if row["draws"] is not None and row["violations"] > row["draws"]:
            raise ValueError(f"{where}.violations must be <= draws ({row['draws']}), got {row['violations']}")
        _check_row_fault(where, row)
    _check_falsify(data)
    _check_contact(data)


def _check_contact(data: Mapping[str, Any]) -> None:
    """bench.json's "contact_under_error": a list of objects with `CONTACT_KEYS`, exactly what its result rows give
    (softcbf.bench.cases: `contact_under_error`; a figure edited by hand is refused)."""
    entries = data["contact_under_error"]
    if not (isinstance(entries, list) and all(isinstance(e, dict) and set(e) == set(CONTACT_KEYS) for e in entries)):
        raise ValueError(f"contact_under_error must be a list of objects with {', '.join(CONTACT_KEYS)}, got {entries!r}")
    expected = contact_under_error(data["results"])
    for i, (entry, want) in enumerate(zip(entries, expected)):
        wrong = [k for k in CONTACT_KEYS if entry[k] != want[k]]
        if wrong:
            raise ValueError(f"contact_under_error[{i}].{wrong[0]} must be {want[wrong[0]]!r} (what its result rows "
                             f"give), got {entry[wrong[0]]!r}")
    if len(entries) != len(expected):
        raise ValueError(f"contact_under_error must hold {len(expected)} entries (one per filter and plant with "
                         f"contact rows), got {len(entries)}")


def _checked_items(data: Mapping[str, Any], name: str, schema: Mapping[str, Callable[[str, Any], None]],
                   noun: tuple[str, str], identity: Callable[[dict[str, Any]], str]):
    """Yield ("NAME[i]", item) for every item of the list data[name] once it is an object holding every key of
    `schema`, each value passing its check, a filter of data["filters"], and `identity(item)` first seen;
    ValueError naming the item and the field otherwise (`noun`: an item, items)."""
    if not isinstance(data[name], list):
        raise ValueError(f"{name} must be a list of {noun[1]}, got {data[name]!r}")
    seen = set()
    for i, item in enumerate(data[name]):
        where = f"{name}[{i}]"
        if not isinstance(item, dict):
            raise ValueError(f"{where} must be an object, got {item!r}")
        missing = [k for k in schema if k not in item]
        if missing:
            raise ValueError(f"{where} lacks {', '.join(missing)}")
        for key, check in schema.items():
            check(f"{where}.{key}", item[key])
        if item["filter"] not in data["filters"]:
            raise ValueError(f"{where}.filter {item['filter']!r} is not one of its filters ({', '.join(data['filters'])})")
        if identity(item) in seen:
            raise ValueError(f"{where}: {identity(item)} has {noun[0]} already")
        seen.add(identity(item))
        yield where, item


def _null_together(where: str, item: Mapping[str, Any], keys: Sequence[str]) -> None:
    nulls = [item[k] is None for k in keys]
    if any(nulls) and not all(nulls):
        raise ValueError(f"{where}: {', '.join(keys[:-1])} and {keys[-1]} must be null together, got "
                         f"{', '.join(repr(item[k]) for k in keys)}")
