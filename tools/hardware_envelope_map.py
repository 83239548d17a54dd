"""Map of the hardware envelope studies: where the paper's hardware tunings hold, and where Table II's ordering does.

Reads the study folders of studies/hardware_envelope*.toml (`softcbf study run … --out DIR`),
one per loop rate, each a grid over the arm's time constant d/k = 0.07 s × damping_scale and
the pressure lag τ_p, and writes:

- a figure (PNG): one panel per tuning plus one for the ordering; rows are (loop rate, τ_p),
  columns d/k; each cell is coloured by whether ρ_meas min ≥ 0 (holds, F ≤ F_max) and
  labelled with ρ_meas min. The grid is deterministic (one draw per cell), so a cell's
  violation probability is 0 or 1;
- a Markdown table (stdout, and --markdown FILE): per cell ρ_meas min of each tuning and
  whether the paper's Table II ordering holds: None < 0 < HW-Low < HW-High;
- per (loop rate, τ_p, tuning) the boundary: the smallest d/k of the grid from which the
  tuning holds at every larger d/k of the grid, and the largest d/k below it that violates.

A study that does not run None (the 20 and 50 Hz ones) takes None's ρ from the study at
the same τ_p and d/k that does (10 Hz): without a filter the loop rate only sets the
zero-order hold of the 0.01 Hz nominal. Ends with one JSON line (the boundaries).

    python tools/hardware_envelope_map.py runs/env10 runs/env20 runs/env50 \
        --figure docs/figures/hardware_envelope.png --markdown runs/hardware_envelope.md
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend must be chosen first
import numpy as np  # noqa: E402

from matplotlib.colors import ListedColormap  # noqa: E402

from softcbf.study.store import StudyStore  # noqa: E402
from softcbf_mj.outputs.palette import BLUE, VERMILLION, rgb  # noqa: E402

REFERENCE_TIME_CONSTANT_S = 0.07  # d/k of the reference arm (controllers.model.params)
TUNINGS = ("None", "HW-Low", "HW-High")
ORDERING = "Table II order"
PAPER_TABLE_II = {"None": -0.780, "HW-Low": 0.594, "HW-High": 0.767}


def load_cells(folders: list[Path]) -> dict[tuple[float, float, float], dict[str, float]]:
    """{(loop rate Hz, τ_p s, d/k s): {tuning: ρ_meas min}} from every study folder's ok rows."""
    cells: dict[tuple[float, float, float], dict[str, float]] = {}
    for folder in folders:
        store = StudyStore.open(folder)
        rate = float(store.study.fixed["control_rate"])
        for row in store.load_rows():
            if row["status"] != "ok" or row.get("rho_min_meas") is None:
                continue
            key = (rate, float(row["param.tau_p"]), round(REFERENCE_TIME_CONSTANT_S * float(row["param.damping_scale"]), 6))
            cells.setdefault(key, {})[row["tuning"]] = float(row["rho_min_meas"])
    for (rate, tau_p, dk), rho in cells.items():
        if "None" not in rho:
            donors = [r["None"] for (other, t, d), r in cells.items() if (t, d) == (tau_p, dk) and "None" in r]
            if donors:
                rho["None"] = donors[0]
    return cells


def ordering_holds(rho: dict[str, float]) -> bool | None:
    """Table II's ordering None < 0 < HW-Low < HW-High (None when a tuning is missing)."""
    if not all(t in rho for t in TUNINGS):
        return None
    return rho["None"] < 0.0 < rho["HW-Low"] < rho["HW-High"]


# violated (0) and holds (1), from the project's colour-blind-safe palette, light enough for black labels
HOLDS_CMAP = ListedColormap([[c / 255 for c in rgb(VERMILLION, 0.45)], [c / 255 for c in rgb(BLUE, 0.55)]])


def boundaries(cells: dict) -> list[dict]:
    """Per (loop rate, τ_p, tuning): the smallest d/k from which it holds at every larger grid d/k
    (`holds_from_dk_s`), the largest d/k below that where it is violated, and every d/k where it holds
    (`holds_at_dk_s`: the ordering is not monotone in d/k)."""
    out = []
    for rate, tau_p in sorted({(r, t) for r, t, _ in cells}):
        dks = sorted(d for r, t, d in cells if (r, t) == (rate, tau_p))
        for tuning in (*TUNINGS[1:], ORDERING):
            holds = []
            for d in dks:
                rho = cells[(rate, tau_p, d)]
                holds.append(ordering_holds(rho) if tuning == ORDERING else (rho[tuning] >= 0.0 if tuning in rho else None))
            first = len(dks)  # start of the trailing run of holding cells
            while first > 0 and holds[first - 1] is True:
                first -= 1
            violating = [d for d, h in zip(dks[:first], holds[:first]) if h is False]
            out.append({"control_rate_Hz": rate, "tau_p_s": tau_p, "tuning": tuning,
                        "holds_from_dk_s": dks[first] if first < len(dks) else None,
                        "violates_at_dk_s": violating[-1] if violating else None,
                        "holds_at_dk_s": [d for d, h in zip(dks, holds) if h is True]})
    return out


def markdown(cells: dict) -> str:
    lines = ["| loop [Hz] | camera [fps] | τ_p [s] | d/k [s] | None | HW-Low | HW-High | None < 0 < Low < High |",
             "|---:|---:|---:|---:|---:|---:|---:|:---:|"]
    for (rate, tau_p, dk), rho in sorted(cells.items()):
        values = " | ".join(f"{rho[t]:+.3f}" if t in rho else "–" for t in TUNINGS)
        ok = ordering_holds(rho)
        lines.append(f"| {rate:g} | {max(12.8, rate):g} | {tau_p:g} | {dk:.3g} | {values} | "
                     f"{'–' if ok is None else ('yes' if ok else 'no')} |")
    return "\n".join(lines)


def figure(cells: dict, path: Path) -> None:
    rows = sorted({(r, t) for r, t, _ in cells})
    dks = sorted({d for _, _, d in cells})
    panels = (*TUNINGS, ORDERING)
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 0.55 * len(rows) + 1.6), sharey=True)
    for ax, panel in zip(axes, panels):
        grid = np.full((len(rows), len(dks)), np.nan)
        for i, (rate, tau_p) in enumerate(rows):
            for j, d in enumerate(dks):
                rho = cells.get((rate, tau_p, d), {})
                ok = ordering_holds(rho) if panel == ORDERING else (rho[panel] >= 0.0 if panel in rho else None)
                if ok is not None:
                    grid[i, j] = float(ok)
                label = "" if panel == ORDERING or panel not in rho else f"{rho[panel]:+.3f}"
                if panel == ORDERING and ok is not None:
                    label = "yes" if ok else "no"
                ax.text(j, i, label, ha="center", va="center", fontsize=6.5)
        ax.imshow(grid, cmap=HOLDS_CMAP, vmin=0.0, vmax=1.0, aspect="auto")
        ax.set_xticks(range(len(dks)), [f"{d:.2g}" for d in dks], fontsize=7)
        ax.set_xlabel("arm time constant d/k [s]", fontsize=8)
        ax.set_title(panel if panel == ORDERING else f"{panel}: ρ_meas min (paper {PAPER_TABLE_II[panel]:+.3f})",
                     fontsize=8)
    axes[0].set_yticks(range(len(rows)), [f"{r:g} Hz, τ_p {t:g} s" for r, t in rows], fontsize=7)
    fig.suptitle("camera_loop, paper's hardware tunings: blue = ρ_meas min ≥ 0 (F ≤ F_max), vermillion = violated "
                 "(deterministic grid: P(violation) = 0 or 1 per cell)", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=Path, help="study folders of studies/hardware_envelope*.toml")
    parser.add_argument("--figure", type=Path, default=Path("docs/figures/hardware_envelope.png"))
    parser.add_argument("--markdown", type=Path, help="also write the table to this file")
    args = parser.parse_args()
    cells = load_cells(args.folders)
    if not cells:
        raise SystemExit("no finished ok samples in " + ", ".join(map(str, args.folders)))
    table = markdown(cells)
    print(table)
    if args.markdown:
        args.markdown.write_text(table + "\n", encoding="utf-8")
    figure(cells, args.figure)
    found = boundaries(cells)
    for b in found:
        held, broke, at = b["holds_from_dk_s"], b["violates_at_dk_s"], b["holds_at_dk_s"]
        where = (f"holds from d/k = {held:.3g} s up" if held is not None else
                 "holds at d/k = " + ", ".join(f"{d:.3g}" for d in at) + " s only" if at else "holds at no grid d/k")
        print(f"{b['control_rate_Hz']:g} Hz, τ_p {b['tau_p_s']:g} s, {b['tuning']}: {where}"
              f"{'' if broke is None else f', last violated at d/k = {broke:.3g} s'}")
    print(f"figure: {args.figure}")
    print(json.dumps({"cells": len(cells), "boundaries": found}))


if __name__ == "__main__":
    main()
