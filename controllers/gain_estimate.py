"""Online estimate of the actuator gain scale g from samples out of contact and in contact at the tip, with a certified interval.

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
|δ_s,i| ≤ Δ per segment (`noise_rad`) the worst case per sample is |x_sᵀKδ_s| ≤ Δ w_s, w_s = Σ_i k_i |x_s,i|
(N·m; Hölder: the maximum over the box |δ_i| ≤ Δ, reached at δ_i = Δ sign(k_i x_s,i)), so

    |ĝ − g| ≤ e = Δ Σ_s w_s / Σ_s |x_s|²_K,

a worst-case bound (it does not shrink with the sample count: δ need not average out, e.g. a
calibration offset of the camera); one sample gives e = Δ w/|x|²_K (≤ Δ√(Σk_i)/|x|_K, Cauchy–Schwarz,
with equality when every k_i |x_i| is the same), e.g. Δ = 5e-3 rad at the rest shape that presses the
plate (≈ 0.38 rad per segment on the reference arm): e = Δ/0.38 ≈ 0.013.
A sample is kept only when it makes e smaller (|x_s|²_K / w_s > Σ|x|²_K / Σw over the samples kept
so far) and when alone it would bound g to within a quarter of the prior's width (Δ w_s/|x_s|²_K ≤
INFORMATIVE·(hi − lo)): every subset of samples gives a valid bound, and the samples near x = 0
(the arm near its vented shape) tell little of g while their δ is largest where the arm starts
from rest: the MuJoCo rod's fast modes after the first pressure step read as δ up to 0.013 rad
in its first 5 ms (`softcbf bench` case mujoco_push_120, p from 0 towards 74 hPa), ≤ 0.002 rad
from 80 ms (x ≥ 0.12 rad) on; the quarter keeps x ≥ 0.1 rad for Δ = 5e-3 rad and the prior
[0.9, 1.1].

In contact (`sample_in_contact`). Where the tip presses facet j with the force F_j n̂_j (N; n̂_j the
facet's outward unit normal, F_j ≥ 0 unknown: any plate, its stiffness and position need not be known),
the plate adds −J_r(q)ᵀn̂_j F_j (N·m) to the right-hand side, so

    y = g x − Σ_j z_j F_j + δ,      z_j = K⁻¹J_r(q̂)ᵀn̂_j (rad/N),

with δ as above plus Σ_j F_j K⁻¹(J_r(q) − J_r(q̂))ᵀn̂_j, the force's direction error from the estimate
(on the reference arm ≤ F |∂J_r/∂q| |q̂ − q|/k ≈ 0.2 N · 0.25 m · 1e-3 rad / 1 N·m/rad = 5e-5 rad at
1.2 F_max: within Δ). Eliminate the unknown forces: let Π be the K-orthogonal projection onto the
complement of Z = span{z_j} (Πv = v − Z(ZᵀKZ)⁺ZᵀKv; self-adjoint in ⟨·,·⟩_K, Πz_j = 0) and
x̃ = Πx. Then

    x̃ᵀK y = g x̃ᵀK x + x̃ᵀKδ = g |x̃|²_K + x̃ᵀKδ      (x̃ᵀK z_j = 0, x̃ᵀKx = x̃ᵀKΠx = |x̃|²_K),

the out-of-contact sample's equation with x̃ in place of x, whatever the F_j (their sign is not used),
and |x̃ᵀKδ| ≤ Δ w̃, w̃ = Σ_i k_i |x̃_i|. So the same sums hold both kinds: ĝ = Σ_s x̃_sᵀK y_s / Σ_s |x̃_s|²_K,
|ĝ − g| ≤ e = Δ Σ_s w̃_s / Σ_s |x̃_s|²_K (x̃_s = x_s out of contact), and the rules above apply to x̃.
One sample alone bounds g to e = Δ w̃/|x̃|²_K ≤ Δ√(Σk_i)/(|x|_K sin θ), θ the K-angle between x and Z:
for N = 2 and one facet θ is the angle between the rest shape's direction and the plate's generalised
force (measured on camera_push_120 at the arm's rest against the plate: θ = 28.6°, |x|_K = 0.43 rad,
|x̃|_K = 0.205 rad, e = 0.030 for Δ = 5e-3 rad: docs/results.md). Degenerate cases give x̃ ≈ 0 and the
sample is refused by the INFORMATIVE rule: x nearly along Z (the rest shape pushes straight into the
plate: a stronger actuator reads as a harder plate), and for N = 2 two facets in contact (a corner: Z
is the whole space). Directions of Z with a singular value > 0 are all eliminated (eliminating more is
always sound: it only loses information). A tangential force (friction, or a surface that tilts as a
flexure sheet bends) is a force along J_rᵀt̂_j too (t̂_j the facet's tangent): the caller then passes
both directions (c-erg's `gain_contact="any"`: for N = 2 and one facet nothing is left, so no sample
in contact); passing n̂_j alone there leaves F_t K⁻¹J_rᵀt̂_j in δ, which Δ does not bound.

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
rest; measured at c-erg's samples against the plate on the camera loop, the deviation x̃ᵀKδ/w̃ that
Δ must bound reached 3.3e-3 rad with |q̂̇_i| ≤ 0.02 rad/s, 1.32e-3 rad with |q̂̇_i| ≤ 3e-3 rad/s, and
1.43e-3 rad with the arm also at rest for 0.2 s before (c-erg's `gain_rest_s`: it removes the samples taken
while the arm rings through q̂̇ ≈ 0, but not the camera's error at rest: ≤ 9e-5 rad on the pushes asking
0.3 and 0.6 F_max, ≤ 8.6e-4 rad on those delivering ≈ 0.81 F_max, up to 1.43e-3 rad at the one or two
samples some mismatch draws take at their sinusoid's peak: the camera's estimate of the distal segment, off by
1–2.3e-3 rad there, where the MuJoCo arm's own q deviates by ≤ 4.5e-4 rad) (tools/gain_contact_samples.py --replay, docs/results.md); (2) g constant and one scale for every
segment; (3) no external force on the arm in the accepted samples (the caller takes samples only
with the model's tip at least `clearance_m` clear of every facet plane: the plate's position error
and the tip's estimate error must be below it)
except, in the samples in contact, forces at the tip along the directions passed, from the facets
within `clearance_m` (the arm touches the plates with its tip only; with `gain_contact="normal"` the
contact is frictionless and the plate's surface normal is n̂_j, as the MuJoCo plant's ideal plate:
condim 1, a box on a slide along n̂_j, its contact with the tip sphere through the sphere's centre r);
(4) the model's K, D, Λ and the pressure lag are the arm's (K's error reads as a gain error).
"""

from __future__ import annotations

import math

import numpy as np

GAIN_CONTACT = ("normal", "any", "off")
"""The plate forces a caller eliminates from a sample with the tip near a facet (c-erg's `gain_contact`): along the
facet's normal (a frictionless plate), along its normal and tangent (any force at the tip), or no sample there."""

ROUNDING = 1e-12
"""Added to e (1): the sums' round-off (relative 1e-16 per operation on a gain near 1), so that the worst case
δ_i = Δ sign(k_i x_i), where the bound is exact, does not put g an ulp outside the interval."""

INFORMATIVE = 0.25
"""A sample is kept only if its own bound Δ w/|x|²_K is at most this fraction of the prior's width (module docstring)."""


class GainEstimator:
    """Least-squares gain scale ĝ and its certified interval (module docstring).

    stiffness k (N,) N·m/rad, rest_per_hPa a = λ/k (N,) rad/hPa, damping d (N,) N·m·s/rad, the prior
    [lo, hi] (1), noise_rad Δ (rad). `sample(p, y)` adds one sample out of contact, `sample_in_contact(p, y,
    torques)` one whose tip may be pushed along known directions (the caller has checked rest or the differences,
    and which facets may touch); `interval` is the certified interval, the prior until a sample narrows it.
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
        self.reset()

    def reset(self) -> None:
        """Forget every sample: the interval is the prior again."""
        self.sum_xy = self.sum_xx = self.sum_w = 0.0  # Σ x̃ᵀKy (J), Σ |x̃|²_K (J), Σ w̃ (N·m)
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
        return self.noise_rad * self.sum_w / self.sum_xx + ROUNDING if self.sum_xx > 0.0 else math.inf

    def rest_residual(self, q, qd) -> np.ndarray:
        """y = q̂ + K⁻¹D q̂̇ (N,) rad: the rest sample's K⁻¹ × (C + D)q̇ + Kq, with C q̇ and M q̈ left to Δ."""
        return np.asarray(q, dtype=float) + self.damping_ratio * np.asarray(qd, dtype=float)

    def sample(self, p, y) -> bool:
        """Add the sample (p, y) out of contact: the model's pressure p (N,) hPa and y = K⁻¹(M q̈ + (C + D) q̇ + K q)
        (N,) rad (`rest_residual` at rest); kept if it narrows e; returns whether it was kept."""
        if self.inconsistent:
            return False
        return self._add(self.a * np.asarray(p, dtype=float), np.asarray(y, dtype=float))

    def sample_in_contact(self, p, y, torques) -> bool:
        """Add the sample (p, y) of an arm whose tip is pushed by unknown forces along known directions (module
        docstring, "in contact"): torques (N, m) holds in its columns the generalised forces per newton J_r(q̂)ᵀv
        (m) of the m possible force directions v (each facet's n̂_j, and t̂_j where the force may be tangential);
        their span is eliminated. p, y as `sample`; returns whether it was kept."""
        torques = np.asarray(torques, dtype=float)
        if torques.ndim != 2 or torques.shape[0] != self.k.size or not np.all(np.isfinite(torques)):
            raise ValueError(f"torques must be a finite ({self.k.size}, m) array, got shape {torques.shape}")
        if self.inconsistent:
            return False
        return self._add(self.free_part(self.a * np.asarray(p, dtype=float), torques), np.asarray(y, dtype=float))

    def free_part(self, x, torques) -> np.ndarray:
        """x̃ = Πx (N,) rad: x less its K-orthogonal projection onto span{K⁻¹ torques} (module docstring, "in
        contact"), in w = K^{1/2}v coordinates (z_w = K^{-1/2} torques) with every direction of nonzero singular
        value eliminated."""
        root = np.sqrt(self.k)
        x_w = root * np.asarray(x, dtype=float)
        basis, values, _ = np.linalg.svd(np.asarray(torques, dtype=float) / root[:, None], full_matrices=False)
        basis = basis[:, values > 0.0]
        return (x_w - basis @ (basis.T @ x_w)) / root

    def _add(self, x: np.ndarray, y: np.ndarray) -> bool:
        """Add the sample x̃ᵀK y = g |x̃|²_K + x̃ᵀKδ (x̃ = x out of contact) if it narrows e and is informative."""
        xx, w = float(np.sum(self.k * x * x)), float(np.sum(self.k * np.abs(x)))
        if not (xx > 0.0 and self.noise_rad * w <= INFORMATIVE * (self.prior[1] - self.prior[0]) * xx
                and (self.sum_w == 0.0 or xx * self.sum_w > self.sum_xx * w)):  # alone within a quarter; e falls
            return False
        self.sum_xy += float(np.sum(self.k * x * y))
        self.sum_xx += xx
        self.sum_w += w
        self.samples += 1
        g, e = self.estimate, self.bound
        lo, hi = max(self.interval[0], g - e), min(self.interval[1], g + e)
        if lo > hi:  # no gain fits every kept sample within Δ: an assumption is false
            self.inconsistent, self.interval = True, self.prior
        else:
            self.interval = (lo, hi)
        return True
