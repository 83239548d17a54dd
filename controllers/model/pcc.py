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

ℓ and its derivatives come from s(q) = sinc(q/2) = ℓ/L (`controllers.model.pcc_model.sinc_half`,
the one evaluation of s): a Taylor series in q for |q| < 2, where the closed forms cancel
catastrophically, and the closed forms (well-conditioned there) for |q| ≥ 2. Every
derivative is then smooth, finite through q = 0 and accurate to a few ulp (the tests
compare with exact rational sums).

Two evaluation paths share these formulas: `kinematics` (numpy tensors, any order ≤ 3,
for derivatives, the plant's Jacobian and the public wrappers) and the compiled per-step
kernels of `controllers.model.pcc_model` (first order plus the q̇-terms, any N, a leading batch
axis; `step_kinematics` here is their B = 1 form). Tests check one path against the other.
"""

from __future__ import annotations

import itertools
from functools import lru_cache
from typing import NamedTuple, Sequence

import numpy as np

from controllers.core.errors import ControllerInputError, NonFiniteStateError, as_vector
from controllers.core.lazy_import import lazy_module

pcc_model = lazy_module("controllers.model.pcc_model")  # numba loads on the first kernel call (controllers.core.lazy_import)

MAX_ORDER = 3


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
    coef = pcc_model.sinc_half_table(q)[:, : order + 1] * weight[:, None]
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

    The kinematic part of `controllers.model.pcc_model`'s kernel (module docstring there), the one
    per-step implementation, at B = 1.
    """
    n = len(q)
    row = pcc_model.kinematics_rows(np.array((q,), dtype=float), np.array((qd,), dtype=float), np.asarray(lengths, dtype=float))[0]
    layout = pcc_model.ModelLayout.of(n)
    centre = row[layout.centre_jac].tolist()
    tip, tip_vel = row[layout.tip_terms][:2].tolist()
    return StepKinematics(row[layout.ends].tolist(), [centre[i * n : i * n + i + 1] for i in range(n)],
                          row[layout.centre_bias_acc].tolist(), tip, tip_vel, row[layout.tip_bias_acc].item(),
                          row[layout.tip_jac].tolist(), row[layout.tip_jac_dot].tolist())


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
    return pcc_model.sinc_half_table(q) * lengths[:, None]


def _xy(z: np.ndarray, axis: int) -> np.ndarray:
    return np.stack((z.real, z.imag), axis=axis)


def segment_ends(q, lengths) -> np.ndarray:
    """p_0 = 0, p_1, …, p_N = r: shape (N+1, 2) (m)."""
    q, lengths = _checked(q, lengths)
    ends = step_kinematics(q.tolist(), [0.0] * q.shape[0], lengths.tolist()).ends
    return np.array([(0.0, 0.0)] + [(p.real, p.imag) for p in ends])


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
