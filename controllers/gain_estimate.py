"""Online estimate of the actuator gain scale g from rest samples out of contact, with a certified interval.

The true arm's gains are g·λ_i, one unknown scale g for every segment (dimensionless; the contact
certificate, `controllers.energy_governor`, certifies an interval [g_lo, g_hi] of it). The model
(docs/model.md#rppr-dynamics, no gravity, no contact) is

    M(q) q̈ + C(q, q̇) q̇ + D q̇ + K q = g Λ p,

so at a sample with the model's pressure p (hPa, the lag `controllers.state_predictor` integrates
from the commands) and the estimate (q̂, q̂̇) (rad, rad/s),

    y = q̂ + K⁻¹D q̂̇ = g x + δ,      x = K⁻¹Λ p (rad, the model's rest shape of p),
    δ = (q̂ − q) + K⁻¹D (q̂̇ − q̇) − K⁻¹(M q̈ + C q̇)   (rad):

the estimate's error and the arm's acceleration and Coriolis torque, all small near rest.

Estimator. Least squares in the energy norm |v|²_K = vᵀKv (J for v in rad): over the accepted
samples s,  ĝ = Σ_s x_sᵀK y_s / Σ_s |x_s|²_K.  Then ĝ − g = Σ_s x_sᵀKδ_s / Σ_s |x_s|²_K, and with
|δ_s,i| ≤ Δ per segment (`noise_rad`), |δ_s|_K ≤ Δ √(Σ_i k_i) = Δ_K, Cauchy–Schwarz per sample gives

    |ĝ − g| ≤ e = Δ_K Σ_s |x_s|_K / Σ_s |x_s|²_K,

a worst-case bound (it does not shrink with the sample count: δ need not average out, e.g. a
calibration offset of the camera); one sample at |x|_K gives e = Δ_K/|x|_K, e.g. Δ = 5e-3 rad at
the rest shape that presses the plate (≈ 0.38 rad per segment on the reference arm): e ≈ 0.013.
A sample is kept only when it makes e smaller (|x_s|_K > Σ|x|²_K / Σ|x|_K over the samples kept
so far) and when alone it would bound g to within a quarter of the prior's width (Δ_K/|x_s|_K ≤
INFORMATIVE·(hi − lo)): every subset of samples gives a valid bound, and the samples near x = 0
(the arm near its vented shape) tell little of g while their δ is largest where the arm starts
from rest: the MuJoCo rod's fast modes after the first pressure step read as δ up to 0.013 rad
in its first 5 ms (`softcbf bench` case mujoco_push_120, p from 0 towards 74 hPa), ≤ 0.002 rad
from 80 ms (x ≥ 0.12 rad) on; the quarter keeps x ≥ 0.1 rad for Δ = 5e-3 rad and the prior
[0.9, 1.1].

Interval. The narrowed interval after each accepted sample is I ← I ∩ [ĝ − e, ĝ + e], starting
from the prior [g_lo, g_hi]: under the assumptions each of these intervals contains g, so does
their intersection, and I only shrinks (a command the certificate held on I stays certified on
any sub-interval: the margin's minimum over fewer gains is no smaller). An empty intersection
proves an assumption false (|δ| > Δ somewhere, g not constant, contact in a sample): the
estimator then returns the prior for good (`inconsistent`; `reset` starts afresh).

Assumptions of "g ∈ I": (1) |δ_s,i| ≤ Δ at every accepted sample: the estimate's error within Δ
and the arm near rest (the caller accepts a sample only with |q̂̇_i| ≤ `rest_rad_s` and the
pressure settled, |λ_i/k_i (p_i − u_i)| ≤ Δ, so that the rest shape has no more than Δ to move;
the remaining M q̈ + C q̇ is what Δ must also cover: an arm ringing through q̇ ≈ 0 is not near
rest); (2) g constant and one scale for every segment; (3) no external force on the arm in the
accepted samples (the caller takes samples only with the model's tip at least `clearance_m` clear
of every facet plane: the plate's position error and the tip's estimate error must be below it);
(4) the model's K, D, Λ and the pressure lag are the arm's (K's error reads as a gain error).
"""

from __future__ import annotations

import math

import numpy as np

INFORMATIVE = 0.25
"""A sample is kept only if its own bound Δ_K/|x|_K is at most this fraction of the prior's width (module docstring)."""


class GainEstimator:
    """Least-squares gain scale ĝ and its certified interval (module docstring).

    stiffness k (N,) N·m/rad, rest_per_hPa a = λ/k (N,) rad/hPa, damping d (N,) N·m·s/rad, the prior
    [lo, hi] (1), noise_rad Δ (rad). `sample(p, y)` adds one sample (the caller has checked rest or
    the differences, and contact); `interval` is the certified interval, the prior until a sample narrows it.
    """

    def __init__(self, stiffness, rest_per_hPa, damping, prior: tuple[float, float], noise_rad: float) -> None:
        self.k = np.asarray(stiffness, dtype=float)
        self.a = np.asarray(rest_per_hPa, dtype=float)
        self.damping_ratio = np.asarray(damping, dtype=float) / self.k  # K⁻¹D (s)
        if not (self.k.shape == self.a.shape == self.damping_ratio.shape and self.k.ndim == 1 and np.all(self.k > 0)):
            raise ValueError(f"stiffness, rest_per_hPa and damping must be (N,) with stiffness > 0, got "
                             f"{self.k.tolist()}, {self.a.tolist()}, {self.damping_ratio.tolist()}")
        lo, hi = (float(v) for v in prior)
        if not 0.0 < lo <= hi < math.inf:
            raise ValueError(f"the prior gain interval must satisfy 0 < lo <= hi < inf, got [{lo!r}, {hi!r}]")
        if not 0.0 <= noise_rad < math.inf:
            raise ValueError(f"noise_rad must be finite and >= 0, got {noise_rad!r}")
        self.prior = (lo, hi)
        self.noise_rad = float(noise_rad)
        self.noise_K = self.noise_rad * math.sqrt(float(np.sum(self.k)))  # Δ_K (J^{1/2})
        self.reset()

    def reset(self) -> None:
        """Forget every sample: the interval is the prior again."""
        self.sum_xy = self.sum_xx = self.sum_x = 0.0
        self.samples = 0
        self.interval = self.prior
        self.inconsistent = False

    @property
    def estimate(self) -> float:
        """ĝ (1), NaN before the first accepted sample."""
        return self.sum_xy / self.sum_xx if self.sum_xx > 0.0 else math.nan

    @property
    def bound(self) -> float:
        """e (1): |ĝ − g| ≤ e under the assumptions; inf before the first accepted sample."""
        return self.noise_K * self.sum_x / self.sum_xx if self.sum_xx > 0.0 else math.inf

    def rest_residual(self, q, qd) -> np.ndarray:
        """y = q̂ + K⁻¹D q̂̇ (N,) rad: the rest sample's K⁻¹ × (C + D)q̇ + Kq, with C q̇ and M q̈ left to Δ."""
        return np.asarray(q, dtype=float) + self.damping_ratio * np.asarray(qd, dtype=float)

    def sample(self, p, y) -> bool:
        """Add the sample (p, y): the model's pressure p (N,) hPa and y = K⁻¹(M q̈ + (C + D) q̇ + K q) (N,) rad
        (`rest_residual` at rest); kept if it narrows e; returns whether it was kept."""
        if self.inconsistent:
            return False
        x, y = self.a * np.asarray(p, dtype=float), np.asarray(y, dtype=float)
        xx = float(np.sum(self.k * x * x))
        norm = math.sqrt(xx)
        if not (self.noise_K <= INFORMATIVE * (self.prior[1] - self.prior[0]) * norm
                and norm > (self.sum_xx / self.sum_x if self.sum_x > 0.0 else 0.0)):
            return False
        self.sum_xy += float(np.sum(self.k * x * y))
        self.sum_xx += xx
        self.sum_x += norm
        self.samples += 1
        g, e = self.estimate, self.bound
        lo, hi = max(self.interval[0], g - e), min(self.interval[1], g + e)
        if lo > hi:  # no gain fits every kept sample within Δ: an assumption is false
            self.inconsistent, self.interval = True, self.prior
        else:
            self.interval = (lo, hi)
        return True
