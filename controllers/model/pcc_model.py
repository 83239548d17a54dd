"""The PCC model's per-step terms and integrators for B states of any N at once: the one implementation
(docs/model.md#one-implementation, docs/model.md#pcc-kinematics, docs/model.md#rppr-dynamics).

Compiled numba kernels over arrays with a leading batch axis b = 0..B−1: `@njit(cache=True)`
(compiled once per machine into __pycache__), no fastmath (IEEE operations in the written order,
so the results are deterministic and a row of a batch equals the same state evaluated alone,
bit for bit), error_model="numpy" (a division by zero gives ±inf/NaN, which the integrators
report as divergence, instead of raising), the per-row kernels inline="always" (2–3× faster:
no call or array reference counting per row) and handed few arrays: every vector of a row is
addressed as (array, row index), the integrators' per-state vectors all rows of one float work
array (`W_*` rows), never a view or an array of its own (numba reference-counts every array
variable of an inlined kernel; at B = 1024 that halved `advance`'s time, the floats unchanged). Every per-step user of the model goes through
them: `controllers.model.dynamics.PCCDynamics` (B = 1), `BatchDynamics`, the barrier terms of
`controllers.cbf.batch`, `softcbf_mj.physics.pcc_plant.PCCPlant` (B = 1),
`softcbf_mj.physics.pcc_batch_plant.PCCBatchPlant` and `controllers.model.state_predictor.StatePredictor`. The tensor path of `controllers.model.pcc.kinematics`
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
softcbf_mj/physics/pcc_plant.py): 0 "ros2" (the L-stable Rosenbrock W-method with J̃ = [[0, I], [−M⁻¹K,
−M⁻¹D]], solved by block elimination through (M + γhD + (γh)²K)), 1 "rk4", 2 "euler". A state
whose step leaves the finite numbers stops there and is flagged; the caller raises.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np
from numba import njit

from controllers.model.params import RobotParams

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


# Rows of the float work array of the row kernels (`_work`): every per-state vector of a step (x,
# the stages, the acting pressure, the Schur complement, the Cholesky scratch and a stage's `dyn`
# row) is a row of one array, addressed by (array, row), not an array each: in a loop over states
# numba reference-counts every array a kernel is handed, which cost more than the arithmetic.
W_X, W_NEW, W_K1, W_X2, W_K2, W_KS = 0, 1, 2, 3, 4, 5  # W_KS..W_KS + 2: the RK4 stages
W_U, W_ACC, W_TAU, W_RHS, W_GHK, W_RQ, W_RV = 8, 9, 10, 11, 12, 13, 14
W_SCHUR, W_SCHUR_INV, W_CHOL, W_DYN2 = 15, 16, 17, 19  # W_CHOL, W_CHOL + 1: the factor L and L⁻¹
WORK_ROWS = 20


@njit(cache=True, error_model="numpy", inline="always")
def _work(n):
    """The float work array (WORK_ROWS, 2N² + N) of N segments (2N² + N ≥ 2N, N²: every row fits)."""
    return np.empty((WORK_ROWS, 2 * n * n + n))


@njit(cache=True, error_model="numpy", inline="always")
def _inverse(m, mr, mo, out, outr, oo, n, w, cr) -> None:
    """out[outr, oo:oo+N²] = (m[mr, mo:mo+N²])⁻¹ for a small SPD matrix stored flat row-major: closed
    form for N ≤ 2, Cholesky (m = L Lᵀ, m⁻¹ = L⁻ᵀ L⁻¹) beyond; w rows cr, cr + 1: scratch (N²,)."""
    if n == 1:
        out[outr, oo] = 1.0 / m[mr, mo]
        return
    if n == 2:
        a, b, c, d = m[mr, mo], m[mr, mo + 1], m[mr, mo + 2], m[mr, mo + 3]
        det = a * d - b * c
        out[outr, oo], out[outr, oo + 1], out[outr, oo + 2], out[outr, oo + 3] = d / det, -b / det, -c / det, a / det
        return
    il = cr + 1
    for i in range(n * n):
        w[cr, i] = 0.0
        w[il, i] = 0.0
    for i in range(n):
        for j in range(i + 1):
            s = m[mr, mo + i * n + j]
            for k in range(j):
                s -= w[cr, i * n + k] * w[cr, j * n + k]
            w[cr, i * n + j] = math.sqrt(s) if i == j else s / w[cr, j * n + j]
    for j in range(n):  # L⁻¹, lower triangular
        w[il, j * n + j] = 1.0 / w[cr, j * n + j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= w[cr, i * n + k] * w[il, k * n + j]
            w[il, i * n + j] = s / w[cr, i * n + i]
    for i in range(n):
        for j in range(i + 1):
            s = 0.0
            for k in range(i, n):
                s += w[il, k * n + i] * w[il, k * n + j]
            out[outr, oo + i * n + j] = s
            out[outr, oo + j * n + i] = s


@njit(cache=True, error_model="numpy", inline="always")
def _row_kinematics(w, xr, par, pr, kin, kr, cw) -> None:
    """The kinematic part of the `kin` row kin[kr]: everything but r̈₀ and ∂r̈/∂u (module docstring).
    x = [q; q̇] = w[xr, :2N]; par[pr]: the parameter row (lengths first); cw: complex scratch (6, N).
    Rows are indexed in place, never taken as views (nor in the other row kernels): in a loop
    over states their reference counting would cost more than the arithmetic."""
    n = cw.shape[1]
    # cw rows: 0 chords g, 1 ℓ' z, 2 ġ, 3 d/dt(ℓ' z), 4 J̇q̇ of g, 5 s_j
    end = 0j
    theta = 0.0
    theta_dot = 0.0
    for k in range(n):
        qk, qdk, length = w[xr, k], w[xr, n + k], par[pr, k]
        s0, s1, s2, _ = sinc_half(qk)
        l0, l1, l2 = length * s0, length * s1, length * s2
        omega = theta_dot + 0.5 * qdk
        phi = theta + 0.5 * qk
        z = complex(math.cos(phi), math.sin(phi))  # e^{iφ}
        theta += qk
        theta_dot += qdk
        cw[0, k] = l0 * z
        end += cw[0, k]
        kin[kr, k] = end
        cw[1, k] = l1 * z
        cw[2, k] = (l1 * qdk + 1j * l0 * omega) * z
        cw[3, k] = (l2 * qdk + 1j * l1 * omega) * z
        cw[4, k] = (l2 * qdk * qdk - l0 * omega * omega + 2j * l1 * qdk * omega) * z
    suffix = 0j  # Σ_{k>j} g_k
    tip_vel = 0j  # Σ_{k>j} ġ_k, finally ṙ
    for j in range(n - 1, -1, -1):
        cw[5, j] = 1j * (0.5 * cw[0, j] + suffix)
        kin[kr, n + j] = cw[1, j] + cw[5, j]  # J_r
        kin[kr, 2 * n + j] = cw[3, j] + 1j * (0.5 * cw[2, j] + tip_vel)  # J̇_r
        suffix += cw[0, j]
        tip_vel += cw[2, j]
    o_cj = 5 * n + 4
    prefix = 0j
    for i in range(n):
        for j in range(i):
            kin[kr, o_cj + i * n + j] = kin[kr, n + j] - cw[5, i]
        kin[kr, o_cj + i * n + i] = 0.5 * cw[1, i] + 0.25j * cw[0, i]
        for j in range(i + 1, n):
            kin[kr, o_cj + i * n + j] = 0j
        kin[kr, 3 * n + i] = prefix + 0.5 * cw[4, i]
        prefix += cw[4, i]
    kin[kr, 4 * n] = end
    kin[kr, 4 * n + 1] = tip_vel
    kin[kr, 5 * n + 3] = prefix


@njit(cache=True, error_model="numpy")
def kinematics_rows(q: np.ndarray, qd: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """`kin` rows of B states without the dynamics (r̈₀ and ∂r̈/∂u left NaN): q, qd (B, N), lengths (N,) m."""
    b_count, n = q.shape
    kin = np.full((b_count, n * n + 5 * n + 4), np.nan + 0j)
    cw = np.empty((6, n), np.complex128)
    w = _work(n)
    par = _as_row(lengths)
    for b in range(b_count):
        for k in range(n):
            w[W_X, k] = q[b, k]
            w[W_X, n + k] = qd[b, k]
        _row_kinematics(w, W_X, par, 0, kin, b, cw)
    return kin


@njit(cache=True, error_model="numpy", inline="always")
def _row_terms(w, xr, par, pr, kin, kr, dyn, dr, cw) -> None:
    """The model terms of the state x = [q; q̇] = w[xr, :2N] into its `kin` and `dyn` rows kin[kr],
    dyn[dr] (module docstring); par[pr]: the parameter row; w rows W_CHOL, W_CHOL + 1: scratch."""
    n = cw.shape[1]
    nn = n * n
    o_m, o_d, o_k, o_g, o_r = n, 2 * n, 3 * n, 4 * n, 5 * n
    o_cj = 5 * n + 4
    _row_kinematics(w, xr, par, pr, kin, kr, cw)
    # M = M_rot + Σ m_i J_ciᵀ J_ci and f = D q̇ + K q + Σ m_i J_ciᵀ (J̇_ci q̇), summed over j ≤ l ≤ i.
    for j in range(nn):
        dyn[dr, j] = par[pr, o_r + j]
    for j in range(n):
        dyn[dr, 2 * nn + j] = par[pr, o_d + j] * w[xr, n + j] + par[pr, o_k + j] * w[xr, j]
    for i in range(n):
        m_i = par[pr, o_m + i]
        acc = kin[kr, 3 * n + i]
        for j in range(i + 1):
            a = kin[kr, o_cj + i * n + j]
            a_re, a_im = m_i * a.real, m_i * a.imag
            dyn[dr, 2 * nn + j] += a_re * acc.real + a_im * acc.imag
            for l in range(j, i + 1):
                b = kin[kr, o_cj + i * n + l]
                dyn[dr, j * n + l] += a_re * b.real + a_im * b.imag
    for j in range(1, n):
        for l in range(j):
            dyn[dr, j * n + l] = dyn[dr, l * n + j]
    _inverse(dyn, dr, 0, dyn, dr, nn, n, w, W_CHOL)
    # Tip terms: w = M⁻¹ J_r, r̈₀ = J̇_r q̇ − Σ w_i f_i, ∂r̈/∂u_i = w_i λ_i.
    o_t = 4 * n
    drift = 0j
    for i in range(n):
        wi = 0j
        for j in range(n):
            wi += dyn[dr, nn + i * n + j] * kin[kr, n + j]
        drift += wi * dyn[dr, 2 * nn + i]
        kin[kr, o_t + 3 + i] = wi * par[pr, o_g + i]
    kin[kr, o_t + 2] = kin[kr, 5 * n + 3] - drift


@njit(cache=True, error_model="numpy")
def model_terms(q: np.ndarray, qd: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kin, dyn) rows (module docstring) of B states: q, qd (B, N); params (1 or B, 5N + N²)."""
    b_count, n = q.shape
    kin = np.empty((b_count, n * n + 5 * n + 4), np.complex128)
    dyn = np.empty((b_count, 2 * n * n + n))
    cw = np.empty((6, n), np.complex128)
    w = _work(n)
    shared = params.shape[0] == 1
    for b in range(b_count):
        for k in range(n):
            w[W_X, k] = q[b, k]
            w[W_X, n + k] = qd[b, k]
        _row_terms(w, W_X, params, 0 if shared else b, kin, b, dyn, b, cw)
    return kin, dyn


@njit(cache=True, error_model="numpy", inline="always")
def _acceleration(dyn, dr, par, pr, w, n) -> None:
    """w[W_ACC] = q̈ = M⁻¹(Λu − f) of one state (its `dyn` row dyn[dr]), u = w[W_U] (N,) hPa;
    w[W_TAU]: scratch (N,)."""
    nn = n * n
    for j in range(n):
        w[W_TAU, j] = par[pr, 4 * n + j] * w[W_U, j] - dyn[dr, 2 * nn + j]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += dyn[dr, nn + i * n + j] * w[W_TAU, j]
        w[W_ACC, i] = s


@njit(cache=True, error_model="numpy")
def accelerations(dyn: np.ndarray, params: np.ndarray, u: np.ndarray) -> np.ndarray:
    """q̈ (B, N) rad/s² from the `dyn` rows of B states and commands u (B, N) hPa."""
    b_count, n = u.shape
    out = np.empty((b_count, n))
    w = _work(n)
    shared = params.shape[0] == 1
    for b in range(b_count):
        for j in range(n):
            w[W_U, j] = u[b, j]
        _acceleration(dyn, b, params, 0 if shared else b, w, n)
        for j in range(n):
            out[b, j] = w[W_ACC, j]
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _solve_w(mass, mr, w, gh, rqr, ro, rvr, outr, n) -> None:
    """w[outr] = [k_q; k_v] = W⁻¹ [r_q; r_v] with r_q = w[rqr, ro:ro+N], r_v = w[rvr, :N]:
    (M + γhD + (γh)²K) k_v = M r_v − γhK r_q, k_q = r_q + γh k_v. M: mass[mr, :N²];
    (M + γhD + (γh)²K)⁻¹: w[W_SCHUR_INV], γhK: w[W_GHK]; w[W_RHS]: scratch (N,)."""
    for j in range(n):
        s = 0.0
        for l in range(n):
            s += mass[mr, j * n + l] * w[rvr, l]
        w[W_RHS, j] = s - w[W_GHK, j] * w[rqr, ro + j]
    for j in range(n):
        s = 0.0
        for l in range(n):
            s += w[W_SCHUR_INV, j * n + l] * w[W_RHS, l]
        w[outr, n + j] = s
    for j in range(n):
        w[outr, j] = w[rqr, ro + j] + gh * w[outr, n + j]


@njit(cache=True, error_model="numpy", inline="always")
def _ros2_first(w, dyn, dr, par, pr, h, n) -> None:
    """`ros2_first` from x = w[W_X], q̈ = w[W_ACC] into k1 = w[W_K1], x2 = w[W_X2] (2N,) and
    w[W_SCHUR_INV] (N²,), with scratch rows W_SCHUR, W_GHK, W_RHS, W_CHOL, W_CHOL + 1."""
    nn = n * n
    gh = ROS2_GAMMA * h
    for j in range(nn):
        w[W_SCHUR, j] = dyn[dr, j]
    for j in range(n):
        d, k = par[pr, 2 * n + j], par[pr, 3 * n + j]
        w[W_SCHUR, j * n + j] = dyn[dr, j * n + j] + (gh * d + gh * gh * k)
        w[W_GHK, j] = gh * k
    _inverse(w, W_SCHUR, 0, w, W_SCHUR_INV, 0, n, w, W_CHOL)
    _solve_w(dyn, dr, w, gh, W_X, n, W_ACC, W_K1, n)
    for i in range(2 * n):
        w[W_X2, i] = w[W_X, i] + h * w[W_K1, i]


@njit(cache=True, error_model="numpy", inline="always")
def _ros2_second(w, dyn, dr, par, pr, h, n) -> None:
    """`ros2_second` from x = w[W_X], x2 = w[W_X2], k1 = w[W_K1], q̈ at x2 = w[W_ACC] and
    w[W_SCHUR_INV] into w[W_NEW] (2N,), with scratch rows W_GHK, W_RQ, W_RV, W_RHS, W_K2."""
    gh = ROS2_GAMMA * h
    for j in range(n):
        w[W_GHK, j] = gh * par[pr, 3 * n + j]
    for i in range(n):
        w[W_RQ, i] = w[W_X2, n + i] - 2.0 * w[W_K1, i]
        w[W_RV, i] = w[W_ACC, i] - 2.0 * w[W_K1, n + i]
    _solve_w(dyn, dr, w, gh, W_RQ, 0, W_RV, W_K2, n)
    for i in range(2 * n):
        w[W_NEW, i] = w[W_X, i] + (0.5 * h) * (3.0 * w[W_K1, i] + w[W_K2, i])


@njit(cache=True, error_model="numpy", inline="always")
def _as_row(v):
    """A copy of the vector v (any layout) as a (1, len) array, for the row kernels' (array, row) arguments."""
    out = np.empty((1, v.shape[0]))
    for i in range(v.shape[0]):
        out[0, i] = v[i]
    return out


@njit(cache=True, error_model="numpy")
def ros2_first(x, acc, dyn, par, h):
    """First stage of one ROS2 step of length h from x (2N,) with q̈ = acc (N,) and the `dyn` row at x:
    (k1 (2N,), x2 = x + h k1 (2N,), (M + γhD + (γh)²K)⁻¹ flat (N²,)).

    W = I − γhJ̃ is solved through its Schur complement (`_solve_w`); ROS2 (Verwer et al. 1999,
    γ = 1 + 1/√2): k1 = W⁻¹ F(x), k2 = W⁻¹ (F(x + h k1) − 2 k1), x' = x + h(3 k1 + k2)/2.
    """
    n = acc.shape[0]
    w = _work(n)
    for i in range(2 * n):
        w[W_X, i] = x[i]
    for i in range(n):
        w[W_ACC, i] = acc[i]
    _ros2_first(w, _as_row(dyn), 0, _as_row(par), 0, h, n)
    return w[W_K1, :2 * n].copy(), w[W_X2, :2 * n].copy(), w[W_SCHUR_INV, :n * n].copy()


@njit(cache=True, error_model="numpy")
def ros2_second(x, x2, k1, acc2, dyn, schur_inv, par, h):
    """Second stage of the ROS2 step begun by `ros2_first`, with q̈ = acc2 at x2: the new state (2N,)."""
    n = acc2.shape[0]
    w = _work(n)
    for i in range(2 * n):
        w[W_X, i], w[W_X2, i], w[W_K1, i] = x[i], x2[i], k1[i]
    for i in range(n):
        w[W_ACC, i] = acc2[i]
    for i in range(n * n):
        w[W_SCHUR_INV, i] = schur_inv[i]
    _ros2_second(w, _as_row(dyn), 0, _as_row(par), 0, h, n)
    return w[W_NEW, :2 * n].copy()


@njit(cache=True, error_model="numpy", inline="always")
def _step(method, w, par, pr, kin, dyn, dr, h, kin2, cw) -> None:
    """One integrator step of length h from x = w[W_X] (2N,) with u = w[W_U] and (kin, dyn) at x in
    the rows kin[dr], dyn[dr]; the new x into w[W_NEW]. Scratch: the other rows of w (W_DYN2: the
    stages' `dyn` row), kin2 (1, ·) (their `kin` row), cw (6, N) complex."""
    n = cw.shape[1]
    _acceleration(dyn, dr, par, pr, w, n)
    if method == 2:  # forward Euler
        for i in range(n):
            w[W_NEW, i] = w[W_X, i] + h * w[W_X, n + i]
            w[W_NEW, n + i] = w[W_X, n + i] + h * w[W_ACC, i]
        return
    if method == 1:  # classical Runge–Kutta
        for i in range(n):
            w[W_K1, i] = w[W_X, n + i]
            w[W_K1, n + i] = w[W_ACC, i]
        for stage in range(3):
            scale = 0.5 * h if stage < 2 else h
            for i in range(2 * n):
                w[W_X2, i] = w[W_X, i] + scale * (w[W_K1, i] if stage == 0 else w[W_KS + stage - 1, i])
            _row_terms(w, W_X2, par, pr, kin2, 0, w, W_DYN2, cw)
            _acceleration(w, W_DYN2, par, pr, w, n)
            for i in range(n):
                w[W_KS + stage, i] = w[W_X2, n + i]
                w[W_KS + stage, n + i] = w[W_ACC, i]
        for i in range(2 * n):
            w[W_NEW, i] = w[W_X, i] + (h / 6.0) * (w[W_K1, i] + 2.0 * w[W_KS, i] + 2.0 * w[W_KS + 1, i]
                                                   + w[W_KS + 2, i])
        return
    # ROS2
    _ros2_first(w, dyn, dr, par, pr, h, n)
    _row_terms(w, W_X2, par, pr, kin2, 0, w, W_DYN2, cw)
    _acceleration(w, W_DYN2, par, pr, w, n)
    _ros2_second(w, dyn, dr, par, pr, h, n)


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
    w = _work(n)
    kin2 = np.empty((1, kin.shape[1]), np.complex128)
    cw = np.empty((6, n), np.complex128)
    for b in range(b_count):
        pr = 0 if shared else b
        for i in range(2 * n):
            w[W_X, i] = x[b, i]
        for _ in range(substeps):
            if decay >= 0.0:
                for j in range(n):
                    w[W_U, j] = u[b, j] + (pressure[b, j] - u[b, j]) * mean
                    pressure[b, j] = u[b, j] + (pressure[b, j] - u[b, j]) * decay
            else:
                for j in range(n):
                    w[W_U, j] = u[b, j]
            _step(method, w, params, pr, kin, dyn, b, h, kin2, cw)
            finite = True
            for i in range(2 * n):
                if not math.isfinite(w[W_NEW, i]):
                    finite = False
            if not finite:
                diverged[b] = True
                break
            for i in range(2 * n):
                w[W_X, i] = w[W_NEW, i]
            _row_terms(w, W_X, params, pr, kin, b, dyn, b, cw)
        for i in range(2 * n):
            x[b, i] = w[W_X, i]
    return diverged
