"""Online estimate of the actuator gain scale g from samples out of contact and in contact at the tip, with a certified interval.

The true arm's gains are g·λ_i, one unknown scale g for every segment (dimensionless; the contact
certificate, `controllers.governors.energy_governor`, certifies an interval [g_lo, g_hi] of it). The model
(docs/model.md#rppr-dynamics, no gravity, no contact) is

    M(q) q̈ + C(q, q̇) q̇ + D q̇ + K q = g Λ p,

so at a sample with the model's pressure p (hPa, the lag `controllers.model.state_predictor` integrates
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

Averaged frames (a noisy camera; c-erg's `gain_window_s`). With image noise the camera's q̂ scatters by
σ ≈ 0.7–1.6e-3 rad per frame and segment (camera_loop, pixel noise 8 grey levels, frames at 12.8 Hz, 20 %
dropped: the frames' q_camera − q_true; the distal segment's the larger), its finite-difference q̂̇ by ≈ 0.1 rad/s: no estimate passes a rest test
|q̂̇_i| ≤ 3e-3 rad/s, and Δ must then cover a frame's noise as well. Instead a sample averages the n frames
(t_f, q̂_f) of a window of `gain_window_s` in which the model's pressure is settled at every frame (`RestWindow`):
per segment the least-squares line q̂_i(t) ≈ α_i + β_i (t − t̄) gives the mean α_i = Σ_f q̂_f,i / n and the slope
β_i; the window is at rest when every |β_i| ≤ `rest_rad_s` (the slope of n frames, not a noisy q̂̇), and the sample
is y = α, x = K⁻¹Λ p̄ (p̄ the frames' mean model pressure). Consecutive windows at rest (blocks) make a run, and
the sample is the run's mean over all its n frames (the run's own slope at rest too; c-erg offers it after each
block: a longer rest, a smaller ε ∝ 1/√n); the scatter is pooled per block. Write the frame's error q̂_f − q_f = b_f + η_f: b a
systematic part (the camera's calibration and tag-geometry error, which no averaging removes), η_f the frame's
noise, independent across frames, Gaussian N(0, σ_i²) with σ_i the same in every window of the run (the pixel
noise is stationary and the arm moves little at rest). The balance at each frame, averaged over the window, gives

    α = g x + δ̄ + η̄,   δ̄ = mean_f(b_f) − K⁻¹D mean_f(q̇_f) − K⁻¹ mean_f(M q̈ + C q̇)

(the balance is linear in p, so the frames' mean of g K⁻¹Λ p_f is g x), η̄ = mean_f η_f ~ N(0, σ_i²/n). δ̄ is bounded by Δ as before (the systematic error, and the residual motion of a
window whose slope is at most `rest_rad_s`: |K⁻¹D mean q̇| ≤ (d_i/k_i)(rest_rad_s + the slope's own noise) ≈
0.07 s × (3e-3 + 3 × 2.5e-3) rad/s ≈ 7e-4 rad on the reference arm, for 8 frames over 0.5 s at σ = 1e-3 rad;
with the camera's systematic error at rest, ≤ 2e-4 rad on the 150 hPa push, within Δ = 1.5e-3 rad);
η̄ is bounded from the samples' own scatter: the residuals about each window's line, pooled over the windows taken
so far (disjoint windows at rest), s_i² = Σ RSS_i / ν, ν = Σ (n_w − 2), so that η̄_i/(s_i/√n) is Student's t
with ν degrees of freedom (α is independent of the residuals and of β, which the rest test selects on, so that
selecting a window on β, on s or on x does not bias α; the other windows' noise is independent of it). A window
whose arm moves other than along a line adds its deterministic curvature to its residuals: their sum of squares is
then a non-central χ², stochastically larger than the central one, so s only grows and the bound errs to the
safe side (the commands within a window depend on its earlier frames through the governor's steps, held near
constant by the settled pressure: neglected). Then

    P(|η̄_i| > ε_i) = risk,   ε_i = t_ν(risk) s_i/√n   (`student_t_quantile`, c-erg's `gain_scatter_risk`).

A calibrated camera (c-erg's `gain_frame_sigma_rad`, e.g. from `softcbf calibrate-camera`): with σ known, η̄_i/(σ/√n)
is standard normal and ε_i = z(risk) σ/√n from the first window on (no pooled degrees of freedom to wait for:
ν = 8 gives t = 13.3 at risk 1e-6 against z = 4.89); sound as far as σ bounds the camera's noise in this run
(its own estimate's error, ≈ σ/√(2ν) at the calibration's ν, is not in the bound: calibrate on a long run and
round σ up, as the command's upper value does).
The sample then enters the sums above with the bound Δ + ε_i per segment: |x̃ᵀK(δ̄ + η̄)| ≤ Σ_i k_i|x̃_i|(Δ + ε_i),
so e = (Δ Σ_s w̃_s + Σ_s Σ_i k_i|x̃_s,i| ε_s,i) / Σ_s |x̃_s|²_K, and the rules above (e falls; alone within a
quarter of the prior) use each sample's own bound. This part of the bound is statistical, not worst case: g ∈ I
holds with probability at least 1 − N·S·risk for S accepted window samples (a union bound over segments and
samples; at least 1 − 2·24·1e-6 for a 12 s push with 0.5 s windows), and only under the Gaussian, stationary, independent
noise assumed (a camera whose noise is correlated across frames, e.g. a tracked tag's window, has a smaller
residual scatter than its mean's error: calibrate it, `controllers.governors.camera_delta`). Δ keeps the worst-case part:
set from the noise-free camera (1.5e-3 rad) or from a recorded run (`softcbf calibrate-camera RUN_DIR`: the
largest error of a window's mean against the simulation's truth). Measured on the 150 hPa push with noise 8 and
20 % drops: docs/beyond-the-paper.md#a-noisy-camera.

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

import functools
import math
import statistics

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
        self.sum_scatter = 0.0  # Σ_s Σ_i k_i |x̃_s,i| ε_s,i (J): the averaged samples' noise bounds
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
        if self.sum_xx <= 0.0:
            return math.inf
        return self.noise_rad * self.sum_w / self.sum_xx + self.sum_scatter / self.sum_xx + ROUNDING

    def rest_residual(self, q, qd) -> np.ndarray:
        """y = q̂ + K⁻¹D q̂̇ (N,) rad: the rest sample's K⁻¹ × (C + D)q̇ + Kq, with C q̇ and M q̈ left to Δ."""
        return np.asarray(q, dtype=float) + self.damping_ratio * np.asarray(qd, dtype=float)

    def sample(self, p, y, scatter=None) -> bool:
        """Add the sample (p, y) out of contact: the model's pressure p (N,) hPa and y = K⁻¹(M q̈ + (C + D) q̇ + K q)
        (N,) rad (`rest_residual` at rest; a window's mean estimate, `RestWindow`); kept if it narrows e; returns
        whether it was kept. scatter (N,) rad: a bound ε_i of this sample's averaged camera noise, added to Δ per
        segment ("averaged frames"); None: 0."""
        if self.inconsistent:
            return False
        return self._add(self.a * np.asarray(p, dtype=float), np.asarray(y, dtype=float), scatter)

    def sample_in_contact(self, p, y, torques, scatter=None) -> bool:
        """Add the sample (p, y) of an arm whose tip is pushed by unknown forces along known directions (module
        docstring, "in contact"): torques (N, m) holds in its columns the generalised forces per newton J_r(q̂)ᵀv
        (m) of the m possible force directions v (each facet's n̂_j, and t̂_j where the force may be tangential);
        their span is eliminated. p, y, scatter as `sample`; returns whether it was kept."""
        torques = np.asarray(torques, dtype=float)
        if torques.ndim != 2 or torques.shape[0] != self.k.size or not np.all(np.isfinite(torques)):
            raise ValueError(f"torques must be a finite ({self.k.size}, m) array, got shape {torques.shape}")
        if self.inconsistent:
            return False
        return self._add(self.free_part(self.a * np.asarray(p, dtype=float), torques), np.asarray(y, dtype=float),
                         scatter)

    def free_part(self, x, torques) -> np.ndarray:
        """x̃ = Πx (N,) rad: x less its K-orthogonal projection onto span{K⁻¹ torques} (module docstring, "in
        contact"), in w = K^{1/2}v coordinates (z_w = K^{-1/2} torques) with every direction of nonzero singular
        value eliminated."""
        root = np.sqrt(self.k)
        x_w = root * np.asarray(x, dtype=float)
        basis, values, _ = np.linalg.svd(np.asarray(torques, dtype=float) / root[:, None], full_matrices=False)
        basis = basis[:, values > 0.0]
        return (x_w - basis @ (basis.T @ x_w)) / root

    def _add(self, x: np.ndarray, y: np.ndarray, scatter) -> bool:
        """Add the sample x̃ᵀK y = g |x̃|²_K + x̃ᵀKδ (x̃ = x out of contact) if it narrows e and is informative;
        its bound per segment is Δ + ε_i (scatter ε; None: Δ alone, the sums' arithmetic as without ε)."""
        xx, w = float(np.sum(self.k * x * x)), float(np.sum(self.k * np.abs(x)))
        if scatter is None:
            spread = 0.0
        else:
            scatter = np.asarray(scatter, dtype=float)
            if scatter.shape != self.k.shape or not np.all(np.isfinite(scatter)) or np.any(scatter < 0.0):
                raise ValueError(f"scatter must be a finite ({self.k.size},) array >= 0 rad, got {scatter.tolist()}")
            spread = float(np.sum(self.k * np.abs(x) * scatter))
        if self.sum_scatter == 0.0 and spread == 0.0:  # Δ alone: e's ratio Σw/Σ|x̃|²_K compared without Δ
            falls = self.sum_w == 0.0 or xx * self.sum_w > self.sum_xx * w
        else:
            falls = self.sum_xx == 0.0 or xx * (self.noise_rad * self.sum_w + self.sum_scatter) > self.sum_xx * (self.noise_rad * w + spread)
        if not (xx > 0.0 and self.noise_rad * w + spread <= INFORMATIVE * (self.prior[1] - self.prior[0]) * xx
                and falls):  # alone within a quarter; e falls
            return False
        self.sum_xy += float(np.sum(self.k * x * y))
        self.sum_xx += xx
        self.sum_w += w
        self.sum_scatter += spread
        self.samples += 1
        g, e = self.estimate, self.bound
        lo, hi = max(self.interval[0], g - e), min(self.interval[1], g + e)
        if lo > hi:  # no gain fits every kept sample within Δ: an assumption is false
            self.inconsistent, self.interval = True, self.prior
        else:
            self.interval = (lo, hi)
        return True


def student_t_tail(t: float, dof: int) -> float:
    """P(|T| > t) (1) for Student's T with `dof` ≥ 1 degrees of freedom, t ≥ 0, from the closed forms for an integer
    dof (Abramowitz & Stegun 26.7.3–4, θ = atan(t/√ν), c = cos²θ): P(|T| ≤ t) = sin θ Σ_{j<ν/2} a_j c^j (ν even,
    a_0 = 1, a_j = a_{j−1}(2j − 1)/(2j)) and (2/π)(θ + sin θ cos θ Σ_{j<(ν−1)/2} b_j c^j) (ν odd, b_0 = 1,
    b_j = b_{j−1}(2j)/(2j + 1)). Their full series sum to 1 (Σ_j a_j c^j = (1 − c)^{-1/2} = 1/sin θ) and to 1
    (Σ_j b_j c^j cos θ = arcsin(cos θ)/sin θ = (π/2 − θ)/sin θ), so the tail is the series' remainder, a sum of
    positive terms (no cancellation at a small tail): sin θ Σ_{j≥ν/2} a_j c^j and (2/π) sin θ cos θ Σ_{j≥(ν−1)/2}
    b_j c^j, summed to a relative 1e-17 (the terms fall at least as c^j), used where 1 − the finite sum is below
    1e-4 (above, that difference loses at most 4 of 16 digits)."""
    if dof < 1 or not t >= 0.0:
        raise ValueError(f"student_t_tail needs dof >= 1 and t >= 0, got dof={dof!r}, t={t!r}")
    ratio = t / math.sqrt(dof)  # tan θ; sin θ and cos θ from it (cos(atan(t)) loses digits near π/2)
    theta, cos = math.atan(ratio), 1.0 / math.sqrt(1.0 + ratio * ratio)
    sin = ratio * cos
    c, even = cos * cos, dof % 2 == 0
    first = dof // 2 if even else (dof - 1) // 2
    term = 1.0
    for j in range(first):  # the coefficient a_first c^first (b_first c^first)
        term *= c * ((2 * j + 1) / (2 * j + 2) if even else (2 * j + 2) / (2 * j + 3))
    total, step = 0.0, 1.0
    for j in range(first):
        total += step
        step *= c * ((2 * j + 1) / (2 * j + 2) if even else (2 * j + 2) / (2 * j + 3))
    direct = 1.0 - (sin * total if even else 2.0 / math.pi * (theta + sin * cos * total))
    if direct > 1e-4:  # a large tail: 1 − the finite sum loses at most 4 digits of 16
        return direct
    total, j = 0.0, first
    while term > 1e-17 * total:
        total += term
        term *= c * ((2 * j + 1) / (2 * j + 2) if even else (2 * j + 2) / (2 * j + 3))
        j += 1
    return sin * total if even else 2.0 / math.pi * sin * cos * total


@functools.lru_cache(maxsize=256)
def student_t_quantile(risk: float, dof: int) -> float:
    """The t ≥ 0 with P(|T| > t) = risk (1) for Student's T with `dof` degrees of freedom: Newton's method on
    log P(|T| > e^u) (its derivative −2 f(t) t / P, f the density) from the normal quantile, to a relative 1e-11,
    then raised by a relative 1e-8 (against scipy.stats.t: tests/test_camera_delta.py), so that P(|T| > t) ≤ risk.
    Cached: a governor asks again for each pooled dof."""
    if not 0.0 < risk < 1.0:
        raise ValueError(f"risk must lie in (0, 1), got {risk!r}")
    if dof < 1:
        raise ValueError(f"dof must be >= 1, got {dof!r}")
    log_norm = math.lgamma((dof + 1) / 2.0) - math.lgamma(dof / 2.0) - 0.5 * math.log(dof * math.pi)
    u = math.log(max(statistics.NormalDist().inv_cdf(1.0 - risk / 2.0), 1e-3))
    for _ in range(200):
        t = math.exp(u)
        tail = student_t_tail(t, dof)
        density = math.exp(log_norm - 0.5 * (dof + 1) * math.log1p(t * t / dof))
        step = (math.log(tail) - math.log(risk)) / (2.0 * density * t / tail)
        u += max(-1.0, min(step, 2.0))  # bounded steps: the heavy tails of dof 1–2 need several
        if abs(step) < 1e-11:
            return math.exp(u) * (1.0 + 1e-8)
    raise ValueError(f"the t quantile for risk {risk!r} with {dof} degrees of freedom did not converge")


MAX_DOF = 1000
"""The most degrees of freedom `RestWindow.scatter_bound` credits (1): t_ν(risk) falls with ν, so fewer is the safe
side (t_1000(1e-6) = 4.96 against the normal 4.89), and `student_t_quantile` stays ≲ 10 ms per new ν."""


class RestWindow:
    """The camera frames of one rest window and the scatter pooled over the windows taken ("averaged frames").

    `add(t, q, p)` appends the estimate q (N,) rad captured at t (s) with the model's pressure p there (hPa; None
    where no model pressure goes with it: `inputs` then holds None) (an estimate already held, t not later than the
    last frame's, is ignored); `fit()` fits the line q_i(t) ≈ α_i + β_i (t − t̄) per segment by least squares
    (α = the frames' mean, β the slope, rad/s) with its residual sum of squares; `pool(fit)` adds a window's
    residuals to the pooled scatter s_i² = Σ RSS_i / Σ (n − 2); `scatter_bound(n, risk)` is
    ε_i = t_ν(risk) s_i / √n, ν the pooled degrees of freedom (at most `MAX_DOF`). `fit(start)` and `span(start)`
    read the frames from index `start` on (a block of a run); `clear()` starts the next window, `drop_oldest()` and
    `drop_before(start)` drop its first frames, `reset()` forgets the pool too."""

    def __init__(self, segments: int) -> None:
        self.segments = int(segments)
        self.reset()

    def reset(self) -> None:
        """No frame, no pooled scatter."""
        self.times: list[float] = []
        self.frames: list[np.ndarray] = []
        self.inputs: list = []
        self.pooled_rss = np.zeros(self.segments)
        self.pooled_dof = 0

    def clear(self) -> None:
        """Drop the window's frames (the pooled scatter is kept)."""
        self.times, self.frames, self.inputs = [], [], []

    def add(self, t: float, q, p=None) -> bool:
        """Append the frame (t, q, p); False (nothing added) when t is not after the last frame's."""
        if self.times and not t > self.times[-1]:
            return False
        self.times.append(float(t))
        self.frames.append(np.array(q, dtype=float))
        self.inputs.append(None if p is None else np.array(p, dtype=float))
        return True

    def drop_oldest(self) -> None:
        """Drop the window's first frame (the window slides on)."""
        del self.times[0], self.frames[0], self.inputs[0]

    def span(self, start: int = 0) -> float:
        """Last frame's time less that of frame `start` (s); 0 with fewer than two frames from it."""
        return self.times[-1] - self.times[start] if len(self.times) > start + 1 else 0.0

    def drop_before(self, start: int) -> None:
        """Drop the frames before index `start`."""
        del self.times[:start], self.frames[:start], self.inputs[:start]

    def fit(self, start: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(α, β, RSS, n): the frames' mean (N,) rad, the least-squares slope (N,) rad/s and the residuals' sum of
        squares (N,) rad² about the line, over the window's n ≥ 3 frames from index `start` on."""
        n = len(self.times) - start
        if n < 3:
            raise ValueError(f"a rest window's fit needs at least 3 frames, got {n}")
        dt = np.array(self.times[start:]) - np.mean(self.times[start:])
        q = np.array(self.frames[start:])
        mean = q.mean(axis=0)
        slope = dt @ (q - mean) / float(dt @ dt)
        residual = q - mean - np.outer(dt, slope)
        return mean, slope, np.sum(residual * residual, axis=0), n

    def pool(self, rss: np.ndarray, n: int) -> None:
        """Add a fitted window's residual sums of squares (N,) rad² and its n − 2 degrees of freedom to the pool."""
        self.pooled_rss = self.pooled_rss + np.asarray(rss, dtype=float)
        self.pooled_dof += n - 2

    def scatter_bound(self, n: int, risk: float, sigma: float | None = None) -> np.ndarray:
        """ε (N,) rad: P(|ᾱ_i − E ᾱ_i| > ε_i) = risk for the mean of n frames with i.i.d. Gaussian noise of the pooled
        scatter's variance (Student's t with the pooled degrees of freedom: module docstring, "averaged frames"),
        or of the known (calibrated) standard deviation `sigma` rad (the normal quantile: ε = z σ/√n)."""
        if sigma is not None:
            return np.full(self.segments, statistics.NormalDist().inv_cdf(1.0 - risk / 2.0) * sigma / math.sqrt(n))
        if self.pooled_dof < 1:
            raise ValueError("no pooled scatter yet: pool a window of at least 3 frames first")
        sigma = np.sqrt(self.pooled_rss / self.pooled_dof)
        return student_t_quantile(risk, min(self.pooled_dof, MAX_DOF)) * sigma / math.sqrt(n)
