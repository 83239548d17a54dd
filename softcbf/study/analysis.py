"""Study results → per-tuning distributions, violation probabilities with confidence intervals, sensitivities.

Violation. A sample violates when its measured margin `rho_min_meas` < 0, i.e. the
measured contact force exceeded F_max at some control step (ρ_meas = (n_max − n)/n_max
with ψ strictly increasing, so ρ_meas < 0 ⇔ F > F_max; docs/model.md#force-safe-set, docs/run-outputs.md),
or when its filter (or nominal) faulted (`store.faulted`): a fault is never a pass. A faulted
run stops at its fault, so its ρ_min_meas covers only the rows before it (1.0 for a filter that
raised at its first call) and says nothing about the filter; counted as safe, a filter that
never ran would earn "P(violation) < 0.99 %" from 300 draws. So a faulted sample counts in k
and n as a violation, its figures stay out of the quantiles, and every summary says how many
samples faulted. Samples that failed outside the filter (status "error": a bad parameter, a
dead worker) have no verdict and are counted apart, as failed.

Violation probability p = k/n with the Wilson score interval at confidence level 1 − α
(z = Φ⁻¹(1 − α/2), 1.96 for 95 %):

    centre = (k + z²/2) / (n + z²),  half = z √(k (n − k)/n + z²/4) / (n + z²)

which stays inside [0, 1] and is informative at k = 0 (upper bound ≈ 3.84/(n + 3.84)).

Beside it, the exact Clopper–Pearson bounds, which hold their confidence for every n and
p (Wilson's only approximately; it is the shorter interval). With X ~ Bin(n, p) and
F(k; n, p) = P(X ≤ k) = Σ_{i ≤ k} C(n, i) pⁱ (1 − p)ⁿ⁻ⁱ, strictly decreasing in p for k < n:

    two-sided at 1 − α:  low = p with P(X ≥ k; p) = α/2 (0 at k = 0),
                         high = p with F(k; n, p) = α/2 (1 at k = n)
    one-sided at 1 − α:  upper = p with F(k; n, p) = α   (1 at k = n)

the Beta quantiles B⁻¹(α/2; k, n − k + 1) and B⁻¹(1 − α/2; k + 1, n − k). At k = 0 the
one-sided bound is 1 − α^(1/n): 0 violations in 300 draws bound P(violation) below
0.99 % at 95 %, the figure a lab can publish. The bounds are solved by bisection on p
(to the last bit of a float) with F summed in log space (`binomial_cdf`).

Sensitivity. For a numeric varied parameter the range of its drawn values is cut into
`bins` equal-width bins (grid values: one bin per grid value); per tuning and bin,
p and its Wilson interval of the samples in that bin, marginalised over every other
varied parameter. `crossing` reads where such a curve first reaches a level (e.g. 5 %):
linear interpolation between bin centres, walking from the end of the range with the
lower probability. Non-numeric parameters get one bin per value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from softcbf.study.store import PARAM_PREFIX, faulted

QUANTILES = (0.0, 0.05, 0.5, 0.95, 1.0)
BISECTION_STEPS = 200  # more than enough to pin a bound in (0, 1) to the last bit of a float64


def wilson_interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval (low, high) for k successes in n trials; (0, 1) when n = 0."""
    if not (0 <= k <= n):
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if n == 0:
        return 0.0, 1.0
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    denom = n + z * z
    centre = (k + z * z / 2) / denom
    half = z * math.sqrt(k * (n - k) / n + z * z / 4) / denom
    # The interval always holds k/n, and its ends are exactly 0 at k = 0 and 1 at k = n;
    # rounding may miss both by an ulp, which would put k/n outside it.
    low = 0.0 if k == 0 else min(max(0.0, centre - half), k / n)
    high = 1.0 if k == n else max(min(1.0, centre + half), k / n)
    return low, high


def _check_counts(k: int, n: int, confidence: float) -> None:
    if not (0 <= k <= n):
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")


def binomial_cdf(k: int, n: int, p: float) -> float:
    """F(k; n, p) = P(X <= k) for X ~ Bin(n, p), summed in log space (exact to rounding for any n)."""
    if not (0 <= k <= n):
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"p must lie in [0, 1], got {p}")
    if k == n or p == 0.0:
        return 1.0
    if p == 1.0:
        return 0.0
    i = np.arange(1, k + 1, dtype=float)
    log_choose = np.concatenate(([0.0], np.cumsum(np.log(n - i + 1.0) - np.log(i))))
    log_terms = log_choose + np.arange(k + 1) * math.log(p) + (n - np.arange(k + 1)) * math.log1p(-p)
    top = float(log_terms.max())
    return min(1.0, math.exp(top) * float(np.exp(log_terms - top).sum()))


def _p_where_cdf_is(k: int, n: int, target: float) -> float:
    """The p in (0, 1) with F(k; n, p) = target (F falls strictly from 1 to 0 in p for k < n), by bisection."""
    low, high = 0.0, 1.0
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (low + high)
        if mid in (low, high):
            break
        if binomial_cdf(k, n, mid) > target:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def clopper_pearson_interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact two-sided Clopper–Pearson interval (low, high) for k successes in n trials (module docstring);
    (0, 1) when n = 0."""
    _check_counts(k, n, confidence)
    if n == 0:
        return 0.0, 1.0
    tail = (1.0 - confidence) / 2.0
    low = 0.0 if k == 0 else _p_where_cdf_is(k - 1, n, 1.0 - tail)
    high = 1.0 if k == n else _p_where_cdf_is(k, n, tail)
    return low, high


def clopper_pearson_upper(k: int, n: int, confidence: float = 0.95) -> float:
    """Exact one-sided upper Clopper–Pearson bound on p for k successes in n trials: 1 − (1 − confidence)^(1/n)
    at k = 0 (module docstring); 1 when n = 0."""
    _check_counts(k, n, confidence)
    if n == 0 or k == n:
        return 1.0
    return _p_where_cdf_is(k, n, 1.0 - confidence)


def violated(row: Mapping[str, Any]) -> bool | None:
    """Whether a row is a violation (module docstring): True when its filter faulted or its measured force
    exceeded F_max; None when it failed outside the filter or has no measured ρ."""
    if faulted(row):
        return True
    rho = row.get("rho_min_meas")
    if row.get("status") != "ok" or rho is None:
        return None
    return bool(rho < 0.0)


def clean(row: Mapping[str, Any]) -> bool:
    """Whether a row's run finished without a fault (status "ok", no fault): its figures are a verdict."""
    return row.get("status") == "ok" and not faulted(row)


@dataclass(frozen=True)
class Proportion:
    """k of n with its Wilson interval (low, high) at `confidence`, and its exact Clopper–Pearson bounds."""

    k: int
    n: int
    low: float
    high: float
    confidence: float = 0.95

    @property
    def p(self) -> float | None:
        return self.k / self.n if self.n else None

    @property
    def exact(self) -> tuple[float, float]:
        """The two-sided Clopper–Pearson interval at `confidence`."""
        return clopper_pearson_interval(self.k, self.n, self.confidence)

    @property
    def upper(self) -> float:
        """The one-sided Clopper–Pearson upper bound at `confidence` (what "P < … at 95 %" states)."""
        return clopper_pearson_upper(self.k, self.n, self.confidence)

    @classmethod
    def of(cls, flags: Iterable[bool | None], confidence: float = 0.95) -> "Proportion":
        values = [f for f in flags if f is not None]
        k = sum(values)
        return cls(k, len(values), *wilson_interval(k, len(values), confidence), confidence)


def _quantiles(values: Sequence[float]) -> dict[str, float] | None:
    finite = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if finite.size == 0:
        return None
    return {f"q{int(round(100 * q)):02d}": float(np.quantile(finite, q)) for q in QUANTILES}


def tuning_summary(rows: Sequence[Mapping[str, Any]], tunings: Sequence[str]) -> list[dict[str, Any]]:
    """Per tuning (in the given order): samples, failed (outside the filter), faulted, the violation Proportion
    (faulted samples count as violations), quantiles of ρ_min_meas and F max over the clean samples."""
    out = []
    for tuning in tunings:
        mine = [r for r in rows if r["tuning"] == tuning]
        finished = [r for r in mine if clean(r)]
        faults = sum(1 for r in mine if faulted(r))
        out.append({
            "tuning": tuning,
            "samples": len(mine),
            "failed": len(mine) - len(finished) - faults,
            "faulted": faults,
            "violation": Proportion.of(violated(r) for r in mine),
            "rho_min_meas": _quantiles([r.get("rho_min_meas") for r in finished]),
            "force_max_N": _quantiles([r.get("force_max_N") for r in finished]),
        })
    return out


def varied_parameters(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Names of the varied parameters present in the rows (without the `param.` prefix)."""
    names: dict[str, None] = {}
    for row in rows:
        for key in row:
            if key.startswith(PARAM_PREFIX):
                names[key[len(PARAM_PREFIX):]] = None
    return list(names)


@dataclass(frozen=True)
class Bin:
    """Samples whose parameter lies in [low, high] (numeric) or equals `value` (other types)."""

    low: float | None
    high: float | None
    value: Any
    violation: Proportion

    @property
    def centre(self) -> float | None:
        return None if self.low is None else 0.5 * (self.low + self.high)


def _numeric(values: Sequence[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def sensitivity(rows: Sequence[Mapping[str, Any]], parameter: str, tuning: str, bins: int = 6) -> list[Bin]:
    """Violation probability of `tuning` per bin of `parameter` (module docstring)."""
    if bins < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    key = PARAM_PREFIX + parameter
    mine = [r for r in rows if r["tuning"] == tuning and violated(r) is not None and r.get(key) is not None]
    values = [r[key] for r in mine]
    if not mine:
        return []
    distinct = sorted(set(values), key=lambda v: (str(type(v)), v))
    if not _numeric(values) or len(distinct) <= bins:
        return [Bin(float(v) if _numeric([v]) else None, float(v) if _numeric([v]) else None, v,
                    Proportion.of(violated(r) for r, x in zip(mine, values) if x == v)) for v in distinct]
    edges = np.linspace(min(values), max(values), bins + 1)
    which = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, bins - 1)
    return [Bin(float(edges[b]), float(edges[b + 1]), None,
                Proportion.of(violated(r) for r, w in zip(mine, which) if w == b)) for b in range(bins)]


def crossing(curve: Sequence[Bin], level: float = 0.05) -> dict[str, Any]:
    """Where a binned violation curve first reaches `level`, walking from its safer end.

    Returns {"value": parameter value or None, "direction": "increasing"/"decreasing",
    "status": "crosses" | "below" (never reaches it) | "above" (already at the safer end)}.
    Bins without samples are skipped; numeric bins only.
    """
    points = [(b.centre, b.violation.p) for b in curve if b.centre is not None and b.violation.n]
    if len(points) < 2:
        return {"value": None, "direction": None, "status": "too few bins"}
    x = [c for c, _ in points]
    p = [q for _, q in points]
    if p[-1] < p[0]:
        x, p, direction = x[::-1], p[::-1], "decreasing"
    else:
        direction = "increasing"
    if p[0] >= level:
        return {"value": x[0], "direction": direction, "status": "above"}
    for (x0, p0), (x1, p1) in zip(zip(x, p), zip(x[1:], p[1:])):
        if p1 >= level:
            return {"value": x0 + (level - p0) / (p1 - p0) * (x1 - x0), "direction": direction, "status": "crosses"}
    return {"value": None, "direction": direction, "status": "below"}
