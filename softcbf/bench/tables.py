"""bench.md, the bench's tables in Markdown, and the words of its printed lines.

bench.md: one table of every result row (`TABLE`: each column's heading with its unit, the row field and its
format), the quick flag, the skipped cases, the force plot's link (with contact tasks), contact under error
(`contact_markdown`: bench.json's "contact_under_error", every column) and the worst cases found
(`worst_found_markdown`). The bench's printed table of contact under error (`contact_text`) keeps within
`PRINT_WIDTH` = 120 columns: the figures that decide (draws, violations and their bound, least ρ_meas, the
delivered force / F_max), the filter by its short label; the rest is in bench.md.

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
PRINT_WIDTH = 120  # columns of the printed table (module docstring)
CONTACT_TABLE = (("filter", "filter", ""), ("plant", "plant", ""), ("draws", "draws", "d"),
                 ("violations", "violations", "d"), ("P(viol) < [CP 95 %]", "violation_cp95_upper", ".3f"),
                 ("ρ_meas min", "rho_min_meas", ".4f"), ("faulted", "faulted", "d"),
                 ("F nominal / F_max", "delivered_nominal_ratio", ".3f"), ("F min / F_max", "delivered_min_ratio", ".3f"),
                 ("F median / F_max", "delivered_median_ratio", ".3f"), ("flexure ρ_meas", "flexure_rho_min_meas", ".4f"),
                 ("F flexure / F_max", "flexure_ratio", ".3f"))
"""bench.md's contact-under-error columns: heading, entry field, format."""
CONTACT_PRINTED = ("filter", "plant", "draws", "violations", "violation_cp95_upper", "rho_min_meas",
                   "delivered_nominal_ratio", "delivered_min_ratio", "delivered_median_ratio", "flexure_ratio")
"""The fields of the printed table (module docstring), under their short headings `PRINTED_HEADINGS`."""
PRINTED_HEADINGS = {"filter": "filter", "plant": "plant", "draws": "draws", "violations": "viol",
                    "violation_cp95_upper": "P<(CP95)", "rho_min_meas": "rho_min", "delivered_nominal_ratio": "F_nom",
                    "delivered_min_ratio": "F_min", "delivered_median_ratio": "F_med", "flexure_ratio": "F_flex"}
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
    return "\n".join(lines + contact_markdown(bench) + worst_found_markdown(bench)) + "\n"


def contact_cell(entry: Mapping[str, Any], key: str, spec: str) -> str:
    """One cell of a contact-under-error table: the value in `spec`, "–" for null."""
    value = entry[key]
    return "–" if value is None else format(value, spec) if spec else str(value)


def contact_markdown(bench: Mapping[str, Any]) -> list[str]:
    """bench.md's lines on contact under error (`CONTACT_TABLE`; none without contact rows)."""
    entries = bench.get("contact_under_error") or []
    if not entries:
        return []
    lines = ["", "## Contact under error", "",
             "Per filter and plant: the 150 hPa push under draws of the standard box (violations: draws with ρ_meas < 0 "
             "or a filter fault; P(viol) <: the exact one-sided 95 % Clopper–Pearson bound; ρ_meas min: the least over "
             "the draws, – when one faulted), the delivered force / F_max on the nominal plate, its minimum and median "
             "over the draws that ran to the end, and the push on the flexure sheet (mujoco_contact).", "",
             "| " + " | ".join(h for h, _, _ in CONTACT_TABLE) + " |", "|" + "---|" * len(CONTACT_TABLE)]
    return lines + ["| " + " | ".join(contact_cell(e, k, s) for _, k, s in CONTACT_TABLE) + " |" for e in entries]


def contact_text(entries: list[Mapping[str, Any]], labels: Mapping[str, str]) -> list[str]:
    """The printed table of contact under error (module docstring): `CONTACT_PRINTED` under `PRINTED_HEADINGS`, a
    filter by its short label (`labels`: {label: shown}), at most `PRINT_WIDTH` columns (a longer label is cut)."""
    formats = {k: s for _, k, s in CONTACT_TABLE}
    rows = [[contact_cell({**e, "filter": labels.get(e["filter"], e["filter"])}, k, formats[k]) for k in CONTACT_PRINTED]
            for e in entries]
    widths = [max([len(PRINTED_HEADINGS[k])] + [len(r[i]) for r in rows]) for i, k in enumerate(CONTACT_PRINTED)]
    spare = PRINT_WIDTH - (sum(widths) + 2 * (len(widths) - 1))
    if spare < 0:
        widths[0] = max(len(PRINTED_HEADINGS["filter"]), widths[0] + spare)
    lines = ["  ".join(PRINTED_HEADINGS[k].rjust(w) for k, w in zip(CONTACT_PRINTED, widths))]
    lines += ["  ".join(c[:w].rjust(w) for c, w in zip(r, widths)) for r in rows]
    return lines


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
