"""Kinematics of N planar piecewise-constant-curvature (PCC) segments (docs/model.md#pcc-kinematics).

Angles in rad, lengths in m. For segment i = 1..N with length L_i and bending
angle q_i (positive: counter-clockwise seen from +z, the tip moves towards +y):

    ℓ_i = 2 L_i sin(q_i/2) / q_i        chord length (→ L_i as q_i → 0)
    φ_i = θ_{i-1} + q_i/2               chord direction, θ_i = θ_{i-1} + q_i, θ_0 = 0
    p_i = p_{i-1} + ℓ_i e^{iφ_i},  p_0 = 0,   tip r = p_N
    c_i = p_{i-1} + ½ ℓ_i e^{iφ_i}      chord midpoint: the body of the RPPR model (docs/model.md#rppr-dynamics)

Points of the plane are complex numbers x + i·y inside this module and the
dynamics; the public wrappers return real arrays with an (x, y) axis.

Every point used here is P = Σ_k W_k g_k with constant weights W and chord vectors
g_k = ℓ_k(q_k) e^{iφ_k}, where φ = A q with A[k, j] = 1 (j < k), ½ (j = k), 0 (j > k).
So all its derivatives follow from one product rule: each ∂/∂q_j hits either ℓ_k
(giving ℓ_k' δ_kj) or e^{iφ_k} (giving i A_kj), hence

    ∂ⁿg_k/∂q_{j1}…∂q_{jn} = e^{iφ_k} Σ_{S ⊆ {1..n}} ℓ_k^{(|S|)} i^{n-|S|} Π_{m∈S} δ_{k jm} Π_{m∉S} A_{k jm}.

The sums over S are constant tensors; `kinematics` contracts them with the
coefficients ℓ_k^{(a)} e^{iφ_k} in one matrix product that yields the positions,
Jacobians (n = 1), Hessians (n = 2) and third derivatives (n = 3) of the N chord
midpoints and the tip together.

ℓ and its derivatives come from s(q) = sinc(q/2) = ℓ/L (`_sinc_half`, the one
evaluation of s, in Python floats): a Taylor series in q for |q| < 2, where the closed
forms cancel catastrophically, and the closed forms (well-conditioned there) for
|q| ≥ 2. Every derivative is then smooth, finite through q = 0 and accurate to a few
ulp (the tests compare with exact rational sums).

Two evaluation paths share these formulas: `kinematics` (numpy tensors, any order ≤ 3,
for derivatives, the plant's Jacobian and the public wrappers) and `step_kinematics`
(Python scalars, first order plus the q̇-terms, for the 1 kHz filter and plant steps,
where numpy's per-call overhead would dominate at N ≈ 2; for N = 2 its loops are
unrolled, giving the same floats). Tests check one path against the other.
"""

from __future__ import annotations

import cmath
import itertools
import math
from functools import lru_cache
from typing import NamedTuple, Sequence

import numpy as np

from controllers.errors import ControllerInputError, NonFiniteStateError, as_vector

_SERIES_SWITCH = 2.0  # |q| below which the Taylor series is used (|x| = |q/2| < 1)
_SERIES_DEGREE = 19  # powers q^0..q^19; first omitted term < 1e-21 relative at |q| = 2
MAX_ORDER = 3


def _series_matrix(degree: int) -> np.ndarray:
    """S (degree+1, 4): Σ_p S[p, a] q^p = d^a/dq^a sinc(q/2), truncated at q^degree.

    From sinc(q/2) = Σ_k d_k q^{2k}, d_k = (-1)^k / ((2k+1)! 4^k).
    """
    s = np.zeros((degree + 1, 4))
    for k in range(degree // 2 + 3):
        d_k = (-1.0) ** k / (math.factorial(2 * k + 1) * 4.0**k)
        for a in range(4):
            p = 2 * k - a
            if 0 <= p <= degree:
                s[p, a] = d_k * math.perm(2 * k, a)
    return s


_SERIES = _series_matrix(_SERIES_DEGREE)


# Column a of _SERIES has nonzero entries only at powers p ≡ a (mod 2): per Horner step (highest
# power first) the four coefficients of q^(2k + a mod 2), so s^(a) = q^(a mod 2) · poly_a(q²).
_HORNER_ROWS = tuple(zip(*(_SERIES[a % 2 :: 2, a][::-1].tolist() for a in range(4))))


def sinc_half_coefficients() -> tuple[tuple[tuple[float, float, float, float], ...], float]:
    """(Horner rows, switch) of `_sinc_half`'s series, for evaluations that must give its floats.

    Each row holds the coefficients (a = 0..3) of one Horner step, highest power first;
    s^(a)(q) = q^(a mod 2) · poly_a(q²) for |q| < switch (rad), the closed forms beyond.
    """
    return _HORNER_ROWS, _SERIES_SWITCH


def _sinc_half(q: float) -> tuple[float, float, float, float]:
    """s^{(a)}(q) for s(q) = sinc(q/2) = ℓ(q)/L and a = 0..3, one Python float q. No input checks.

    The only evaluation of s: scalar, because numpy's per-call overhead dominates at N ≈ 2.
    """
    if abs(q) < _SERIES_SWITCH:
        x = q * q
        s0 = s1 = s2 = s3 = 0.0
        for c0, c1, c2, c3 in _HORNER_ROWS:  # separate statements: no tuple built per step
            s0 = s0 * x + c0
            s1 = s1 * x + c1
            s2 = s2 * x + c2
            s3 = s3 * x + c3
        return s0, s1 * q, s2, s3 * q
    # x s0 = sin x, differentiated thrice: s0 + x s1 = cos x, 2 s1 + x s2 = -sin x, 3 s2 + x s3 = -cos x.
    x = 0.5 * q
    sin, cos = math.sin(x), math.cos(x)
    s0 = sin / x
    s1 = (cos - s0) / x
    s2 = -s0 - 2.0 * s1 / x
    s3 = -(cos + 3.0 * s2) / x
    return s0, 0.5 * s1, 0.25 * s2, 0.125 * s3  # d^a/dq^a = 2^{-a} d^a/dx^a


def _sinc_derivatives(q: np.ndarray) -> np.ndarray:
    """`_sinc_half` of every q_i: shape (N, 4). No input checks."""
    return np.array([_sinc_half(v) for v in q.tolist()]).reshape(-1, 4)


@lru_cache(maxsize=None)
def kinematic_structure(n: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Constants for N = n segments up to derivative `order`.

    Returns iA = i·A (n, n) with A[k, j] = ∂φ_k/∂q_j, and the complex map D of shape
    (n·(order+1), (n+1)·width), width = Σ_{d ≤ order} n^d, such that
    (coef.ravel() @ D).reshape(n+1, width) holds, per point (c_1..c_N, r), its
    position, Jacobian, Hessian, … flattened, where coef[k, a] = ℓ_k^{(a)} e^{iφ_k}.
    """
    a = np.tril(np.ones((n, n)), -1) + 0.5 * np.eye(n)
    eye = np.eye(n)
    weights = np.vstack((a, np.ones((1, n))))  # c_i = Σ_k A_ik g_k, r = Σ_k g_k
    blocks = []
    for degree in range(order + 1):
        block = np.zeros((n, order + 1) + (n,) * degree, dtype=complex)
        for hits_chord in itertools.product((False, True), repeat=degree):
            term = np.ones(n)
            for m, hit in enumerate(hits_chord):
                term = term[..., None] * (eye if hit else a).reshape((n,) + (1,) * m + (n,))
            count = sum(hits_chord)
            block[:, count] += 1j ** (degree - count) * term
        blocks.append(block.reshape(n, order + 1, -1))
    basis = np.concatenate(blocks, axis=2)
    dmap = np.einsum("pk,kaw->kapw", weights, basis).reshape(n * (order + 1), -1)
    ia = 1j * a
    ia.setflags(write=False)
    dmap.setflags(write=False)
    return ia, dmap


class PCCKinematics(NamedTuple):
    """Kinematics of one configuration q (points as complex x + i·y, in m).

    Points are indexed p = 0..N: the chord midpoints c_1..c_N, then the tip r.
    Derivative arrays have one trailing axis per ∂/∂q_j (per rad); `hess` and
    `third` are None below the requested order.
    """

    segments: np.ndarray  # (N,) chord vectors g_i = p_i - p_{i-1} = ℓ_i e^{iφ_i}
    points: np.ndarray  # (N+1,) c_1..c_N, r
    jac: np.ndarray  # (N+1, N) ∂P/∂q
    hess: np.ndarray | None  # (N+1, N, N) ∂²P/∂q∂q
    third: np.ndarray | None  # (N+1, N, N, N) ∂³P/∂q³


def kinematics_unchecked(q: np.ndarray, lengths: np.ndarray, order: int) -> PCCKinematics:
    """`kinematics` without input checks (for callers that checked already)."""
    n = q.shape[0]
    ia, dmap = kinematic_structure(n, order)
    weight = lengths * np.exp(ia.dot(q))  # L_k e^{iφ_k}
    coef = _sinc_derivatives(q)[:, : order + 1] * weight[:, None]
    table = coef.ravel().dot(dmap).reshape(n + 1, -1)
    jac_end = n + 1
    hess = table[:, jac_end : jac_end + n * n].reshape(n + 1, n, n) if order >= 2 else None
    third = table[:, jac_end + n * n :].reshape(n + 1, n, n, n) if order >= 3 else None
    return PCCKinematics(coef[:, 0], table[:, 0], table[:, 1:jac_end], hess, third)


class StepKinematics(NamedTuple):
    """First-order kinematics and velocity terms at (q, q̇) as Python scalars (the per-step path).

    Complex numbers are x + i·y (m). A bias acceleration is a point's acceleration at
    q̈ = 0, i.e. q̇ᵀ (∂²P/∂q²) q̇ = J̇ q̇.
    """

    ends: list[complex]  # (N) segment ends p_1..p_N (p_N = r)
    centre_jac: list[list[complex]]  # [i][j] = ∂c_i/∂q_j for j ≤ i (zero for j > i, not stored)
    centre_bias_acc: list[complex]  # (N) J̇_{c_i} q̇
    tip: complex  # r
    tip_vel: complex  # ṙ = J_r q̇
    tip_bias_acc: complex  # J̇_r q̇
    tip_jac: list[complex]  # (N) J_r
    tip_jac_dot: list[complex]  # (N) J̇_r


def step_kinematics(q: Sequence[float], qd: Sequence[float], lengths: Sequence[float]) -> StepKinematics:
    """`StepKinematics` at (q, q̇), given as Python float lists (N,); no input checks.

    N = 2 (the paper's arm) takes `step_kinematics_2`, the same arithmetic unrolled.
    """
    if len(q) == 2:
        return step_kinematics_2(q, qd, lengths)
    return step_kinematics_n(q, qd, lengths)


def step_kinematics_n(q: Sequence[float], qd: Sequence[float], lengths: Sequence[float]) -> StepKinematics:
    """`StepKinematics` for any N.

    Scalar loops, because numpy's per-call overhead (1–2 µs on a slow machine)
    dominates for N ≈ 2; tested against `kinematics`. With ω = φ̇ = A q̇ and
    z_k = e^{iφ_k}: ġ_k = (ℓ_k' q̇_k + i ℓ_k ω_k) z_k, the bias acceleration of g_k is
    (ℓ_k'' q̇_k² − ℓ_k ω_k² + 2i ℓ_k' q̇_k ω_k) z_k, and, from J_P[j] = W_j ℓ_j' z_j +
    i Σ_k W_k A_kj g_k, with s_j = i(½ g_j + Σ_{k>j} g_k):
        J_r[j] = ℓ_j' z_j + s_j,   J_{c_i}[j] = J_r[j] − s_i (j < i),   J_{c_i}[i] = ½ ℓ_i' z_i + ¼ i g_i;
    J̇_r likewise with d/dt(ℓ_j' z_j) = (ℓ_j'' q̇_j + i ℓ_j' ω_j) z_j and ġ_k for g_k.
    """
    n = len(q)
    ends, chord, chord_d, chord_dot, chord_d_dot, bias = [], [], [], [], [], []
    end, theta, theta_dot = 0j, 0.0, 0.0
    for length, qk, qdk in zip(lengths, q, qd):
        s0, s1, s2, _ = _sinc_half(qk)
        l0, l1, l2 = length * s0, length * s1, length * s2
        omega = theta_dot + 0.5 * qdk
        z = cmath.exp(1j * (theta + 0.5 * qk))
        theta += qk
        theta_dot += qdk
        chord.append(l0 * z)
        end += chord[-1]
        ends.append(end)
        chord_d.append(l1 * z)
        chord_dot.append((l1 * qdk + 1j * l0 * omega) * z)
        chord_d_dot.append((l2 * qdk + 1j * l1 * omega) * z)
        bias.append((l2 * qdk * qdk - l0 * omega * omega + 2j * l1 * qdk * omega) * z)

    tip_jac, tip_jac_dot, shift = [0j] * n, [0j] * n, [0j] * n
    suffix = tip_vel = 0j  # Σ_{k>j} g_k and Σ_{k>j} ġ_k, finally ṙ
    for j in range(n - 1, -1, -1):
        shift[j] = 1j * (0.5 * chord[j] + suffix)
        tip_jac[j] = chord_d[j] + shift[j]
        tip_jac_dot[j] = chord_d_dot[j] + 1j * (0.5 * chord_dot[j] + tip_vel)
        suffix += chord[j]
        tip_vel += chord_dot[j]

    centre_jac, centre_bias_acc = [], []
    prefix = 0j
    for i in range(n):
        centre_jac.append([tip_jac[j] - shift[i] for j in range(i)] + [0.5 * chord_d[i] + 0.25j * chord[i]])
        centre_bias_acc.append(prefix + 0.5 * bias[i])
        prefix += bias[i]
    return StepKinematics(ends, centre_jac, centre_bias_acc, end, tip_vel, prefix, tip_jac, tip_jac_dot)


def step_kinematics_2(q: Sequence[float], qd: Sequence[float], lengths: Sequence[float]) -> StepKinematics:
    """`step_kinematics_n` for N = 2 with its loops unrolled: the same operations in the same
    order, so the same floats (tested), at well under half the interpreter overhead."""
    (q0, q1), (v0, v1), (length0, length1) = q, qd, lengths
    s0, s1, s2, _ = _sinc_half(q0)
    a0, a1, a2 = length0 * s0, length0 * s1, length0 * s2  # ℓ_1, ℓ_1', ℓ_1''
    s0, s1, s2, _ = _sinc_half(q1)
    b0, b1, b2 = length1 * s0, length1 * s1, length1 * s2  # ℓ_2, ℓ_2', ℓ_2''
    w0, w1 = 0.5 * v0, v0 + 0.5 * v1  # ω = φ̇
    z0, z1 = cmath.exp(1j * (0.5 * q0)), cmath.exp(1j * (q0 + 0.5 * q1))
    g0, g1 = a0 * z0, b0 * z1  # chords
    gd0, gd1 = a1 * z0, b1 * z1  # ℓ' z
    gv0 = (a1 * v0 + 1j * a0 * w0) * z0  # ġ
    gv1 = (b1 * v1 + 1j * b0 * w1) * z1
    bias0 = (a2 * v0 * v0 - a0 * w0 * w0 + 2j * a1 * v0 * w0) * z0
    bias1 = (b2 * v1 * v1 - b0 * w1 * w1 + 2j * b1 * v1 * w1) * z1
    shift0, shift1 = 1j * (0.5 * g0 + g1), 1j * (0.5 * g1)
    jac0, jac1 = gd0 + shift0, gd1 + shift1
    jac_dot0 = (a2 * v0 + 1j * a1 * w0) * z0 + 1j * (0.5 * gv0 + gv1)
    jac_dot1 = (b2 * v1 + 1j * b1 * w1) * z1 + 1j * (0.5 * gv1)
    tip = g0 + g1
    return StepKinematics([g0, tip], [[0.5 * gd0 + 0.25j * g0], [jac0 - shift1, 0.5 * gd1 + 0.25j * g1]],
                          [0.5 * bias0, bias0 + 0.5 * bias1], tip, gv1 + gv0, bias0 + bias1, [jac0, jac1], [jac_dot0, jac_dot1])


def body_terms_2(q0: float, q1: float, v0: float, v1: float, length0: float,
                 length1: float) -> tuple[complex, complex, complex, complex, complex, complex, complex, complex]:
    """The parts of `step_kinematics_2` that the mass matrix, the bias forces and a tip force
    need, for integrators that evaluate the model many times per call (the governors' state
    predictor): (J_c1[0], J_c2[0], J_c2[1], J̇_c1 q̇, J̇_c2 q̇, r, J_r[0], J_r[1]).

    The same operations in the same order as `step_kinematics_2` (so the same floats,
    tested), less the unused terms (ℓ''', J̇_r, ṙ) and the containers; both series of ℓ
    are evaluated in one Horner loop when both angles take the series branch.
    """
    if abs(q0) < _SERIES_SWITCH and abs(q1) < _SERIES_SWITCH:
        x0, x1 = q0 * q0, q1 * q1
        a0 = a1 = a2 = b0 = b1 = b2 = 0.0
        for c0, c1, c2, _ in _HORNER_ROWS:  # `_sinc_half`'s recurrences for a = 0..2, both angles
            a0 = a0 * x0 + c0
            a1 = a1 * x0 + c1
            a2 = a2 * x0 + c2
            b0 = b0 * x1 + c0
            b1 = b1 * x1 + c1
            b2 = b2 * x1 + c2
        a0, a1, a2 = length0 * a0, length0 * (a1 * q0), length0 * a2  # ℓ_1, ℓ_1', ℓ_1''
        b0, b1, b2 = length1 * b0, length1 * (b1 * q1), length1 * b2  # ℓ_2, ℓ_2', ℓ_2''
    else:
        s0, s1, s2, _ = _sinc_half(q0)
        a0, a1, a2 = length0 * s0, length0 * s1, length0 * s2
        s0, s1, s2, _ = _sinc_half(q1)
        b0, b1, b2 = length1 * s0, length1 * s1, length1 * s2
    w0, w1 = 0.5 * v0, v0 + 0.5 * v1
    z0, z1 = cmath.exp(1j * (0.5 * q0)), cmath.exp(1j * (q0 + 0.5 * q1))
    g0, g1 = a0 * z0, b0 * z1
    gd0, gd1 = a1 * z0, b1 * z1
    bias0 = (a2 * v0 * v0 - a0 * w0 * w0 + 2j * a1 * v0 * w0) * z0
    bias1 = (b2 * v1 * v1 - b0 * w1 * w1 + 2j * b1 * v1 * w1) * z1
    shift1 = 1j * (0.5 * g1)
    jac0 = gd0 + 1j * (0.5 * g0 + g1)
    return (0.5 * gd0 + 0.25j * g0, jac0 - shift1, 0.5 * gd1 + 0.25j * g1, 0.5 * bias0, bias0 + 0.5 * bias1,
            g0 + g1, jac0, gd1 + shift1)


def _checked(q, lengths) -> tuple[np.ndarray, np.ndarray]:
    q = as_vector("q", q, None, NonFiniteStateError)
    lengths = as_vector("lengths", lengths, q.shape[0], ControllerInputError)
    if not np.all(lengths > 0):
        raise ControllerInputError(f"lengths must be > 0, got {lengths}")
    return q, lengths


def kinematics(q, lengths, order: int = 1) -> PCCKinematics:
    """Positions and derivatives up to `order` (0..3) of the chord midpoints and the tip.

    q: (N,) bending angles (rad); lengths: (N,) segment lengths L_i (m).
    """
    if order not in range(MAX_ORDER + 1):
        raise ControllerInputError(f"order must be 0..{MAX_ORDER}, got {order!r}")
    return kinematics_unchecked(*_checked(q, lengths), order)


def chord_derivatives(q, lengths) -> np.ndarray:
    """ℓ_i(q_i) and its first three derivatives: shape (N, 4), [i, a] = d^aℓ_i/dq_i^a (m/rad^a)."""
    q, lengths = _checked(q, lengths)
    return _sinc_derivatives(q) * lengths[:, None]


def _xy(z: np.ndarray, axis: int) -> np.ndarray:
    return np.stack((z.real, z.imag), axis=axis)


def ends_array(ends: list[complex]) -> np.ndarray:
    """`StepKinematics.ends` as the (N+1, 2) array p_0 = 0, p_1, …, p_N (m)."""
    return np.array([(0.0, 0.0)] + [(p.real, p.imag) for p in ends])


def segment_ends(q, lengths) -> np.ndarray:
    """p_0 = 0, p_1, …, p_N = r: shape (N+1, 2) (m)."""
    q, lengths = _checked(q, lengths)
    return ends_array(step_kinematics(q.tolist(), [0.0] * q.shape[0], lengths.tolist()).ends)


def segment_orientations(q) -> np.ndarray:
    """θ_0 = 0, θ_1, …, θ_N: tangent angles at the segment ends, shape (N+1,) (rad)."""
    q = as_vector("q", q, None, NonFiniteStateError)
    return np.concatenate(([0.0], np.cumsum(q)))


def centre_positions(q, lengths) -> np.ndarray:
    """Chord midpoints c_i: shape (N, 2) (m)."""
    return _xy(kinematics(q, lengths, order=0).points[:-1], axis=-1)


def centre_jacobians(q, lengths) -> np.ndarray:
    """∂c_i/∂q: shape (N, 2, N), [i] = J_{c_i} (m/rad)."""
    return _xy(kinematics(q, lengths, order=1).jac[:-1], axis=1)


def tip_position(q, lengths) -> np.ndarray:
    """r(q): shape (2,) (m)."""
    return _xy(kinematics(q, lengths, order=0).points[-1], axis=0)


def tip_jacobian(q, lengths) -> np.ndarray:
    """J_r = ∂r/∂q: shape (2, N) (m/rad)."""
    return _xy(kinematics(q, lengths, order=1).jac[-1], axis=0)


def tip_jacobian_derivative(q, lengths) -> np.ndarray:
    """∂J_r/∂q: shape (N, 2, N), [k] = ∂J_r/∂q_k (m/rad²)."""
    return _xy(kinematics(q, lengths, order=2).hess[-1].T, axis=1)


def tip_positions(q, lengths) -> np.ndarray:
    """r(q) for T configurations at once: q (T, N) rad → (T, 2) m (vectorised over T, for tables).

    The chord form of docs/model.md#pcc-kinematics with ℓ_i = L_i sinc(q_i/2) (numpy's sinc, exact at q_i = 0).
    """
    q = np.asarray(q, dtype=float)
    lengths = as_vector("lengths", lengths, None, ControllerInputError)
    if q.ndim != 2 or q.shape[1] != lengths.shape[0]:
        raise ControllerInputError(f"q must have shape (T, {lengths.shape[0]}), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise NonFiniteStateError("q must be finite")
    theta = np.cumsum(q, axis=1) - 0.5 * q  # chord directions φ_i
    chord = lengths * np.sinc(q / (2.0 * np.pi))
    return np.stack(((chord * np.cos(theta)).sum(axis=1), (chord * np.sin(theta)).sum(axis=1)), axis=1)
