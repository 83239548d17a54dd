"""The acting pressure's interval under a valve lag known only as an interval τ_p ∈ [τ_lo, τ_hi].

The valves follow ṗ = (u(t) − p)/τ_p (hPa, s) per segment, u piecewise constant: u_k from t_k on (u_0 = 0 hPa,
vented since t = −∞). Solved exactly, for t at or after the latest application time t_K,

    p(t) = u_K + Σ_{k=1..K} Δ_k e^{−(t − t_k)/τ_p},      Δ_k = u_{k−1} − u_k   (hPa, per segment),

(one jump: p = U + (0 − U) e^{−(t − t_1)/τ_p}). Each term is monotone in τ_p (e^{−a/τ} grows with τ for a ≥ 0),
so over τ_p ∈ [τ_lo, τ_hi] a term with Δ_k > 0 lies in [Δ_k e^{−a/τ_lo}, Δ_k e^{−a/τ_hi}] and one with Δ_k < 0 in
[Δ_k e^{−a/τ_hi}, Δ_k e^{−a/τ_lo}], and the sum in the sum of the intervals:

    p ∈ [u_K + S⁺(τ_lo) + S⁻(τ_hi),  u_K + S⁺(τ_hi) + S⁻(τ_lo)],   S^±(τ) = Σ_{±Δ_k > 0} Δ_k e^{−(t − t_k)/τ}.

(Sound for every τ_p in the interval, not only its ends; it can be wider than the set of pressures some one τ_p
gives, since the terms' worst τ_p need not agree.) The four sums S^±(τ_lo), S^±(τ_hi) decay exactly between
records, S ← S e^{−dt/τ}, and grow by the jump's positive or negative part at each record, so the tracker holds
4 (N,) arrays, not the history. τ = 0 (an ideal valve): the factor is 1 for dt = 0 (the pressure just before the
switch, its left limit) and 0 after.

The energy governor's certificate uses it for the lag term ½ Σ β_i (p_i − u_i)² (its worst over the interval, the
end farther from u_i: `controllers.governors.energy_governor.certificate`, "valve lag"), joined with the model's predicted
pressure p̂ (the interval's hull with p̂, so a model τ_p outside [τ_lo, τ_hi] is covered too). Assumption: the
commands recorded are those acting at the valves from the recorded times (the governor's own, as its predictor).
"""

from __future__ import annotations

import math

import numpy as np


def decay(dt: float, tau: float) -> float:
    """e^{−dt/τ} (1) for dt ≥ 0 s; for τ = 0, 1 at dt = 0 and 0 after (module docstring)."""
    if tau == 0.0:
        return 1.0 if dt == 0.0 else 0.0
    return math.exp(-dt / tau)


class PressureInterval:
    """The acting pressure's interval per segment for τ_p ∈ taus = (τ_lo, τ_hi) s (module docstring), n segments."""

    def __init__(self, taus: tuple[float, float], n: int) -> None:
        lo, hi = (float(t) for t in taus)
        if not 0.0 <= lo <= hi < math.inf:
            raise ValueError(f"the valve lag's interval must satisfy 0 <= tau_lo <= tau_hi < inf, got [{lo!r}, {hi!r}] s")
        self.taus = (lo, hi)
        self.time = -math.inf
        self.command = np.zeros(n)
        self.sums = np.zeros((4, n))  # S⁺(τ_lo), S⁻(τ_lo), S⁺(τ_hi), S⁻(τ_hi) at `time`

    def copy(self) -> "PressureInterval":
        """An independent copy (one per simulation of a batched governor)."""
        twin = PressureInterval(self.taus, self.command.size)
        twin.time, twin.command, twin.sums = self.time, self.command.copy(), self.sums.copy()
        return twin

    def decayed(self, t: float) -> np.ndarray:
        """The four sums at t ≥ the latest record (4, N)."""
        dt = t - self.time
        if dt < 0.0:
            raise ValueError(f"t = {t!r} s is before the latest record at {self.time!r} s")
        if math.isinf(self.time):
            return np.zeros_like(self.sums)
        lo, hi = (decay(dt, tau) for tau in self.taus)
        return self.sums * np.array([lo, lo, hi, hi])[:, None]

    def record(self, t: float, u) -> None:
        """The command u (N,) hPa acts from t (s) on (times must not decrease)."""
        u = np.asarray(u, dtype=float)
        sums = self.decayed(t)
        jump = self.command - u
        rise, fall = np.maximum(jump, 0.0), np.minimum(jump, 0.0)
        self.sums = sums + np.array([rise, fall, rise, fall])
        self.time, self.command = float(t), u.copy()

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(lowest, highest) acting pressure (N,) hPa at t ≥ the latest record, over every τ_p in the interval."""
        rise_lo, fall_lo, rise_hi, fall_hi = self.decayed(t)
        return self.command + rise_lo + fall_hi, self.command + rise_hi + fall_lo
