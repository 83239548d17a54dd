"""The PCC model's per-step terms and integrators for B states of any N at once: the one implementation
(docs/model.md#one-implementation, docs/model.md#pcc-kinematics, docs/model.md#rppr-dynamics).

Compiled numba kernels over arrays with a leading batch axis b = 0..B−1: `@njit(cache=True)`
(compiled once per machine into __pycache__), no fastmath (IEEE operations in the written order,
so the results are deterministic and a row of a batch equals the same state evaluated alone,
bit for bit), error_model="numpy" (a division by zero gives ±inf/NaN, which the integrators
report as divergence, instead of raising), the per-row kernels inline="always" (2–3× faster:
no call or array reference counting per row). Every per-step user of the model goes through
them: `controllers.dynamics.PCCDynamics` (B = 1), `BatchDynamics`, the barrier terms of
`controllers.cbf_batch`, `softcbf_mj.pcc_plant.PCCPlant` (B = 1),
`softcbf_mj.pcc_batch_plant.PCCBatchPlant` and `controllers.state_predictor.StatePredictor`. The tensor path of `controllers.pcc.kinematics`
(second and third derivatives, for ∂M/∂q, C and the Jacobians of q̈) shares the chord
function s(q) = sinc(q/2) of this module (`sinc_half_table`).

Per state (q, q̇) ∈ R^N × R^N (rad, rad/s), with L_k the segment lengths (m), ℓ_k = L_k s(q_k)
the chord lengths, φ_k = θ_{k−1} + q_k/2 the chord directions (θ_k = Σ_{j≤k} q_j), ω = φ̇,
z_k = e^{iφ_k} and points of the plane as complex numbers x + i·y (m):

    g_k = ℓ_k z_k (chords),  ġ_k = (ℓ_k' q̇_k + i ℓ_k ω_k) z_k,
    J̇ q̇ of g_k = (ℓ_k'' q̇_k² − ℓ_k ω_k² + 2i ℓ_k' q̇_k ω_k) z_k,
    J_r[j] = ℓ_j' z_j + s_j,  s_j = i(½ g_j + Σ_{k>j} g_k),  J_{c_i}[j] = J_r[j] − s_i (j < i),
    J_{c_i}[i] = ½ ℓ_i' z_i + ¼ i g_i,   J̇_r[j] = (ℓ_j'' q̇_j + i ℓ_j' ω_j) z_j + i(½ ġ_j + Σ_{k>j} ġ_k),

then M = Σ_i m_i J_{c_i}ᵀ J_{c_i} + Aᵀ diag(I) A (kg·m²), f = C q̇ + D q̇ + K q with
C q̇ = Σ_i m_i J_{c_i}ᵀ (J̇_{c_i} q̇) (N·m), M⁻¹ (closed form for N ≤ 2, Cholesky for N > 2),
q̈ = M⁻¹(Λu − f) (rad/s²) and the tip terms the barrier reads: r, ṙ, r̈ at u = 0
(= J̇_r q̇ − w·f with w = M⁻¹J_r) and ∂r̈/∂u_j = w_j λ_j (m/s² per hPa).

s(q) and its derivatives: a Taylor series in q (Horner, degree 19) for |q| < 2, where the
closed forms cancel catastrophically, and the closed forms beyond (accurate to a few ulp;
tests/test_pcc.py compares them with exact rational sums).

Layouts (per state; `ModelLayout` names the slices):
- parameters `params` (P, 5N + N²), P = 1 (shared) or B (one arm per state): L, m, d, k, λ, then
  Aᵀ diag(I) A row-major;
- `kin` (B, N² + 5N + 4) complex: segment ends p_1..p_N, J_r, J̇_r, J̇_{c_i} q̇, the tip terms
  (r, ṙ, r̈₀, ∂r̈/∂u_1..N), J̇_r q̇, then J_{c_i}[j] row-major (zero for j > i);
- `dyn` (B, 2N² + N) float: M row-major, M⁻¹ row-major, f.

Integrators (`advance`, one control period of `substeps` fixed steps h, the command held and,
with a valve lag, the acting pressure held at its exact mean over each step; see
softcbf_mj/pcc_plant.py): 0 "ros2" (the L-stable Rosenbrock W-method with J̃ = [[0, I], [−M⁻¹K,
−M⁻¹D]], solved by block elimination through (M + γhD + (γh)²K)), 1 "rk4", 2 "euler". A state
whose step leaves the finite numbers stops there and is flagged; the caller raises.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np
from numba import njit

from controllers.params import RobotParams

SERIES_SWITCH = 2.0  # |q| (rad) below which s(q) comes from its Taylor series (|q/2| < 1)
SERIES_DEGREE = 19  # powers q^0..q^19; first omitted term < 1e-21 relative at |q| = 2
INTEGRATOR_CODES = {"ros2": 0, "rk4": 1, "euler": 2}
ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


def _horner_rows(degree: int) -> np.ndarray:
    """(R, 4): per Horner step (highest power first) the coefficients of s^(a), a = 0..3.

    From s(q) = Σ_k d_k q^{2k}, d_k = (−1)^k / ((2k+1)! 4^k): s^(a) = q^(a mod 2) · poly_a(q²).
    """
    series = np.zeros((degree + 1, 4))
    for k in range(degree // 2 + 3):
        d_k = (-1.0) ** k / (math.factorial(2 * k + 1) * 4.0**k)
        for a in range(4):
            p = 2 * k - a
            if 0 <= p <= degree:
                series[p, a] = d_k * math.perm(2 * k, a)
    columns = [series[a % 2 :: 2, a][::-1] for a in range(4)]
    return np.ascontiguousarray(np.column_stack(columns))


HORNER_ROWS = _horner_rows(SERIES_DEGREE)
HORNER_ROWS.setflags(write=False)


@njit(cache=True, error_model="numpy", inline="always")
def sinc_half(q: float) -> tuple[float, float, float, float]:
    """s^(a)(q) for s(q) = sinc(q/2) = ℓ/L and a = 0..3 (module docstring)."""
    if abs(q) < SERIES_SWITCH:
        x = q * q
        s0 = s1 = s2 = s3 = 0.0
        for r in range(HORNER_ROWS.shape[0]):
            s0 = s0 * x + HORNER_ROWS[r, 0]
            s1 = s1 * x + HORNER_ROWS[r, 1]
            s2 = s2 * x + HORNER_ROWS[r, 2]
            s3 = s3 * x + HORNER_ROWS[r, 3]
        return s0, s1 * q, s2, s3 * q
    # x s0 = sin x, differentiated thrice: s0 + x s1 = cos x, 2 s1 + x s2 = −sin x, 3 s2 + x s3 = −cos x.
    x = 0.5 * q
    sin, cos = math.sin(x), math.cos(x)
    s0 = sin / x
    s1 = (cos - s0) / x
    s2 = -s0 - 2.0 * s1 / x
    s3 = -(cos + 3.0 * s2) / x
    return s0, 0.5 * s1, 0.25 * s2, 0.125 * s3  # d^a/dq^a = 2^{−a} d^a/dx^a


@njit(cache=True, error_model="numpy")
def sinc_half_table(q: np.ndarray) -> np.ndarray:
    """`sinc_half` of every q_i: (N,) → (N, 4)."""
    out = np.empty((q.shape[0], 4))
    for i in range(q.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = sinc_half(q[i])
    return out


class ModelLayout(NamedTuple):
    """Column slices of the `kin` (complex) and `dyn` (float) rows for N segments (module docstring)."""

    ends: slice
    tip_jac: slice
    tip_jac_dot: slice
    centre_bias_acc: slice
    tip_terms: slice  # r, ṙ, r̈₀, ∂r̈/∂u_1..N
    tip_bias_acc: int
    centre_jac: slice
    mass: slice
    mass_inv: slice
    force: slice

    @staticmethod
    def of(n: int) -> "ModelLayout":
        nn = n * n
        return ModelLayout(slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n), slice(3 * n, 4 * n),
                           slice(4 * n, 5 * n + 3), 5 * n + 3, slice(5 * n + 4, 5 * n + 4 + nn),
                           slice(0, nn), slice(nn, 2 * nn), slice(2 * nn, 2 * nn + n))


def parameter_rows(params: RobotParams | Sequence[RobotParams]) -> np.ndarray:
    """`params` (one arm, or one per state) as the kernels' (P, 5N + N²) parameter rows."""
    models = [params] if isinstance(params, RobotParams) else list(params)
    if not models:
        raise ValueError("params must be one RobotParams or a non-empty sequence of them")
    n = models[0].n_segments
    if any(p.n_segments != n for p in models):
        raise ValueError(f"every arm of a batch must have the same number of segments, got {[p.n_segments for p in models]}")
    a = np.tril(np.ones((n, n)), -1) + 0.5 * np.eye(n)  # A = ∂φ/∂q
    rows = []
    for p in models:
        rot = a.T @ (p.array("inertias")[:, None] * a)
        rows.append(np.concatenate([p.array(name) for name in ("lengths", "masses", "damping", "stiffness", "gains")]
                                   + [rot.ravel()]))
    return np.ascontiguousarray(np.array(rows, dtype=float))


@njit(cache=True, error_model="numpy", inline="always")
def _inverse(m, mo, out, oo, n, chol, inv_l) -> None:
    """out[oo:oo+N²] = (m[mo:mo+N²])⁻¹ for a small SPD matrix stored flat row-major: closed form for
    N ≤ 2, Cholesky (m = L Lᵀ, m⁻¹ = L⁻ᵀ L⁻¹) beyond; chol, inv_l: scratch (N²,)."""
    if n == 1:
        out[oo] = 1.0 / m[mo]
        return
    if n == 2:
        a, b, c, d = m[mo], m[mo + 1], m[mo + 2], m[mo + 3]
        det = a * d - b * c
        out[oo], out[oo + 1], out[oo + 2], out[oo + 3] = d / det, -b / det, -c / det, a / det
        return
    for i in range(n * n):
        chol[i] = 0.0
        inv_l[i] = 0.0
    for i in range(n):
        for j in range(i + 1):
            s = m[mo + i * n + j]
            for k in range(j):
                s -= chol[i * n + k] * chol[j * n + k]
            chol[i * n + j] = math.sqrt(s) if i == j else s / chol[j * n + j]
    for j in range(n):  # L⁻¹, lower triangular
        inv_l[j * n + j] = 1.0 / chol[j * n + j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= chol[i * n + k] * inv_l[k * n + j]
            inv_l[i * n + j] = s / chol[i * n + i]
    for i in range(n):
        for j in range(i + 1):
            s = 0.0
            for k in range(i, n):
                s += inv_l[k * n + i] * inv_l[k * n + j]
            out[oo + i * n + j] = s
            out[oo + j * n + i] = s


@njit(cache=True, error_model="numpy", inline="always")
def _row_kinematics(x, par, kin, cw) -> None:
    """The kinematic part of one state's `kin` row: everything but r̈₀ and ∂r̈/∂u (module docstring).
    x = [q; q̇] (2N,); par: the parameter row (lengths first); cw: complex scratch (6, N).
    No array views are made here (nor in the other row kernels): in a loop over states
    their reference counting would cost more than the arithmetic."""
    n = cw.shape[1]
    # cw rows: 0 chords g, 1 ℓ' z, 2 ġ, 3 d/dt(ℓ' z), 4 J̇q̇ of g, 5 s_j (indexed in place: no views)
    end = 0j
    theta = 0.0
    theta_dot = 0.0
    for k in range(n):
        qk, qdk, length = x[k], x[n + k], par[k]
        s0, s1, s2, _ = sinc_half(qk)
        l0, l1, l2 = length * s0, length * s1, length * s2
        omega = theta_dot + 0.5 * qdk
        phi = theta + 0.5 * qk
        z = complex(math.cos(phi), math.sin(phi))  # e^{iφ}
        theta += qk
        theta_dot += qdk
        cw[0, k] = l0 * z
        end += cw[0, k]
        kin[k] = end
        cw[1, k] = l1 * z
        cw[2, k] = (l1 * qdk + 1j * l0 * omega) * z
        cw[3, k] = (l2 * qdk + 1j * l1 * omega) * z
        cw[4, k] = (l2 * qdk * qdk - l0 * omega * omega + 2j * l1 * qdk * omega) * z
    suffix = 0j  # Σ_{k>j} g_k
    tip_vel = 0j  # Σ_{k>j} ġ_k, finally ṙ
    for j in range(n - 1, -1, -1):
        cw[5, j] = 1j * (0.5 * cw[0, j] + suffix)
        kin[n + j] = cw[1, j] + cw[5, j]  # J_r
        kin[2 * n + j] = cw[3, j] + 1j * (0.5 * cw[2, j] + tip_vel)  # J̇_r
        suffix += cw[0, j]
        tip_vel += cw[2, j]
    o_cj = 5 * n + 4
    prefix = 0j
    for i in range(n):
        for j in range(i):
            kin[o_cj + i * n + j] = kin[n + j] - cw[5, i]
        kin[o_cj + i * n + i] = 0.5 * cw[1, i] + 0.25j * cw[0, i]
        for j in range(i + 1, n):
            kin[o_cj + i * n + j] = 0j
        kin[3 * n + i] = prefix + 0.5 * cw[4, i]
        prefix += cw[4, i]
    kin[4 * n] = end
    kin[4 * n + 1] = tip_vel
    kin[5 * n + 3] = prefix


@njit(cache=True, error_model="numpy")
def kinematics_rows(q: np.ndarray, qd: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """`kin` rows of B states without the dynamics (r̈₀ and ∂r̈/∂u left NaN): q, qd (B, N), lengths (N,) m."""
    b_count, n = q.shape
    kin = np.full((b_count, n * n + 5 * n + 4), np.nan + 0j)
    cw = np.empty((6, n), np.complex128)
    xs = np.empty(2 * n)
    for b in range(b_count):
        for k in range(n):
            xs[k] = q[b, k]
            xs[n + k] = qd[b, k]
        _row_kinematics(xs, lengths, kin[b], cw)
    return kin


@njit(cache=True, error_model="numpy", inline="always")
def _row_terms(x, par, kin, dyn, cw, chol, inv_l) -> None:
    """The model terms of the state x = [q; q̇] (2N,) into its `kin` and `dyn` rows (module docstring)."""
    n = cw.shape[1]
    nn = n * n
    o_m, o_d, o_k, o_g, o_r = n, 2 * n, 3 * n, 4 * n, 5 * n
    o_cj = 5 * n + 4
    _row_kinematics(x, par, kin, cw)
    # M = M_rot + Σ m_i J_ciᵀ J_ci and f = D q̇ + K q + Σ m_i J_ciᵀ (J̇_ci q̇), summed over j ≤ l ≤ i.
    for j in range(nn):
        dyn[j] = par[o_r + j]
    for j in range(n):
        dyn[2 * nn + j] = par[o_d + j] * x[n + j] + par[o_k + j] * x[j]
    for i in range(n):
        m_i = par[o_m + i]
        acc = kin[3 * n + i]
        for j in range(i + 1):
            a = kin[o_cj + i * n + j]
            a_re, a_im = m_i * a.real, m_i * a.imag
            dyn[2 * nn + j] += a_re * acc.real + a_im * acc.imag
            for l in range(j, i + 1):
                b = kin[o_cj + i * n + l]
                dyn[j * n + l] += a_re * b.real + a_im * b.imag
    for j in range(1, n):
        for l in range(j):
            dyn[j * n + l] = dyn[l * n + j]
    _inverse(dyn, 0, dyn, nn, n, chol, inv_l)
    # Tip terms: w = M⁻¹ J_r, r̈₀ = J̇_r q̇ − Σ w_i f_i, ∂r̈/∂u_i = w_i λ_i.
    o_t = 4 * n
    drift = 0j
    for i in range(n):
        w = 0j
        for j in range(n):
            w += dyn[nn + i * n + j] * kin[n + j]
        drift += w * dyn[2 * nn + i]
        kin[o_t + 3 + i] = w * par[o_g + i]
    kin[o_t + 2] = kin[5 * n + 3] - drift


@njit(cache=True, error_model="numpy")
def model_terms(q: np.ndarray, qd: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kin, dyn) rows (module docstring) of B states: q, qd (B, N); params (1 or B, 5N + N²)."""
    b_count, n = q.shape
    kin = np.empty((b_count, n * n + 5 * n + 4), np.complex128)
    dyn = np.empty((b_count, 2 * n * n + n))
    cw = np.empty((6, n), np.complex128)
    chol, inv_l, xs = np.empty(n * n), np.empty(n * n), np.empty(2 * n)
    shared = params.shape[0] == 1
    for b in range(b_count):
        for k in range(n):
            xs[k] = q[b, k]
            xs[n + k] = qd[b, k]
        _row_terms(xs, params[0 if shared else b], kin[b], dyn[b], cw, chol, inv_l)
    return kin, dyn


@njit(cache=True, error_model="numpy", inline="always")
def _acceleration(dyn, par, u, out, tau) -> None:
    """out = q̈ = M⁻¹(Λu − f) of one state (its `dyn` row), u (N,) hPa; tau: scratch (N,)."""
    n = u.shape[0]
    nn = n * n
    for j in range(n):
        tau[j] = par[4 * n + j] * u[j] - dyn[2 * nn + j]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += dyn[nn + i * n + j] * tau[j]
        out[i] = s


@njit(cache=True, error_model="numpy")
def accelerations(dyn: np.ndarray, params: np.ndarray, u: np.ndarray) -> np.ndarray:
    """q̈ (B, N) rad/s² from the `dyn` rows of B states and commands u (B, N) hPa."""
    b_count, n = u.shape
    out = np.empty((b_count, n))
    tau, acc, ub = np.empty(n), np.empty(n), np.empty(n)
    shared = params.shape[0] == 1
    for b in range(b_count):
        for j in range(n):
            ub[j] = u[b, j]
        _acceleration(dyn[b], params[0 if shared else b], ub, acc, tau)
        for j in range(n):
            out[b, j] = acc[j]
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _solve_w(mass, schur_inv, ghk, gh, r_q, ro, r_v, out, rhs) -> None:
    """out = [k_q; k_v] = W⁻¹ [r_q; r_v] with r_q = r_q[ro:ro+N]: (M + γhD + (γh)²K) k_v = M r_v − γhK r_q,
    k_q = r_q + γh k_v. mass (M first, flat), schur_inv flat (N²,); rhs: scratch (N,)."""
    n = ghk.shape[0]
    for j in range(n):
        s = 0.0
        for l in range(n):
            s += mass[j * n + l] * r_v[l]
        rhs[j] = s - ghk[j] * r_q[ro + j]
    for j in range(n):
        s = 0.0
        for l in range(n):
            s += schur_inv[j * n + l] * rhs[l]
        out[n + j] = s
    for j in range(n):
        out[j] = r_q[ro + j] + gh * out[n + j]


@njit(cache=True, error_model="numpy", inline="always")
def _ros2_first(x, acc, dyn, par, h, k1, x2, schur, schur_inv, ghk, rhs, chol, inv_l) -> None:
    """`ros2_first` into k1, x2 (2N,), schur_inv (N²,), with scratch schur (N²,), ghk, rhs (N,), chol, inv_l."""
    n = acc.shape[0]
    nn = n * n
    gh = ROS2_GAMMA * h
    for j in range(nn):
        schur[j] = dyn[j]
    for j in range(n):
        d, k = par[2 * n + j], par[3 * n + j]
        schur[j * n + j] = dyn[j * n + j] + (gh * d + gh * gh * k)
        ghk[j] = gh * k
    _inverse(schur, 0, schur_inv, 0, n, chol, inv_l)
    _solve_w(dyn, schur_inv, ghk, gh, x, n, acc, k1, rhs)
    for i in range(2 * n):
        x2[i] = x[i] + h * k1[i]


@njit(cache=True, error_model="numpy", inline="always")
def _ros2_second(x, x2, k1, acc2, dyn, schur_inv, par, h, new, ghk, r_q, r_v, k2, rhs) -> None:
    """`ros2_second` into new (2N,), with scratch ghk, r_q, r_v, rhs (N,), k2 (2N,)."""
    n = acc2.shape[0]
    gh = ROS2_GAMMA * h
    for j in range(n):
        ghk[j] = gh * par[3 * n + j]
    for i in range(n):
        r_q[i] = x2[n + i] - 2.0 * k1[i]
        r_v[i] = acc2[i] - 2.0 * k1[n + i]
    _solve_w(dyn, schur_inv, ghk, gh, r_q, 0, r_v, k2, rhs)
    for i in range(2 * n):
        new[i] = x[i] + (0.5 * h) * (3.0 * k1[i] + k2[i])


@njit(cache=True, error_model="numpy")
def ros2_first(x, acc, dyn, par, h):
    """First stage of one ROS2 step of length h from x (2N,) with q̈ = acc (N,) and the `dyn` row at x:
    (k1 (2N,), x2 = x + h k1 (2N,), (M + γhD + (γh)²K)⁻¹ flat (N²,)).

    W = I − γhJ̃ is solved through its Schur complement (`_solve_w`); ROS2 (Verwer et al. 1999,
    γ = 1 + 1/√2): k1 = W⁻¹ F(x), k2 = W⁻¹ (F(x + h k1) − 2 k1), x' = x + h(3 k1 + k2)/2.
    """
    n = acc.shape[0]
    k1, x2, schur, schur_inv = np.empty(2 * n), np.empty(2 * n), np.empty(n * n), np.empty(n * n)
    _ros2_first(x, acc, dyn, par, h, k1, x2, schur, schur_inv, np.empty(n), np.empty(n), np.empty(n * n),
                np.empty(n * n))
    return k1, x2, schur_inv


@njit(cache=True, error_model="numpy")
def ros2_second(x, x2, k1, acc2, dyn, schur_inv, par, h):
    """Second stage of the ROS2 step begun by `ros2_first`, with q̈ = acc2 at x2: the new state (2N,)."""
    n = acc2.shape[0]
    new = np.empty(2 * n)
    _ros2_second(x, x2, k1, acc2, dyn, schur_inv, par, h, new, np.empty(n), np.empty(n), np.empty(n),
                 np.empty(2 * n), np.empty(n))
    return new


@njit(cache=True, error_model="numpy", inline="always")
def _step(method, x, u, par, kin, dyn, h, new, acc, k1, x2, k2, ks, schur, schur_inv, tau, rhs, ghk, r_q, r_v, chol,
          inv_l, kin2, dyn2, cw) -> None:
    """One integrator step of length h from x (2N,) with (kin, dyn) at x; the new x into `new` (2N,).
    Scratch: acc, tau, rhs, ghk, r_q, r_v (N,); k1, x2, k2 (2N,); ks (3, 2N); schur, schur_inv, chol,
    inv_l (N²,); kin2, dyn2: rows; cw (6, N) complex."""
    n = u.shape[0]
    _acceleration(dyn, par, u, acc, tau)
    if method == 2:  # forward Euler
        for i in range(n):
            new[i] = x[i] + h * x[n + i]
            new[n + i] = x[n + i] + h * acc[i]
        return
    if method == 1:  # classical Runge–Kutta
        for i in range(n):
            k1[i] = x[n + i]
            k1[n + i] = acc[i]
        for stage in range(3):
            scale = 0.5 * h if stage < 2 else h
            for i in range(2 * n):
                x2[i] = x[i] + scale * (k1[i] if stage == 0 else ks[stage - 1, i])
            _row_terms(x2, par, kin2, dyn2, cw, chol, inv_l)
            _acceleration(dyn2, par, u, acc, tau)
            for i in range(n):
                ks[stage, i] = x2[n + i]
                ks[stage, n + i] = acc[i]
        for i in range(2 * n):
            new[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * ks[0, i] + 2.0 * ks[1, i] + ks[2, i])
        return
    # ROS2
    _ros2_first(x, acc, dyn, par, h, k1, x2, schur, schur_inv, ghk, rhs, chol, inv_l)
    _row_terms(x2, par, kin2, dyn2, cw, chol, inv_l)
    _acceleration(dyn2, par, u, acc, tau)
    _ros2_second(x, x2, k1, acc, dyn, schur_inv, par, h, new, ghk, r_q, r_v, k2, rhs)


@njit(cache=True, error_model="numpy")
def advance(method: int, x: np.ndarray, u: np.ndarray, pressure: np.ndarray, params: np.ndarray, kin: np.ndarray,
            dyn: np.ndarray, h: float, substeps: int, decay: float, mean: float):
    """One control period of B states (module docstring), in place.

    x (B, 2N) rad, rad/s; u (B, N) hPa held; pressure (B, N) hPa, the acting pressure p, used
    when decay ≥ 0 (valve lag: per step the arm sees u + (p − u)·mean, then p ← u + (p − u)·decay),
    ignored when decay < 0 (ideal valve); kin, dyn: the terms at x, replaced by those at the
    new x. Returns (B,) bool: the state left the finite numbers (x, kin, dyn of that state hold
    the last finite step's values; the period's others are finished).
    """
    b_count, n = u.shape
    shared = params.shape[0] == 1
    diverged = np.zeros(b_count, np.bool_)
    acting, acc = np.empty(n), np.empty(n)
    xb, new, k1, x2 = np.empty(2 * n), np.empty(2 * n), np.empty(2 * n), np.empty(2 * n)
    k2, ks = np.empty(2 * n), np.empty((3, 2 * n))
    tau, rhs, ghk, r_q, r_v = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    schur, schur_inv, chol, inv_l = np.empty(n * n), np.empty(n * n), np.empty(n * n), np.empty(n * n)
    kin2 = np.empty(kin.shape[1], np.complex128)
    dyn2 = np.empty(dyn.shape[1])
    cw = np.empty((6, n), np.complex128)
    for b in range(b_count):
        par = params[0 if shared else b]
        kb, db = kin[b], dyn[b]
        for i in range(2 * n):
            xb[i] = x[b, i]
        for _ in range(substeps):
            if decay >= 0.0:
                for j in range(n):
                    acting[j] = u[b, j] + (pressure[b, j] - u[b, j]) * mean
                    pressure[b, j] = u[b, j] + (pressure[b, j] - u[b, j]) * decay
            else:
                for j in range(n):
                    acting[j] = u[b, j]
            _step(method, xb, acting, par, kb, db, h, new, acc, k1, x2, k2, ks, schur, schur_inv, tau, rhs, ghk, r_q, r_v,
                  chol, inv_l, kin2, dyn2, cw)
            finite = True
            for i in range(2 * n):
                if not math.isfinite(new[i]):
                    finite = False
            if not finite:
                diverged[b] = True
                break
            for i in range(2 * n):
                xb[i] = new[i]
            _row_terms(xb, par, kb, db, cw, chol, inv_l)
        for i in range(2 * n):
            x[b, i] = xb[i]
    return diverged
