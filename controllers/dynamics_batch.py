"""The PCC model's per-step terms at B states at once (numpy over the batch; docs/model.md#pcc-kinematics, docs/model.md#rppr-dynamics).

The same quantities as the scalar per-step path of `controllers.pcc` and
`controllers.dynamics` (`step_kinematics_2`, `PCCDynamics.model_terms` / `evaluate_floats`), for
N = 2 segments (the paper's arm), evaluated for B states (q, q̇), each (B, 2) rad,
rad/s, with one numpy operation per scalar operation of that path:

- kinematics: segment ends p_1, p_2 = r (m), the tip velocity ṙ = J_r q̇ (m/s), the tip
  Jacobian J_r (m/rad) and the bias accelerations J̇ q̇ of the chord midpoints and the tip;
- M(q) (kg·m²), C q̇ + D q̇ + K q (N·m) and M⁻¹ (closed-form 2 × 2 inverse);
- the tip terms the barrier reads: r, ṙ, r̈ at u = 0, and ∂r̈/∂u_j = (M⁻¹ J_r)_j λ_j.

Complex numbers of the scalar path (x + i·y) are pairs of real arrays here, and
every complex product is written out as CPython evaluates it,
(a + ib)(c + id) = (ac − bd) + i(ad + bc), with the real-times-complex and
1j-times-complex products reduced exactly as CPython's arithmetic reduces them (a
product with an exact zero only adds ±0). Elementwise IEEE operations in the same
order give the same floats: the results equal the scalar path's bit for bit (tested,
including sin/cos, which numpy and the math module evaluate identically here; the
test would catch a platform where they do not).

Shapes: B states; arrays (B,) unless stated. Assumes N = 2 (raises otherwise).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from controllers.params import RobotParams
from controllers.pcc import sinc_half_coefficients

Pair = tuple[np.ndarray, np.ndarray]  # (real, imaginary) parts of B complex numbers


class BatchTerms(NamedTuple):
    """Model terms at B states (module docstring); pairs are (x, y) arrays of shape (B,)."""

    ends: tuple[Pair, Pair]  # p_1, p_2 = r (m)
    tip: Pair  # r (m)
    tip_vel: Pair  # ṙ (m/s)
    tip_jac: tuple[Pair, Pair]  # ∂r/∂q_1, ∂r/∂q_2 (m/rad)
    mass: tuple[np.ndarray, np.ndarray, np.ndarray]  # M_00, M_01 (= M_10), M_11 (kg·m²)
    force: tuple[np.ndarray, np.ndarray]  # C q̇ + D q̇ + K q (N·m)
    mass_inv: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # (M⁻¹)_00, _01, _10, _11
    tip_bias_acc: Pair  # J̇_r q̇ (m/s²)


def _sinc_half(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """s, s', s'' of s(q) = sinc(q/2) elementwise, as `controllers.pcc._sinc_half` (same floats)."""
    rows, switch = sinc_half_coefficients()
    x = q * q
    s0 = np.zeros_like(q)
    s1 = np.zeros_like(q)
    s2 = np.zeros_like(q)
    for c0, c1, c2, _ in rows:
        s0 = s0 * x + c0
        s1 = s1 * x + c1
        s2 = s2 * x + c2
    s1 = s1 * q
    far = np.abs(q) >= switch
    if np.any(far):  # the closed forms, where the series is not used
        xf = 0.5 * q[far]
        sin, cos = np.sin(xf), np.cos(xf)
        f0 = sin / xf
        f1 = (cos - f0) / xf
        f2 = -f0 - 2.0 * f1 / xf
        s0[far], s1[far], s2[far] = f0, 0.5 * f1, 0.25 * f2
    return s0, s1, s2


def _times(a: Pair, b: Pair) -> Pair:
    """CPython's complex product a·b."""
    return a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]


def _scaled(s: np.ndarray | float, a: Pair) -> Pair:
    """float · complex."""
    return s * a[0], s * a[1]


def _plus(a: Pair, b: Pair) -> Pair:
    return a[0] + b[0], a[1] + b[1]


def _i_times(a: Pair) -> Pair:
    """1j · complex."""
    return -a[1], a[0]


class BatchDynamics:
    """`PCCDynamics`'s per-step terms for B states at once (N = 2 only; module docstring).

    `params`: one `RobotParams` for every state, or one per state (B of them: per-simulation
    model parameters, e.g. a mismatch study's true arms); each parameter is then a (B,)
    array in the same elementwise operations, so the floats are those of B `PCCDynamics`.
    Attributes `damping`, `stiffness`, `gains`: per segment, a float or a (B,) array.
    """

    def __init__(self, params: RobotParams | Sequence[RobotParams]) -> None:
        many = not isinstance(params, RobotParams)
        models = list(params) if many else [params]
        if not models or any(p.n_segments != 2 for p in models):
            raise ValueError(f"the batched PCC dynamics is written for N = 2 segments, got {[p.n_segments for p in models]}")
        self.params = params
        self.n = 2

        def column(values: list[float]) -> np.ndarray | float:
            """One parameter: a (B,) array per simulation, or the shared Python float."""
            return np.array(values) if many else values[0]

        # M_rot = Aᵀ diag(I) A with A = [[½, 0], [1, ½]], as `PCCDynamics` builds it (same floats).
        a = np.array([[0.5, 0.0], [1.0, 0.5]])
        rots = [(a.T @ (p.array("inertias")[:, None] * a)).tolist() for p in models]
        self._rot = tuple(column([r[j][k] for r in rots]) for j, k in ((0, 0), (0, 1), (1, 1)))
        self._masses = tuple(column([p.array("masses").tolist()[i] for p in models]) for i in range(2))
        self.damping = tuple(column([p.damping[i] for p in models]) for i in range(2))
        self.stiffness = tuple(column([p.stiffness[i] for p in models]) for i in range(2))
        self.gains = tuple(column([p.gains[i] for p in models]) for i in range(2))
        self._lengths = tuple(column([p.lengths[i] for p in models]) for i in range(2))
        self._last: tuple = (None, None, None)  # (q, q̇, BatchTerms) of the last `terms` call

    def terms(self, q: np.ndarray, qd: np.ndarray) -> BatchTerms:
        """The model terms at (q, q̇), each (B, 2); no input checks.

        The last call's terms are kept: a plant and a filter sharing this object evaluate
        each reported state once (as `PCCDynamics.model_terms` does for one state).
        """
        last_q, last_qd, last = self._last
        if last is not None and np.array_equal(q, last_q) and np.array_equal(qd, last_qd):
            return last
        terms = self._terms(q, qd)
        self._last = (q.copy(), qd.copy(), terms)
        return terms

    def _terms(self, q: np.ndarray, qd: np.ndarray) -> BatchTerms:
        q0, q1, v0, v1 = q[:, 0], q[:, 1], qd[:, 0], qd[:, 1]
        length0, length1 = self._lengths
        s0, s1, s2 = _sinc_half(q0)
        a0, a1, a2 = length0 * s0, length0 * s1, length0 * s2
        s0, s1, s2 = _sinc_half(q1)
        b0, b1, b2 = length1 * s0, length1 * s1, length1 * s2
        w0, w1 = 0.5 * v0, v0 + 0.5 * v1
        angle0, angle1 = 0.5 * q0, q0 + 0.5 * q1
        z0, z1 = (np.cos(angle0), np.sin(angle0)), (np.cos(angle1), np.sin(angle1))
        g0, g1 = _scaled(a0, z0), _scaled(b0, z1)
        gd0, gd1 = _scaled(a1, z0), _scaled(b1, z1)
        gv0 = _times((a1 * v0, a0 * w0), z0)
        gv1 = _times((b1 * v1, b0 * w1), z1)
        bias0 = _times((a2 * v0 * v0 - a0 * w0 * w0, 2.0 * a1 * v0 * w0), z0)
        bias1 = _times((b2 * v1 * v1 - b0 * w1 * w1, 2.0 * b1 * v1 * w1), z1)
        shift0, shift1 = _i_times(_plus(_scaled(0.5, g0), g1)), _i_times(_scaled(0.5, g1))
        jac0, jac1 = _plus(gd0, shift0), _plus(gd1, shift1)
        tip = _plus(g0, g1)
        tip_vel = _plus(gv1, gv0)
        tip_bias = _plus(bias0, bias1)
        # Chord-midpoint Jacobians and bias accelerations (`_step_kinematics_2`), then M and the force.
        h0 = _plus(_scaled(0.5, gd0), (-0.25 * g0[1], 0.25 * g0[0]))
        j10 = (jac0[0] - shift1[0], jac0[1] - shift1[1])
        h1 = _plus(_scaled(0.5, gd1), (-0.25 * g1[1], 0.25 * g1[0]))
        acc0, acc1 = _scaled(0.5, bias0), _plus(bias0, _scaled(0.5, bias1))
        (m0, m1), (d0, d1), (k0, k1), (r00, r01, r11) = self._masses, self.damping, self.stiffness, self._rot
        a_re, a_im = m0 * h0[0], m0 * h0[1]
        f0 = d0 * v0 + k0 * q0 + (a_re * acc0[0] + a_im * acc0[1])
        m00 = r00 + (a_re * h0[0] + a_im * h0[1])
        a_re, a_im = m1 * j10[0], m1 * j10[1]
        f0 = f0 + (a_re * acc1[0] + a_im * acc1[1])
        m00 = m00 + (a_re * j10[0] + a_im * j10[1])
        m01 = r01 + (a_re * h1[0] + a_im * h1[1])
        a_re, a_im = m1 * h1[0], m1 * h1[1]
        f1 = d1 * v1 + k1 * q1 + (a_re * acc1[0] + a_im * acc1[1])
        m11 = r11 + (a_re * h1[0] + a_im * h1[1])
        det = m00 * m11 - m01 * m01
        inv = (m11 / det, -m01 / det, -m01 / det, m00 / det)
        return BatchTerms((g0, tip), tip, tip_vel, (jac0, jac1), (m00, m01, m11), (f0, f1), inv, tip_bias)

    def acceleration(self, terms: BatchTerms, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q̈ = M⁻¹(Λu − C q̇ − D q̇ − K q) (rad/s²), as `PCCDynamics.acceleration_from_terms`; u (B, 2) hPa."""
        (g0, g1), (f0, f1), (n00, n01, n10, n11) = self.gains, terms.force, terms.mass_inv
        t0, t1 = g0 * u[:, 0] - f0, g1 * u[:, 1] - f1
        return n00 * t0 + n01 * t1, n10 * t0 + n11 * t1

    def tip_accelerations(self, terms: BatchTerms) -> tuple[Pair, Pair, Pair]:
        """(r̈ at u = 0, ∂r̈/∂u_1, ∂r̈/∂u_2) as `PCCDynamics.evaluate_floats`' tip terms (m/s², m/s² per hPa)."""
        (n00, n01, n10, n11), (j0, j1), (f0, f1) = terms.mass_inv, terms.tip_jac, terms.force
        w0 = _plus(_scaled(n00, j0), _scaled(n01, j1))  # w = M⁻¹ J_r
        w1 = _plus(_scaled(n10, j0), _scaled(n11, j1))
        drift = _plus(_scaled(f0, w0), _scaled(f1, w1))  # Σ w_j f_j
        acc0 = (terms.tip_bias_acc[0] - drift[0], terms.tip_bias_acc[1] - drift[1])
        g0, g1 = self.gains
        return acc0, _scaled(g0, w0), _scaled(g1, w1)
