"""Sequential stop of a study: draw until P(violation) is bounded or a violation is found (docs/studies.md#sequential-stop).

Rule (`softcbf study run FILE --until-bound TARGET`). The study runs its draws in rounds
(`execute.run_study` with resume, so each round adds draws to the same folder). After a
round, per tuning t with k_t violations (ρ_min_meas < 0 or a filter fault, `analysis.violated`:
a fault is never a pass) among the n_t samples with a verdict, u_t is the one-sided Clopper–Pearson upper bound on P(violation)
at `confidence` (95 %; `analysis.clopper_pearson_upper`). Tuning t is settled when
u_t < TARGET (the claim "P(violation) < TARGET at 95 %" holds) or k_t ≥ 1 (a violation was
found: the claim cannot be made on this many draws). The study stops when every tuning is
settled, or when its `draws` are spent (then `bounded` is false for the tunings left).

Why stopping early keeps the bound valid: an unsettled tuning has k_t = 0, and with k = 0
the bound 1 − α^(1/n) (α = 1 − confidence) falls below TARGET exactly when
n ≥ n* = ⌊ln α / ln(1 − TARGET)⌋ + 1 (TARGET 0.01: n* = 299). So the procedure is "draw n*
samples unless a violation comes first", and a p ≥ TARGET passes it with probability
(1 − p)^n* ≤ α: the stated bound keeps its confidence.

Rounds: each round adds min(⌈n* / 4⌉, what the unsettled tunings still need) draws, so a
violation stops the study at most a quarter of n* draws after it happened (each round is one
`run_study` call, i.e. one pool start), and no round goes past n* for a tuning without
violations (failed samples do not count towards n_t, so a round may be added for them; faulted
samples count as violations and settle their tuning as violated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from softcbf.study.analysis import Proportion, violated
from softcbf.study.definition import Study
from softcbf.study.execute import StudyOutcome, run_study
from softcbf.study.store import StudyStore, faulted

ROUNDS = 4  # rounds to reach n* without violations


@dataclass(frozen=True)
class SequentialOutcome:
    """The study's draws run, per tuning its violation Proportion (with `.upper`; faulted samples are violations),
    whether it is settled and how many of its samples faulted, and the summed `run_study` outcomes."""

    draws: int
    violation: dict[str, Proportion]
    settled: dict[str, bool]
    target: float
    outcome: StudyOutcome
    faulted: dict[str, int]

    @property
    def bounded(self) -> dict[str, bool]:
        """Per tuning: whether "P(violation) < target" holds at the confidence."""
        return {t: p.k == 0 and p.upper < self.target for t, p in self.violation.items()}


def draws_needed(target: float, confidence: float = 0.95) -> int:
    """n*: the fewest violation-free samples whose one-sided Clopper–Pearson bound is below `target`."""
    if not 0 < target < 1:
        raise ValueError(f"until-bound target must lie in (0, 1), got {target}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    return math.floor(math.log(1 - confidence) / math.log1p(-target)) + 1


def run_until_bound(study: Study, out_dir: str | Path, target: float, *, confidence: float = 0.95,
                    resume: bool = False, **run: Any) -> SequentialOutcome:
    """Run `study` in rounds until every tuning is settled (module docstring); `run`: `run_study`'s other options."""
    if "samples" in run:
        raise ValueError("the sequential stop chooses the number of samples itself; give --until-bound or --samples")
    needed = draws_needed(target, confidence)
    step = math.ceil(needed / ROUNDS)
    tunings = list(study.tunings)
    draws = 0
    totals: StudyOutcome | None = None
    store = StudyStore.create(out_dir, study, resume=True) if resume else None  # refuses another study's folder
    while True:
        rows = store.load_rows() if store is not None else []
        violation = {t: Proportion.of((violated(r) for r in rows if r["tuning"] == t), confidence) for t in tunings}
        faults = {t: sum(1 for r in rows if r["tuning"] == t and faulted(r)) for t in tunings}
        settled = {t: p.k > 0 or p.upper < target for t, p in violation.items()}
        draws = max(draws, len({r["draw"] for r in rows}))
        if all(settled.values()) or draws >= study.n_draws:
            break
        short = max(needed - violation[t].n for t in tunings if not settled[t])
        draws = min(study.n_draws, draws + max(1, min(step, short)))
        outcome = run_study(study, out_dir, resume=store is not None, samples=draws * len(tunings), **run)
        store = StudyStore.open(out_dir)
        totals = outcome if totals is None else replace(
            outcome, skipped=totals.skipped, ran=totals.ran + outcome.ran, failed=totals.failed + outcome.failed,
            wall_s=totals.wall_s + outcome.wall_s, corrupted=totals.corrupted + outcome.corrupted,
            faulted=totals.faulted + outcome.faulted)
    if totals is None:  # a resumed folder that was settled already
        totals = StudyOutcome(study.n_samples, len(rows), 0, 0, 0.0, "none", 0)
    return SequentialOutcome(draws, violation, settled, target, totals, faults)
