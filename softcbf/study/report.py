"""A study folder's report: PNG plots and a Markdown summary (`softcbf.study.analysis`).

`write_report(DIR, level=0.05, bins=6)` reads DIR's rows and writes:

    DIR/report.md                      per tuning: samples, failed, violation probability with its
                                       95 % Wilson interval, quantiles of ρ_min_meas and F max [N];
                                       per varied parameter and tuning: where the binned violation
                                       probability reaches `level`; the first failed samples' errors
    DIR/plots/rho_min_meas.png         ρ_min_meas per sample, by tuning (dots over box plots)
    DIR/plots/force_max_N.png          peak measured force [N] per sample, by tuning, F_max marked
                                       when the study fixes one (scenario parameter `f_max`)
    DIR/plots/violation_<param>.png    binned violation probability vs the parameter, per tuning,
                                       with Wilson intervals and the `level` line
    DIR/results.parquet                every row in one file (`StudyStore.compact`)

Plots use matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend must be chosen first

from softcbf.study.analysis import crossing, sensitivity, tuning_summary, varied_parameters  # noqa: E402
from softcbf.study.store import StudyStore  # noqa: E402

REPORT_FILE = "report.md"
PLOTS_DIR = "plots"
MAX_ERRORS_LISTED = 5


def _fmt(value: Any, spec: str = ".4g") -> str:
    return "–" if value is None else format(value, spec)


def _distribution_plot(rows: Sequence[Mapping[str, Any]], tunings: Sequence[str], key: str, label: str,
                       path: Path, line: float | None = None) -> None:
    data = [[r[key] for r in rows if r["tuning"] == t and r["status"] == "ok" and r.get(key) is not None]
            for t in tunings]
    fig, ax = plt.subplots(figsize=(1.6 + 1.3 * len(tunings), 4))
    if any(data):
        ax.boxplot([d if d else [float("nan")] for d in data], showfliers=False)
    for i, d in enumerate(data, start=1):
        ax.plot([i] * len(d), d, ".", alpha=0.5, color="C0")
    ax.set_xticks(range(1, len(tunings) + 1), tunings)
    if line is not None:
        ax.axhline(line, color="C3", ls="--", lw=1)
    ax.set_ylabel(label)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _sensitivity_plot(rows: Sequence[Mapping[str, Any]], tunings: Sequence[str], parameter: str, bins: int,
                      level: float, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6, 4))
    for i, tuning in enumerate(tunings):
        curve = [b for b in sensitivity(rows, parameter, tuning, bins) if b.violation.n and b.centre is not None]
        if not curve:
            continue
        x = [b.centre for b in curve]
        p = [b.violation.p for b in curve]
        err = [[q - b.violation.low for q, b in zip(p, curve)], [b.violation.high - q for q, b in zip(p, curve)]]
        ax.errorbar(x, p, yerr=err, marker="o", capsize=3, label=tuning, color=f"C{i}")
    ax.axhline(level, color="k", ls=":", lw=1, label=f"{100 * level:g} %")
    ax.set_xlabel(parameter)
    ax.set_ylabel("P(F > F_max)")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(root: str | Path, level: float = 0.05, bins: int = 6) -> Path:
    """Write DIR/report.md, DIR/plots/*.png and DIR/results.parquet; return the report's path."""
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
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
    f_max = study.fixed.get("f_max")
    _distribution_plot(rows, tunings, "rho_min_meas", "ρ_min measured", plots / "rho_min_meas.png", line=0.0)
    _distribution_plot(rows, tunings, "force_max_N", "peak measured force [N]", plots / "force_max_N.png", line=f_max)
    parameters = varied_parameters(rows)
    for parameter in parameters:
        _sensitivity_plot(rows, tunings, parameter, bins, level, plots / f"violation_{parameter}.png")

    lines = [f"# Study `{study.name}`", ""]
    if study.description:
        lines += [study.description, ""]
    fixed = ", ".join(f"{k} = {v!r}" for k, v in study.fixed.items()) or "none"
    lines += [f"Scenario `{study.scenario}`, {study.sampling.replace('_', ' ')} sampling, seed {study.seed}: "
              f"{len(rows)} of {study.n_samples} samples stored ({study.n_draws} draws × {len(tunings)} tunings). "
              f"Fixed: {fixed}. Varied: "
              + (", ".join(f"`{d.parameter}` {d.to_dict()}" for d in study.vary) or "nothing") + ".", "",
              "Violation: measured force > F_max at some step (ρ_min_meas < 0); 95 % Wilson intervals.", "",
              "| tuning | samples | failed | violations | P(violation) | 95 % CI | ρ_min_meas min / median / max "
              "| F max [N] median / p95 / max |",
              "|---|---|---|---|---|---|---|---|"]
    for s in summary:
        v, rho, force = s["violation"], s["rho_min_meas"] or {}, s["force_max_N"] or {}
        lines.append(f"| {s['tuning']} | {s['samples']} | {s['failed']} | {v.k}/{v.n} | {_fmt(v.p, '.3f')} "
                     f"| [{v.low:.3f}, {v.high:.3f}] | {_fmt(rho.get('q00'))} / {_fmt(rho.get('q50'))} / "
                     f"{_fmt(rho.get('q100'))} | {_fmt(force.get('q50'))} / {_fmt(force.get('q95'))} / "
                     f"{_fmt(force.get('q100'))} |")
    lines += ["", "![rho](plots/rho_min_meas.png) ![force](plots/force_max_N.png)", ""]
    if parameters:
        lines += [f"## Sensitivity: where P(violation) reaches {100 * level:g} %", "",
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
        lines += [""] + [f"![{p}](plots/violation_{p}.png)" for p in parameters] + [""]
    errors = [r for r in rows if r["status"] != "ok"]
    if errors:
        lines += [f"## Failed samples ({len(errors)})", ""]
        for r in errors[:MAX_ERRORS_LISTED]:
            first = (r.get("error") or "").splitlines()[0] if r.get("error") else ""
            lines.append(f"- sample {r['sample']} (draw {r['draw']}, {r['tuning']}): {first}")
        lines.append("")
    path = store.root / REPORT_FILE
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
