"""bench.md, the bench's tables in Markdown, and the words of its printed lines.

bench.md: one table of every result row (`TABLE`: each column's heading with its unit, the row field and its
format), the quick flag, the skipped cases, the force plot's link (with contact tasks) and the worst cases
found (`worst_found_markdown`).

Nominal acceptance (column "u = u_nom [share of calls]"): the fraction of the filter's calls that returned the
nominal command in every segment within softcbf.bench.figures.ACCEPT_TOL_HPA (stated under the table).

The worst case found is a search over the standard mismatch box. Where that box is wider than what the filter
certifies (softcbf.bench.certified: the entry's `beyond_certified` names the coordinates), a negative
ρ_meas is no broken promise: it is labelled `WIDER_BOX` ("over a box wider than this filter certifies") with
the coordinates beyond, in bench.md and on the printed line alike (`worst_case_text`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from softcbf.bench.figures import ACCEPT_TOL_HPA

PLOT_FILE, FORCE_PLOT_FILE = "plots/bench.png", "plots/force_budget.png"  # in the bench folder; bench.md links them
WIDER_BOX = "over a box wider than this filter certifies"
TABLE = (("filter", "filter", ""), ("case", "case", ""), ("filter fault", "fault", ""), ("ρ_meas min", "rho_min_meas", ".4f"),
         ("t_viol [s]", "t_violation_s", ".3f"), ("F max [N]", "force_max_N", ".4f"),
         ("P(viol) [95 % CI] (n)", None, ""), ("u_dev RMS [hPa]", "u_dev_rms_hPa", ".1f"), ("blocked [s]", "blocked_s", ".2f"),
         ("switches [1/s]", "switches_per_s", ".2f"), ("u = u_nom [share of calls]", "nominal_acceptance", ".3f"),
         ("filter med [µs]", "filter_us_median", ".0f"),
         ("filter p99 [µs]", "filter_us_p99", ".0f"), ("wall [s]", "wall_s", ".0f"), ("F asked [N]", "force_asked_N", ".4f"),
         ("F delivered [N]", "force_delivered_N", ".4f"), ("delivered / min(asked, F_max)", "force_delivered_ratio", ".3f"),
         ("F max / F_max", "force_budget_used", ".3f"))


def fault_text(item: Mapping[str, Any]) -> str:
    """A bench row's or worst_found entry's fault in words: "TYPE in the WHERE (n runs)", "" without one."""
    fault, n = item["fault"], item["faulted"]
    if fault is None:
        return ""
    return f"{fault['type']} in the {fault['where']} ({n} run{'s' if n != 1 else ''})"


def cell(row: Mapping[str, Any], key: str | None, spec: str) -> str:
    """One cell of `TABLE` (`key` None: the violation probability with its interval and draws); "–" for null."""
    if key == "fault":
        return fault_text(row) or "–"
    if key is None:
        p = row["violation_probability"]
        if p is None:
            return "–"
        lo, hi = row["violation_ci95"]
        return f"{p:.3f} [{lo:.3f}, {hi:.3f}] ({row['draws']})"
    value = row[key]
    if value is None:
        return "–"
    return format(value, spec) if isinstance(value, float) and math.isfinite(value) else str(value)


def table_markdown(bench: Mapping[str, Any]) -> str:
    """bench.md: the results as one Markdown table, the quick flag and the skipped cases."""
    lines = [f"# Filter benchmark{' (quick: shortened for CI, not the battery)' if bench['quick'] else ''}", "",
             f"Battery: {', '.join(bench['battery'])}. Filters: {', '.join(bench['filters'])}.", "",
             "A fault is never a pass: a row whose filter faulted in some run names the fault and has no ρ_meas min "
             "or t_viol (its runs stopped at the fault); P(viol) counts each faulted run as a violation. "
             "u = u_nom: the share of the filter's calls that returned the nominal command in every segment "
             f"(within {ACCEPT_TOL_HPA:g} hPa).", "",
             "| " + " | ".join(h for h, _, _ in TABLE) + " |", "|" + "---|" * len(TABLE)]
    lines += ["| " + " | ".join(cell(r, k, s) for _, k, s in TABLE) + " |" for r in bench["results"]]
    lines += [f"\nSkipped: {name}: {reason}" for name, reason in bench["skipped"].items()]
    if any(r["force_delivered_N"] is not None for r in bench["results"]):
        lines += ["", "Contact tasks: force delivered against force asked, every filter:", "",
                  f"![delivered against asked]({FORCE_PLOT_FILE})"]
    return "\n".join(lines + worst_found_markdown(bench)) + "\n"


def worst_case_text(entry: Mapping[str, Any], spec: str = ".4f") -> str:
    """A worst_found entry's ρ_meas worst found in words: the value (or the filter fault, or "–"), and `WIDER_BOX`
    with the coordinates beyond what the filter certifies where there are any."""
    if entry["fault"]:
        shown = f"a filter fault ({fault_text(entry)})"
    else:
        shown = "–" if entry["rho_worst_found"] is None else format(entry["rho_worst_found"], spec)
    beyond = entry["beyond_certified"]
    return f"{shown} {WIDER_BOX} ({', '.join(beyond)})" if beyond else shown


def worst_found_markdown(bench: Mapping[str, Any]) -> list[str]:
    """bench.md's lines on the worst-case searches: the box and budget, then one row per filter (none: no search)."""
    f = bench["falsify"]
    if f is None:
        return []
    lines = ["", "## Worst case found", "",
             f"Per filter: {f['budget']} evaluations of a falsification ({f['sampler']}, the box's vertices first, seed "
             f"{f['seed']}) over the box {f['box']} ({f['box_file']}: {f['scenario']}, {f['duration_s']:g} s each); "
             "ρ_meas worst found = the least ρ_min_meas of those evaluations, or a filter fault, the worst there "
             "is (< 0 or a fault: a violation found; ≥ 0 proves nothing). The box is the same for every filter; "
             f"where it is wider than what the filter certifies, the value is marked \"{WIDER_BOX}\" with the "
             "box's parameters beyond its certified intervals (a violation there breaks no promise of the filter). "
             "Each search's folder: cases/<filter>/worst_found/ (its worst/ replays with `softcbf run --config`).", "",
             "| filter | ρ_meas worst found | at evaluation | first violation | evaluations (failed) | its parameters |",
             "|---|---|---|---|---|---|"]
    for e in bench["worst_found"]:
        params = ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                           for k, v in (e["params"] or {}).items()) or "–"
        lines.append(f"| {e['filter']} | {worst_case_text(e)} | {e['evaluation'] or '–'} | "
                     f"{e['first_violation'] or '–'} | {e['evaluations']} ({e['failed']}) | {params} |")
    return lines
