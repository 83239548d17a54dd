"""A study folder's report: plots and a Markdown summary (`softcbf.study.analysis`).

`write_report(DIR, level=0.05, bins=6, figure_format="png", dpi=DPI)` reads DIR's rows and writes:

    DIR/report.md                      per tuning: samples, failed, faulted, violation probability with
                                       its 95 % Wilson interval, quantiles of ρ_min_meas and F max [N];
                                       per varied parameter and tuning: where the binned violation
                                       probability reaches `level`; the first failed and faulted
                                       samples' errors
    DIR/plots/rho_min_meas.<fmt>       ρ_meas min [1] per clean sample, by tuning (dots over box plots),
                                       ρ = 0 (F = F_max) marked
    DIR/plots/force_max_N.<fmt>        peak measured force [N] per sample, by tuning, F_max marked
                                       (the study's fixed `f_max`, else the scenario's default)
    DIR/plots/violation_<param>.<fmt>  binned violation probability vs the parameter (in words, in its
                                       unit: PARAMETERS), per tuning, with Wilson intervals, the `level`
                                       line and the value the controller assumes
    DIR/results.parquet                every row in one file (`StudyStore.compact`); load it with
                                       `pandas.read_parquet("DIR/results.parquet")`

Per tuning the table gives the violation probability's 95 % Wilson interval, the exact
two-sided Clopper–Pearson interval and the one-sided 95 % Clopper–Pearson upper bound (the
"P(violation) < … at 95 %" a lab can publish; `softcbf.study.analysis`). A sample whose filter
faulted counts as a violation in all of them and in the sensitivities, and stays out of the
distributions and their plots (its figures stop at the fault); the table's "faulted" column says
how many (a fault is never a pass).

A falsification folder (DIR/falsify.json, `softcbf.study.falsify`) gets its own report:

    DIR/report.md                      the objective, the search's and the uniform baseline's best value
                                       (or filter fault), where (parameters, tuning, evaluation), how many
                                       faulted and their first violation; the
                                       worst case's replay; the baseline's violation probability (its draws
                                       are uniform, so it estimates P over the box; the search's are not)
    DIR/plots/best_so_far.<fmt>        best-so-far objective against evaluations, search and baseline,
                                       first violations marked (a vertical line when it is a filter fault,
                                       which has no value), 0 marked for a ρ objective

A screened falsification (falsify.json's "screen", `softcbf.study.screen`) adds a section: the cheap search,
every expensive evaluation with the screened one it confirmed, and the expensive evaluations spent; its plot
shows both fidelities. A falsification campaign folder (DIR/campaign.json, `softcbf.study.campaign`) gets
the ARCH-COMP table: per filter and box, runs, falsified, rate, evaluations to the first counterexample
(median [min, max]) and the evaluations spent.

`figure_format` ∈ png, svg, pdf; `dpi` sets the raster resolution. The figures follow
softcbf_mj.outputs.plot_style (one journal column, 3.5 in wide, 8 pt text, legends below the axes, the
constrained layout): a tuning is named by softcbf_mj.outputs.palette.plot_labels (a filter's label with
every parameter runs to ~150 characters; report.md keys each shortened label to the full one)
and takes its run colour (Okabe–Ito), as in run reports; every axis that shows a quantity names
it in words with its unit (`PARAMETERS`: a varied parameter's words, unit and the factor from its
setting's unit, e.g. the plate offset in mm; `METRICS`: a summary metric's).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Sequence


from scenarios import get as get_scenario
from softcbf.study.analysis import (Proportion, clean, crossing, sensitivity, tuning_summary, varied_parameters,
                                    violated)
from softcbf.study.falsify import BASELINE_DIR, SEARCH_DIR, WORST_DIR, minimised, objective_value
from softcbf.study.campaign import CAMPAIGN_FILE
from softcbf.study.store import FALSIFY_FILE, STUDY_FILE, StudyStore, fault_of, faulted
from softcbf_mj.outputs.palette import LIMIT_COLOR, NEUTRAL_COLOR, plot_labels
from softcbf_mj.outputs.plot_style import (COLUMN_WIDTH_IN, FIGURE_FORMATS, GRID_ALPHA, distinct_colors, legend_outside, new_figure,
                                   save_figure, styled)
from vocabulary.settings import SETTINGS

REPORT_FILE = "report.md"
PLOTS_DIR = "plots"
MAX_ERRORS_LISTED = 5
DPI = 110
# Known scenario parameters: (words, unit shown, factor from the setting's unit to it, the value the controller
# assumes). The assumed value (in the setting's unit) is a number, the name of the parameter that holds it (its
# fixed value in the study, else the scenario's default), or None (the controller has no assumption to mark).
PARAMETERS: dict[str, tuple[str, str, float, float | str | None]] = {
    "plate_stiffness": ("true plate stiffness", "N/m", 1.0, "assumed_plate_stiffness"),
    "assumed_plate_stiffness": ("assumed plate stiffness", "N/m", 1.0, None),
    "true_stiffness_scale": ("true arm stiffness / model's", "1", 1.0, 1.0),
    "true_damping_scale": ("true arm damping / model's", "1", 1.0, 1.0),
    "true_gain_scale": ("true actuator gain / model's", "1", 1.0, 1.0),
    "true_length_scale": ("true segment length / model's", "1", 1.0, 1.0),
    "facet_offset": ("plate offset along its normal", "mm", 1e3, 0.0),
    "facet_angle": ("plate angle error", "mrad", 1e3, 0.0),
    "tau_p": ("valve lag τ_p", "ms", 1e3, None),
    "links_per_segment": ("links per segment", "1", 1.0, None),
    "f_max": ("force limit F_max", "N", 1.0, None),
    "latency": ("camera latency", "ms", 1e3, 0.0),
    "pixel_noise": ("image noise", "grey levels", 1.0, 0.0),
    "drop_rate": ("dropped frames", "share", 1.0, 0.0),
    "amplitude": ("nominal amplitude", "hPa", 1.0, None),
    "frequency": ("nominal frequency", "Hz", 1.0, None),
}
METRICS = {"rho_min_meas": ("ρ_meas min", "1"), "rho_min_pred": ("ρ_pred min", "1"),
           "force_max_N": ("peak measured force", "N"), "force_max": ("peak measured force", "N"),
           "t_violation_s": ("time above F_max", "s"), "t_violation": ("time above F_max", "s"),
           "u_dev_rms_hPa": ("|u − u_nom| RMS", "hPa"), "force_budget_used": ("F max / F_max", "1")}
"""A summary metric's words and unit (ρ: 1); an objective "-NAME" (maximised) takes NAME's."""
SIZE_IN = (COLUMN_WIDTH_IN, 3.2)  # one journal column; the legend below the axes


def _fmt(value: Any, spec: str = ".4g") -> str:
    return "–" if value is None else format(value, spec)


def scenario_value(scenario: str, fixed: Mapping[str, Any], parameter: str) -> Any:
    """The value of `parameter` in a study of `scenario`: its fixed value, else the scenario's default (None if it has no such parameter)."""
    if parameter in fixed:
        return fixed[parameter]
    return get_scenario(scenario).defaults().get(parameter)


def assumed_value(scenario: str, fixed: Mapping[str, Any], parameter: str) -> float | None:
    """The value the controller assumes for a varied `parameter` (PARAMETERS), or None."""
    assumed = PARAMETERS.get(parameter, ("", "", 1.0, None))[3]
    if isinstance(assumed, str):
        assumed = scenario_value(scenario, fixed, assumed)
    return None if assumed is None else float(assumed)


def axis_label(parameter: str) -> tuple[str, float]:
    """(words with the unit, factor from the setting's unit to the one shown) of a varied parameter (`PARAMETERS`;
    another: its name in words with its setting's unit)."""
    if parameter in PARAMETERS:
        words, unit, factor, _ = PARAMETERS[parameter]
        return f"{words} [{unit}]", factor
    unit = SETTINGS[parameter].unit if parameter in SETTINGS and SETTINGS[parameter].unit else "1"
    return f"{parameter.replace('_', ' ')} [{unit}]", 1.0


def metric_label(metric: str, words_after: str = "") -> str:
    """A summary metric's words, `words_after`, and its unit in brackets (`METRICS`; another: its name in words, [1])."""
    words, unit = METRICS.get(metric.removeprefix("-"), (metric.removeprefix("-").replace("_", " "), "1"))
    return f"{words}{words_after} [{unit}]"


def distribution_plot(rows: Sequence[Mapping[str, Any]], tunings: Sequence[str], key: str, path: Path,
                      figure_format: str, dpi: float, line: float | None = None) -> None:
    """The metric `key` per clean sample by tuning (dots over horizontal box plots, one row per tuning, top to
    bottom: no tuning's name runs into another's), the limit `line` marked (ρ = 0, F_max)."""
    data = [[r[key] for r in rows if r["tuning"] == t and clean(r) and r.get(key) is not None]
            for t in tunings]
    with styled():
        fig = new_figure((SIZE_IN[0], 1.4 + 0.35 * len(tunings)), dpi)
        ax = fig.add_subplot()
        if any(data):
            ax.boxplot([d if d else [float("nan")] for d in data], orientation="horizontal", showfliers=False,
                       medianprops={"color": NEUTRAL_COLOR})
        for i, (colour, d) in enumerate(zip(distinct_colors(tunings), data), start=1):
            ax.plot(d, [i] * len(d), ".", alpha=0.6, color=colour)
        ax.set_yticks(range(1, len(tunings) + 1), plot_labels(list(tunings)))
        ax.set_ylim(len(tunings) + 0.5, 0.5)
        if line is not None:
            limit = "ρ = 0 (F = F_max)" if key.startswith("rho") else f"F_max = {line:g} N"
            ax.axvline(line, color=LIMIT_COLOR, ls="--", lw=1.2, label=limit)
            legend_outside(fig, [ax], loc="outside lower center")
        ax.set_ylabel("tuning")
        ax.set_xlabel(metric_label(key))
        ax.grid(alpha=GRID_ALPHA)
        save_figure(fig, path, figure_format, dpi)


def sensitivity_plot(rows: Sequence[Mapping[str, Any]], tunings: Sequence[str], parameter: str, bins: int,
                     level: float, assumed: float | None, path: Path, figure_format: str, dpi: float) -> None:
    """The binned violation probability against `parameter` per tuning, with Wilson intervals, `level` and the
    value the controller assumes (`assumed`, in the setting's unit)."""
    label, factor = axis_label(parameter)
    with styled():
        fig = new_figure((SIZE_IN[0], SIZE_IN[1] + 0.3), dpi)
        ax = fig.add_subplot()
        for tuning, shown, colour in zip(tunings, plot_labels(list(tunings)), distinct_colors(tunings)):
            curve = [b for b in sensitivity(rows, parameter, tuning, bins) if b.violation.n and b.centre is not None]
            if not curve:
                continue
            x = [b.centre * factor for b in curve]
            p = [b.violation.p for b in curve]
            err = [[q - b.violation.low for q, b in zip(p, curve)], [b.violation.high - q for q, b in zip(p, curve)]]
            ax.errorbar(x, p, yerr=err, marker="o", ms=3, capsize=2, label=shown, color=colour)
        ax.axhline(level, color=NEUTRAL_COLOR, ls=":", lw=1.2, label=f"level {100 * level:g} %")
        if assumed is not None:
            ax.axvline(assumed * factor, color=LIMIT_COLOR, ls="--", lw=1.2, label=f"assumed: {assumed * factor:g}")
        ax.set_xlabel(label)
        ax.set_ylabel("P(F > F_max) [1]")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=GRID_ALPHA)
        legend_outside(fig, [ax], loc="outside lower center", ncols=2)
        save_figure(fig, path, figure_format, dpi)


def sensitivity_markdown(rows: Sequence[Mapping[str, Any]], tunings: Sequence[str], parameters: Sequence[str],
                         bins: int, level: float, ext: str) -> list[str]:
    """report.md's section on where each tuning's binned violation probability reaches `level`, per parameter."""
    lines = [f"## Sensitivity: where P(violation) reaches {100 * level:g} %", "",
             f"Binned ({bins} equal-width bins, or one per distinct value) and marginalised over the other "
             "varied parameters; the value interpolates between bin centres from the safer end. "
             "'above': already at the safer end; 'below': never within the range.", "",
             "| parameter | " + " | ".join(tunings) + " |", "|---|" + "---|" * len(tunings)]
    for parameter in parameters:
        cells = []
        for tuning in tunings:
            c = crossing(sensitivity(rows, parameter, tuning, bins), level)
            cells.append(f"{c['value']:.4g} ({c['status']})" if c["value"] is not None else c["status"])
        lines.append(f"| {parameter} | " + " | ".join(cells) + " |")
    return lines + [""] + [f"![{p}](plots/violation_{p}.{ext})" for p in parameters] + [""]


def write_report(root: str | Path, level: float = 0.05, bins: int = 6, figure_format: str = "png",
                 dpi: float = DPI) -> Path:
    """Write DIR/report.md, DIR/plots/*.<figure_format> and DIR/results.parquet; return the report's path."""
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    if figure_format not in FIGURE_FORMATS:
        raise ValueError(f"figure_format must be one of {', '.join(FIGURE_FORMATS)}, got {figure_format!r}")
    if not dpi > 0:
        raise ValueError(f"dpi must be > 0, got {dpi}")
    if (Path(root) / CAMPAIGN_FILE).is_file():
        return write_campaign_report(root)
    if (Path(root) / FALSIFY_FILE).is_file() and not (Path(root) / STUDY_FILE).is_file():
        return write_falsify_report(root, figure_format, dpi)
    store = StudyStore.open(root)
    study = store.study
    rows = store.load_rows()
    if not rows:
        raise ValueError(f"{store.root} holds no results yet; run the study first")
    store.compact()
    plots = store.root / PLOTS_DIR
    plots.mkdir(exist_ok=True)
    tunings = list(study.tunings)
    summary = tuning_summary(rows, tunings)
    f_max = scenario_value(study.scenario, study.fixed, "f_max")
    ext = figure_format
    distribution_plot(rows, tunings, "rho_min_meas", plots / f"rho_min_meas.{ext}", ext, dpi, line=0.0)
    distribution_plot(rows, tunings, "force_max_N", plots / f"force_max_N.{ext}", ext, dpi, line=f_max)
    parameters = varied_parameters(rows)
    for parameter in parameters:
        sensitivity_plot(rows, tunings, parameter, bins, level, assumed_value(study.scenario, study.fixed, parameter),
                          plots / f"violation_{parameter}.{ext}", ext, dpi)

    lines = [f"# Study `{study.name}`", ""]
    if study.description:
        lines += [study.description, ""]
    fixed = ", ".join(f"{k} = {v!r}" for k, v in study.fixed.items()) or "none"
    lines += [f"Scenario `{study.scenario}`, {study.sampling.replace('_', ' ')} sampling, seed {study.seed}: "
              f"{len(rows)} of {study.n_samples} samples stored ({study.n_draws} draws × {len(tunings)} tunings). "
              f"Fixed: {fixed}. Varied: "
              + (", ".join(f"`{d.parameter}` {d.to_dict()}" for d in study.vary) or "nothing") + ".", "",
              "Violation: measured force > F_max at some step (ρ_min_meas < 0), or a filter fault: a sample whose "
              "filter (or nominal) faulted counts as a violation (a fault is never a pass; its figures stop at the "
              "fault and stay out of the distributions). Failed samples (an error outside the filter) have no "
              "verdict and are left out. Intervals at 95 %: Wilson, exact "
              "Clopper–Pearson, and the one-sided Clopper–Pearson upper bound (P(violation) < bound at 95 %; "
              "with 0 violations in n samples it is 1 − 0.05^(1/n)).", "",
              "| tuning | samples | failed | faulted | violations (faults included) | P(violation) | Wilson 95 % "
              "| Clopper–Pearson 95 % | P < (one-sided 95 %) | ρ_min_meas min / median / max "
              "| F max [N] median / p95 / max |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        v, rho, force = s["violation"], s["rho_min_meas"] or {}, s["force_max_N"] or {}
        exact = v.exact
        lines.append(f"| {s['tuning']} | {s['samples']} | {s['failed']} | {s['faulted']} | {v.k}/{v.n} "
                     f"| {_fmt(v.p, '.3f')} "
                     f"| [{v.low:.3f}, {v.high:.3f}] | [{exact[0]:.3f}, {exact[1]:.3f}] | {v.upper:.4f} "
                     f"| {_fmt(rho.get('q00'))} / {_fmt(rho.get('q50'))} / "
                     f"{_fmt(rho.get('q100'))} | {_fmt(force.get('q50'))} / {_fmt(force.get('q95'))} / "
                     f"{_fmt(force.get('q100'))} |")
    key = [f"- {short}: `{full}`" for full, short in zip(tunings, plot_labels(tunings)) if short != full]
    lines += [*(["", "Shortened tunings in the plots:", "", *key] if key else []),
              "", f"![rho](plots/rho_min_meas.{ext}) ![force](plots/force_max_N.{ext})", "",
              "All rows: `pandas.read_parquet(\"results.parquet\")` (one row per sample; columns: softcbf.study.store).", ""]
    if parameters:
        lines += sensitivity_markdown(rows, tunings, parameters, bins, level, ext)
    errors = [r for r in rows if not clean(r)]
    if errors:
        faults = sum(1 for r in errors if faulted(r))
        lines += [f"## Failed and faulted samples ({len(errors) - faults} failed, {faults} faulted)", ""]
        for r in errors[:MAX_ERRORS_LISTED]:
            fault = fault_of(r)
            first = (r.get("error") or "").splitlines()[0] if r.get("error") else (
                f"filter fault in the {fault['where']}: {fault['type']}: {fault['message']}" if fault else "")
            lines.append(f"- sample {r['sample']} (draw {r['draw']}, {r['tuning']}): {first}")
        lines.append("")
    path = store.root / REPORT_FILE
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def _best_so_far(rows: Sequence[Mapping[str, Any]], objective: str) -> tuple[list[int], list[float]]:
    """(evaluation counts, best objective so far) over the rows in evaluation order; failed and faulted rows
    (no value) keep the best."""
    x, y, best = [], [], None
    for row in rows:
        value = objective_value(dict(row), objective)
        if value is not None and (best is None or minimised(value, objective) < minimised(best, objective)):
            best = value
        if best is not None:
            x.append(int(row["sample"]) + 1)
            y.append(best)
    return x, y


def best_so_far_plot(curves: Mapping[str, Sequence[Mapping[str, Any]]], objective: str, path: Path,
                     figure_format: str, dpi: float) -> None:
    """The best objective so far against evaluations per curve (search, baseline), first violations marked (module
    docstring)."""
    with styled():
        fig = new_figure(SIZE_IN, dpi)
        ax = fig.add_subplot()
        for (label, rows), colour in zip(curves.items(), distinct_colors(curves)):
            x, y = _best_so_far(rows, objective)
            ax.step(x, y, where="post", color=colour, label=label)
            first = next((r for r in rows if violated(r)), None)
            if first is not None and faulted(first):
                ax.axvline(int(first["sample"]) + 1, color=colour, ls=":", lw=1.2,
                           label=f"{label}: first violation at {int(first['sample']) + 1} (a filter fault)")
            elif first is not None:
                ax.plot([int(first["sample"]) + 1], [objective_value(dict(first), objective)], "o", color=colour,
                        label=f"{label}: first violation at {int(first['sample']) + 1}")
        if objective.removeprefix("-").startswith("rho"):
            ax.axhline(0.0, color=LIMIT_COLOR, ls="--", lw=1.2, label="ρ = 0 (F = F_max)")
        ax.set_xlabel("evaluations [1]")
        ax.set_ylabel(("highest " if objective.startswith("-") else "least ") + metric_label(objective, " so far"))
        ax.grid(alpha=GRID_ALPHA)
        legend_outside(fig, [ax], loc="outside lower center")
        save_figure(fig, path, figure_format, dpi)


def write_falsify_report(root: str | Path, figure_format: str = "png", dpi: float = DPI) -> Path:
    """Write a falsification folder's report.md and plots/best_so_far.<figure_format> (module docstring)."""
    root = Path(root)
    state = json.loads((root / FALSIFY_FILE).read_text(encoding="utf-8"))
    objective = state["objective"]
    screen = state.get("screen")
    study = state["study"]
    curves = {}
    searched = (f"confirmed on {study['scenario']}" if screen else "search (" + state["sampler"] + ")", SEARCH_DIR)
    screened = ((f"screen on {screen['scenario']} ({state['sampler']})", f"{screen['dir']}/{SEARCH_DIR}")
                if screen else None)
    for label, folder in (searched, ("uniform random", BASELINE_DIR), *([screened] if screened else [])):
        if (root / folder / STUDY_FILE).is_file():
            curves[label] = StudyStore.open(root / folder).load_rows()
    if not any(curves.values()):
        raise ValueError(f"{root} holds no evaluations yet; run `study falsify` first")
    plots = root / PLOTS_DIR
    plots.mkdir(exist_ok=True)
    best_so_far_plot(curves, objective, plots / f"best_so_far.{figure_format}", figure_format, dpi)
    box = ", ".join(f"`{name}` {spec}" for name, spec in study["vary"].items()) or "none"
    lines = [f"# Falsification of study `{study['name']}`", "",
             f"Scenario `{study['scenario']}`, tunings {study['tunings']}; fixed: "
             + (", ".join(f"{k} = {v!r}" for k, v in study["fixed"].items()) or "none") + f". Box: {box}.", "",
             f"Objective: minimise `{objective}`" + (" (i.e. maximise it without the minus)" if objective.startswith("-")
                                                    else "") + f"; sampler {state['sampler']}, population "
             f"{state['population']}, generation 0 {state.get('initial', 'random')}, seed {state['seed']}, budget "
             f"{state['budget']}; status {state['status']}"
             + (f", stopped at the {state['stopped']}" if state.get("stopped") else "") + ".", "",
             "A filter fault is the worst value there is (a fault is never a pass): an evaluation that faulted is "
             "a violation and, if any did, the best.", "",
             "| | evaluations | failed | faulted | best | at evaluation | tuning | parameters | first violation |",
             "|---|---|---|---|---|---|---|---|---|"]
    best = state.get("best") or {}
    base = state.get("random_baseline") or {}
    for label, s, value in (("search", {**state, **best}, best.get("value")), ("uniform random", base, base.get("best"))):
        if not s.get("evaluations"):
            continue
        shown = (f"filter fault ({s['fault']['type']} in the {s['fault']['where']})" if s.get("fault")
                 else _fmt(value, '.6g'))
        params = ", ".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v!r}"
                           for k, v in (s.get("params") or {}).items()) or "–"
        lines.append(f"| {label} | {s['evaluations']} | {s['failed']} | {s.get('faulted', 0)} | {shown} | "
                     f"{_fmt(s.get('evaluation'), 'd')} | {s.get('tuning') or '–'} | {params} | "
                     f"{_fmt(s.get('first_violation'), 'd')} |")
    lines += ["", f"![best so far](plots/best_so_far.{figure_format})", ""]
    worst = state.get("worst")
    if worst and (worst.get("fault") or best.get("fault")):
        again = worst.get("fault")
        lines += ["## Worst case", "",
                  f"`{WORST_DIR}/` is a run folder of evaluation {worst['evaluation']} run alone: "
                  + (f"its filter faulted again ({again['type']} in the {again['where']}: {again['message']})"
                     if again else f"{objective.removeprefix('-')} = {_fmt(worst['value'], '.6g')}, no fault: the "
                                   "search's filter fault was NOT replayed")
                  + f". Replay: `softcbf run --config {root / WORST_DIR / 'config.json'}`.", ""]
    elif worst:
        same = worst["value"] == best.get("value")
        lines += ["## Worst case", "",
                  f"`{WORST_DIR}/` is a run folder of evaluation {worst['evaluation']} run alone: "
                  f"{objective.removeprefix('-')} = {_fmt(worst['value'], '.6g')} "
                  + ("(equal to the search's row, bit for bit)" if same else
                     f"(the search's row has {_fmt(best.get('value'), '.6g')}: NOT replayed)")
                  + f". Replay: `softcbf run --config {root / WORST_DIR / 'config.json'}`.", ""]
    baseline_rows = curves.get("uniform random") or []
    if baseline_rows:
        lines += ["## The uniform baseline as an estimate", "",
                  "Its draws are uniform over the box, so it estimates P(violation) over the box (the search's "
                  "evaluations are chosen, not drawn, and estimate nothing); a draw whose filter faulted counts "
                  "as a violation:", "",
                  "| tuning | faulted | violations (faults included) | P(violation) | Wilson 95 % | Clopper–Pearson 95 % "
                  "| P < (one-sided 95 %) |",
                  "|---|---|---|---|---|---|---|"]
        for tuning in study["tunings"]:
            v = Proportion.of(violated(r) for r in baseline_rows if r["tuning"] == tuning)
            faults = sum(1 for r in baseline_rows if r["tuning"] == tuning and faulted(r))
            exact = v.exact
            lines.append(f"| {tuning} | {faults} | {v.k}/{v.n} | {_fmt(v.p, '.3f')} | [{v.low:.3f}, {v.high:.3f}] | "
                         f"[{exact[0]:.3f}, {exact[1]:.3f}] | {v.upper:.4f} |")
        lines.append("")
    if screen:
        lines += screen_markdown(state)
    lines += [f"Rows: `{SEARCH_DIR}/` and `{BASELINE_DIR}/` are study folders (one Parquet part per evaluation; "
              "`softcbf study report` on either gives its own distributions); falsify.json holds the figures above.", ""]
    path = root / REPORT_FILE
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def screen_markdown(state: Mapping[str, Any]) -> list[str]:
    """report.md's section of a multi-fidelity falsification (`softcbf.study.screen`): both fidelities'
    evaluations, which screened evaluation each expensive one confirmed, and the expensive evaluations spent."""
    screen, scenario = state["screen"], state["study"]["scenario"]
    lines = ["## Multi-fidelity: screened, then confirmed", "",
             f"The box was searched on `{screen['scenario']}` ({screen['evaluations']} evaluations of a budget of "
             f"{screen['budget']}, {screen['faulted']} faulted, first violation there: "
             f"{_fmt(screen['first_violation'], 'd')}; folder `{screen['dir']}/`), and its worst distinct candidates "
             f"(at most {screen['confirm']}) were run on `{scenario}` in that order (`{SEARCH_DIR}/`). Expensive "
             f"evaluations spent: **{state['expensive_evaluations']}** on `{scenario}` ({len(state['confirmed'])} "
             "confirmations" + (" and the worst case's replay" if state.get("worst") else "") + ").", "",
             f"| evaluation on {scenario} | screened evaluation | {state['objective']} screened | "
             f"{state['objective']} confirmed | violated |", "|---|---|---|---|---|"]
    for c in state["confirmed"]:
        shown = f"filter fault ({c['fault']['type']})" if c.get("fault") else _fmt(c["value"], ".4g")
        lines.append(f"| {c['evaluation']} | {c['screen_evaluation']} | {_fmt(c['screen_value'], '.4g')} | {shown} | "
                     f"{'yes' if c['violated'] else 'no'} |")
    return lines + [""]


def campaign_markdown(state: Mapping[str, Any]) -> list[str]:
    """The ARCH-COMP table of a falsification campaign (`softcbf.study.campaign`): per filter and box, the
    falsification rate over the seeds and the evaluations to the first counterexample (median and range)."""
    screened = f", screened on `{state['screen']}`" if state.get("screen") else ""
    lines = [f"# Falsification campaign of study `{state['study']['name']}`", "",
             f"Scenario `{state['study']['scenario']}`{screened}; {len(state['seeds'])} seeds "
             f"({state['seeds'][0]}–{state['seeds'][-1]}), budget {state['budget']} evaluations per run"
             + (" (of the cheap scenario; the counts below are the expensive scenario's)" if state.get("screen") else "")
             + f", sampler {state['sampler']}, generation 0 {state['initial']}"
             + (", each run stopped after its first violation" if state["stop_on_violation"] else "") + ".", "",
             "Falsification rate: the fraction of runs that found a counterexample (ρ_min_meas < 0 or a filter fault) "
             "within the budget; evaluations to the first counterexample: over the runs that found one, counted "
             "from 1 (ARCH-COMP's falsification track). No counterexample in a run is no proof of safety.", "",
             "| filter | box | runs | falsified | rate | evaluations to first counterexample: median [min, max] "
             "| evaluations spent |", "|---|---|---|---|---|---|---|"]
    for row in state.get("table") or []:
        first = row["first_counterexample"]
        shown = f"{first['median']:g} [{first['min']}, {first['max']}]" if first else "–"
        lines.append(f"| {row['filter']} | {row['box']} | {row['runs']} | {row['falsified']} | "
                     f"{_fmt(row['rate'], '.2f')} | {shown} | {row['evaluations']} |")
    return lines + ["", f"Every run is a falsification folder: `filter_<i>/seed_<s>/` (i: the filter's index in the "
                        f"study's tunings); `{CAMPAIGN_FILE}` holds the table and every run's figures.", ""]


def write_campaign_report(root: str | Path) -> Path:
    """Write a falsification campaign folder's report.md (`campaign_markdown`); return its path."""
    root = Path(root)
    state = json.loads((root / CAMPAIGN_FILE).read_text(encoding="utf-8"))
    if state.get("status") != "done":
        raise ValueError(f"{root}'s campaign has not finished; continue it with `study falsify --seeds N --resume`")
    path = root / REPORT_FILE
    path.write_text("\n".join(campaign_markdown(state)), encoding="utf-8")
    return path
