"""Augmented-body (RPPR) dynamics of the planar PCC arm (docs/model.md#rppr-dynamics).

State x = [q; q̇] ∈ R^{2N} (rad, rad/s); input u ∈ R^N (hPa). Each segment is one
rigid body at its chord midpoint c_i (see `controllers.pcc`) with mass m_i (kg),
rotational inertia I_i (kg·m²) about c_i and orientation φ_i = θ_{i-1} + q_i/2, so
with J_{c_i} = ∂c_i/∂q (2, N) and A = ∂φ/∂q (N, N, constant):

    M(q) = Σ_i m_i J_{c_i}ᵀ J_{c_i} + Aᵀ diag(I) A                     (N, N), kg·m²
    M q̈ + C(q, q̇) q̇ + D q̇ + K q = Λ u                                 (N·m)
    ẋ = f(x) + g(x) u,  f = [q̇; -M⁻¹(C q̇ + D q̇ + K q)],  g = [0; M⁻¹ Λ]

with K = diag(k_i) (N·m/rad), D = diag(d_i) (N·m·s/rad), Λ = diag(λ_i) (N·m/hPa).
C is the Christoffel matrix C_jk = Σ_l ½(∂_l M_jk + ∂_k M_jl − ∂_j M_kl) q̇_l, so
Ṁ − 2C is skew-symmetric. The vector C q̇ equals Σ_i m_i J_{c_i}ᵀ (q̇ᵀ ∂²c_i/∂q² q̇),
the centripetal/Coriolis accelerations of the bodies (the rotational term has no
velocity part: φ is linear in q); that is how the per-step path computes it.

Per-step path (`evaluate`, `acceleration`, `state_derivative`; unchecked Python-list
entry points `model_terms`, `evaluate_floats`, `acceleration_from_terms` for the filter and the PCC plant): Python
scalars on top of `pcc.step_kinematics`, with M⁻¹ in closed form for N ≤ 2 and M,
C q̇ unrolled for N = 2 (the same floats), because numpy's per-call overhead dominates
such small arrays. `model_terms` keeps the last state's terms, so a plant and a filter sharing
one `PCCDynamics` evaluate each measured state once. Derivative terms (∂M/∂q, C, the
Jacobians of q̈) use the tensor path `pcc.kinematics`; the tests check both against
each other and against finite differences.

Energies: kinetic T = ½ q̇ᵀ M q̇, elastic V = ½ qᵀ K q (J); no gravity (docs/model.md#frames-units-conventions).

The plant's implicit integrators get the analytic Jacobians of q̈ = M⁻¹(Λu − Cq̇ − Dq̇ − Kq):
    ∂q̈/∂q = −M⁻¹ (∂(M q̈ + C q̇)/∂q |_{q̈, q̇ fixed} + K),  ∂q̈/∂q̇ = −M⁻¹ (∂(C q̇)/∂q̇ + D),
using third derivatives of c_i (from `controllers.pcc`).
"""

from __future__ import annotations

from operator import mul
from typing import NamedTuple

import numpy as np

from controllers.errors import NonFiniteCommandError, NonFiniteStateError, as_vector
from controllers.params import RobotParams
from controllers.pcc import StepKinematics, body_terms_2, kinematics_unchecked, step_kinematics, kinematic_structure


class DynamicsEval:
    """`PCCDynamics.evaluate`'s model terms at one state (complex numbers are x + i·y, m).

    `tip` holds Python scalars, which the barrier reads every control step; the
    array properties are built on access.
    """

    __slots__ = ("tip", "_mass", "_force", "_mass_inv", "_gains", "_tip_jac", "_tip_jac_dot")

    def __init__(self, tip: tuple, core: "ModelTerms", gains: list[float]) -> None:
        self.tip = tip  # (r, ṙ, r̈ at u = 0, ∂r̈/∂u_1, …, ∂r̈/∂u_N): m, m/s, m/s², m/s² per hPa
        self._mass, self._force, self._mass_inv = core.mass, core.force, core.mass_inv
        self._tip_jac, self._tip_jac_dot = core.kin.tip_jac, core.kin.tip_jac_dot
        self._gains = gains

    @property
    def mass(self) -> np.ndarray:
        """M(q): (N, N) (kg·m²)."""
        return np.array(self._mass)

    @property
    def bias(self) -> np.ndarray:
        """C q̇ + D q̇ + K q: (N,) (N·m)."""
        return np.array(self._force)

    @property
    def drift_acc(self) -> np.ndarray:
        """q̈ at u = 0, −M⁻¹(C q̇ + D q̇ + K q): (N,) (rad/s²)."""
        return -np.array(self._mass_inv) @ np.array(self._force)

    @property
    def input_acc(self) -> np.ndarray:
        """M⁻¹ Λ = ∂q̈/∂u: (N, N) (rad/s² per hPa)."""
        return np.array(self._mass_inv) * np.array(self._gains)

    @property
    def tip_terms(self) -> np.ndarray:
        """`tip` as a complex array of shape (N+3,)."""
        return np.array(self.tip)

    @property
    def tip_jac(self) -> np.ndarray:
        """J_r: (N,) complex (m/rad)."""
        return np.array(self._tip_jac)

    @property
    def tip_jac_dot(self) -> np.ndarray:
        """J̇_r: (N,) complex (m/(rad·s))."""
        return np.array(self._tip_jac_dot)


class ModelTerms(NamedTuple):
    """Python-scalar model terms at (q, q̇): M, C q̇ + D q̇ + K q and M⁻¹ (nested lists)."""

    kin: StepKinematics
    mass: list[list[float]]
    force: list[float]
    mass_inv: list[list[float]]


def spd_inverse(m: list[list[float]]) -> list[list[float]]:
    """M⁻¹ of a small SPD matrix given as nested Python float lists; closed form for N ≤ 2
    (np.linalg.inv costs ~5 µs). For per-step integrators (this module, the PCC plant, the
    governors' state predictor)."""
    if len(m) == 1:
        return [[1.0 / m[0][0]]]
    if len(m) == 2:
        (a, b), (c, d) = m
        det = a * d - b * c
        return [[d / det, -b / det], [-c / det, a / det]]
    return np.linalg.inv(np.array(m)).tolist()


class PCCDynamics:
    """M, C, K, D, Λ, f, g and q̈ of an N-segment PCC arm with parameters `params`."""

    def __init__(self, params: RobotParams) -> None:
        self.params = params
        self.n = n = params.n_segments
        self.lengths = params.array("lengths")
        self.stiffness = params.array("stiffness")
        self.damping = params.array("damping")
        self.gains = params.array("gains")
        self._masses = params.array("masses")
        a = kinematic_structure(n, 1)[0].imag  # A = ∂φ/∂q
        self._mass_rot = (a.T @ (params.array("inertias")[:, None] * a)).tolist()
        self._scalars = (self._masses.tolist(), params.damping, params.stiffness, list(params.gains), list(params.lengths))
        self._stiffness_damping = np.hstack((self.K, self.D))
        self._last: tuple = (None, None, None)  # (q, q̇, ModelTerms) of the last `model_terms` call

    @property
    def K(self) -> np.ndarray:
        """Stiffness matrix diag(k_i): (N, N) (N·m/rad)."""
        return np.diag(self.stiffness)

    @property
    def D(self) -> np.ndarray:
        """Damping matrix diag(d_i): (N, N) (N·m·s/rad)."""
        return np.diag(self.damping)

    @property
    def Lambda(self) -> np.ndarray:
        """Input matrix Λ = diag(λ_i): (N, N) (N·m/hPa)."""
        return np.diag(self.gains)

    # -- input checks -------------------------------------------------------------
    def _state(self, q, qd) -> tuple[np.ndarray, np.ndarray]:
        return as_vector("q", q, self.n, NonFiniteStateError), as_vector("qd", qd, self.n, NonFiniteStateError)

    def _split(self, x) -> tuple[np.ndarray, np.ndarray]:
        x = as_vector("x", x, 2 * self.n, NonFiniteStateError)
        return x[: self.n], x[self.n :]

    def _command(self, u) -> np.ndarray:
        return as_vector("u", u, self.n, NonFiniteCommandError)

    # -- core ---------------------------------------------------------------------
    def model_terms(self, q: list[float], qd: list[float]) -> ModelTerms:
        """The per-step model terms at (q, q̇) (Python floats); see `_mass_and_force`.

        The last state's terms are kept: in a closed loop whose plant and filter share this
        object, the filter reads the state the plant has just evaluated.
        """
        last_q, last_qd, last = self._last
        if q == last_q and qd == last_qd:
            return last
        kin = step_kinematics(q, qd, self._scalars[4])
        mass, force = (self._mass_and_force_2 if self.n == 2 else self._mass_and_force)(kin, q, qd)
        core = ModelTerms(kin, mass, force, spd_inverse(mass))
        self._last = (q[:], qd[:], core)
        return core

    def _mass_and_force(self, kin: StepKinematics, q: list[float], qd: list[float]) -> tuple[list[list[float]], list[float]]:
        """M = Σ m_i J_ciᵀ J_ci + M_rot and C q̇ + D q̇ + K q with C q̇ = Σ m_i J_ciᵀ (J̇_ci q̇), summed over j ≤ l ≤ i."""
        masses, damping, stiffness = self._scalars[:3]
        mass = [row[:] for row in self._mass_rot]
        force = [d * v + k * x for d, v, k, x in zip(damping, qd, stiffness, q)]
        for m_i, row, acc in zip(masses, kin.centre_jac, kin.centre_bias_acc):
            for j, a in enumerate(row):
                a_re, a_im = m_i * a.real, m_i * a.imag
                force[j] += a_re * acc.real + a_im * acc.imag
                mass_j = mass[j]
                for l in range(j, len(row)):
                    mass_j[l] += a_re * row[l].real + a_im * row[l].imag
        for j in range(1, self.n):
            for l in range(j):
                mass[j][l] = mass[l][j]
        return mass, force

    def _mass_and_force_2(self, kin: StepKinematics, q: list[float], qd: list[float]) -> tuple[list[list[float]], list[float]]:
        """`_mass_and_force` for N = 2 unrolled: the same operations in the same order (tested)."""
        ((h0,), (j10, h1)), (acc0, acc1) = kin.centre_jac, kin.centre_bias_acc
        m00, m01, m11, f0, f1 = self._mass_force_terms_2(q[0], q[1], qd[0], qd[1], h0, j10, h1, acc0, acc1)
        return [[m00, m01], [m01, m11]], [f0, f1]

    def _mass_force_terms_2(self, q0: float, q1: float, v0: float, v1: float, h0: complex, j10: complex, h1: complex,
                            acc0: complex, acc1: complex) -> tuple[float, float, float, float, float]:
        """(M_00, M_01, M_11, f_0, f_1) for N = 2 from the bodies' centre Jacobians and bias accelerations
        (x + i·y): the rotational mass plus Σ m_b J_bᵀJ_b, and D q̇ + K q + Σ m_b J_bᵀ J̇_b q̇."""
        (m0, m1), (d0, d1), (k0, k1) = self._scalars[:3]
        ((r00, r01), (_, r11)) = self._mass_rot
        a_re, a_im = m0 * h0.real, m0 * h0.imag  # body 1: J_c1 = [h0, 0]
        f0 = d0 * v0 + k0 * q0 + (a_re * acc0.real + a_im * acc0.imag)
        m00 = r00 + (a_re * h0.real + a_im * h0.imag)
        a_re, a_im = m1 * j10.real, m1 * j10.imag  # body 2: J_c2 = [j10, h1]
        f0 += a_re * acc1.real + a_im * acc1.imag
        m00 += a_re * j10.real + a_im * j10.imag
        m01 = r01 + (a_re * h1.real + a_im * h1.imag)
        a_re, a_im = m1 * h1.real, m1 * h1.imag
        f1 = d1 * v1 + k1 * q1 + (a_re * acc1.real + a_im * acc1.imag)
        m11 = r11 + (a_re * h1.real + a_im * h1.imag)
        return m00, m01, m11, f0, f1

    def evaluate_floats(self, q: list[float], qd: list[float]) -> DynamicsEval:
        """`evaluate` on Python float lists; no input checks."""
        core = self.model_terms(q, qd)
        kin, gains = core.kin, self._scalars[3]
        # w = M⁻¹ J_r (M⁻¹ symmetric): tip acceleration per unit generalised force.
        w = [sum(map(mul, row, kin.tip_jac)) for row in core.mass_inv]
        acc0 = kin.tip_bias_acc - sum(map(mul, w, core.force))
        return DynamicsEval((kin.tip, kin.tip_vel, acc0, *map(mul, w, gains)), core, gains)

    def evaluate(self, q, qd) -> DynamicsEval:
        """All per-step quantities of the filter at (q, q̇) in one pass."""
        q, qd = self._state(q, qd)
        return self.evaluate_floats(q.tolist(), qd.tolist())

    def acceleration_from_terms(self, core: ModelTerms, u: list[float]) -> list[float]:
        """q̈ = M⁻¹(Λu − C q̇ − D q̇ − K q) from `core` and a Python float list u."""
        tau = [g * u_l - f for g, u_l, f in zip(self._scalars[3], u, core.force)]
        return [sum(map(mul, row, tau)) for row in core.mass_inv]


    # -- model terms --------------------------------------------------------------
    def mass_matrix(self, q) -> np.ndarray:
        """M(q): (N, N), symmetric positive definite (kg·m²)."""
        q = as_vector("q", q, self.n, NonFiniteStateError)
        return np.array(self.model_terms(q.tolist(), [0.0] * self.n).mass)

    def mass_matrix_derivative(self, q) -> np.ndarray:
        """∂M/∂q: (N, N, N), [k] = ∂M/∂q_k (kg·m²/rad)."""
        q = as_vector("q", q, self.n, NonFiniteStateError)
        kin = kinematics_unchecked(q, self.lengths, 2)
        n = self.n
        weighted = (self._masses[:, None, None] * kin.hess[:n]).conj()
        half = np.einsum("ijk,il->kjl", weighted, kin.jac[:n]).real  # Σ_i m_i (∂J_ci/∂q_k)ᵀ J_ci
        return half + half.transpose(0, 2, 1)

    def coriolis_matrix(self, q, qd) -> np.ndarray:
        """C(q, q̇) from the Christoffel symbols of M: (N, N) (kg·m²/s)."""
        q, qd = self._state(q, qd)
        dm = self.mass_matrix_derivative(q)  # dm[l, j, k] = ∂_l M_jk
        contracted = dm @ qd  # [j, k] = Σ_l ∂_j M_kl q̇_l
        return 0.5 * (np.tensordot(qd, dm, axes=1) + contracted.T - contracted)

    def acceleration(self, q, qd, u) -> np.ndarray:
        """q̈ = M⁻¹(Λu − C q̇ − D q̇ − K q): (N,) (rad/s²)."""
        q, qd = self._state(q, qd)
        return np.array(self.acceleration_from_terms(self.model_terms(q.tolist(), qd.tolist()), self._command(u).tolist()))

    def acceleration_and_mass(self, q, qd, u) -> tuple[np.ndarray, np.ndarray]:
        """(q̈, M) at (q, q̇, u) from one evaluation: (N,) rad/s² and (N, N) kg·m²."""
        q, qd = self._state(q, qd)
        core = self.model_terms(q.tolist(), qd.tolist())
        return np.array(self.acceleration_from_terms(core, self._command(u).tolist())), np.array(core.mass)

    def acceleration_and_mass_unchecked(self, q: list[float], qd: list[float], u: list[float]) -> tuple[list[float], list[list[float]]]:
        """`acceleration_and_mass` on Python float lists (N,), unchecked: (q̈, M) as lists.

        For per-step integrators outside this module (the governors' state predictor), where
        numpy's per-call overhead would dominate at N ≈ 2; the caller guarantees finite
        inputs of length N. Same floats as `acceleration_and_mass` (tested).
        """
        core = self.model_terms(q, qd)
        return self.acceleration_from_terms(core, u), core.mass

    def acceleration_and_mass_2(self, q0: float, q1: float, v0: float, v1: float, u0: float, u1: float) -> tuple:
        """`acceleration_and_mass_unchecked` for N = 2 on scalars, with M⁻¹ and the tip terms:
        (q̈_0, q̈_1, M_00, M_01, M_11, (M⁻¹)_00, (M⁻¹)_01, (M⁻¹)_11, r, J_r[0], J_r[1])
        in rad/s², kg·m², 1/(kg·m²), m (x + i·y), m/rad.

        For integrators that evaluate the model many times per call (the governors' state
        predictor): `pcc.body_terms_2` and the mass and force terms of `_mass_and_force_2`, then
        `spd_inverse` and `acceleration_from_terms` written out, the same operations in the same
        order (so the same floats, tested), without the containers and the memo.
        """
        (g0, g1), (length0, length1) = self._scalars[3:]
        h0, j10, h1, acc0, acc1, tip, jac0, jac1 = body_terms_2(q0, q1, v0, v1, length0, length1)
        m00, m01, m11, f0, f1 = self._mass_force_terms_2(q0, q1, v0, v1, h0, j10, h1, acc0, acc1)
        det = m00 * m11 - m01 * m01
        i00, i01, i11 = m11 / det, -m01 / det, m00 / det
        tau0, tau1 = g0 * u0 - f0, g1 * u1 - f1
        return i00 * tau0 + i01 * tau1, i01 * tau0 + i11 * tau1, m00, m01, m11, i00, i01, i11, tip, jac0, jac1

    def acceleration_jacobian(self, q, qd, u) -> tuple[np.ndarray, np.ndarray]:
        """(∂q̈/∂q, ∂q̈/∂q̇) at (q, q̇, u), each (N, N) (1/s², 1/s)."""
        q, qd = self._state(q, qd)
        u = self._command(u)
        n = self.n
        core = self.model_terms(q.tolist(), qd.tolist())
        qdd = np.array(self.acceleration_from_terms(core, u.tolist()))
        kin = kinematics_unchecked(q, self.lengths, 3)
        jac, hess = kin.jac[:n], kin.hess[:n]
        jac_dot = hess.dot(qd)  # [i, m] = Σ_j ∂²c_i/∂q_m∂q_j q̇_j  (.dot: less call overhead than @)
        acc = jac.dot(qdd) + jac_dot.dot(qd)  # body accelerations c̈_i
        dacc_dq = hess.dot(qdd) + kin.third[:n].dot(qd).dot(qd)  # [i, m] = ∂c̈_i/∂q_m at fixed q̈, q̇
        weighted_h = jac.conj().T * self._masses  # [j, i] = m_i conj(J_ci[j])
        # ∂(M q̈ + C q̇)/∂q_m = Σ_i m_i [(∂J_ci/∂q_m)ᵀ c̈_i + J_ciᵀ ∂c̈_i/∂q_m];  ∂(C q̇)/∂q̇ = 2 Σ_i m_i J_ciᵀ J̇_ci
        dforce_dq = (self._masses * acc).dot(hess.reshape(n, -1).conj()).reshape(n, n) + weighted_h.dot(dacc_dq)
        dforce_dqd = 2.0 * weighted_h.dot(jac_dot)
        lhs = np.hstack((dforce_dq, dforce_dqd)).real + self._stiffness_damping
        sol = -np.array(core.mass_inv).dot(lhs)
        return sol[:, :n], sol[:, n:]

    def f(self, x) -> np.ndarray:
        """Drift f(x) = [q̇; −M⁻¹(C q̇ + D q̇ + K q)]: (2N,)."""
        q, qd = self._split(x)
        return np.concatenate((qd, self.acceleration_from_terms(self.model_terms(q.tolist(), qd.tolist()), [0.0] * self.n)))

    def g(self, x) -> np.ndarray:
        """Input matrix g(x) = [0; M⁻¹ Λ]: (2N, N)."""
        q, qd = self._split(x)
        return np.vstack((np.zeros((self.n, self.n)), self.evaluate_floats(q.tolist(), qd.tolist()).input_acc))

    def state_derivative(self, x, u) -> np.ndarray:
        """ẋ = f(x) + g(x) u: (2N,)."""
        q, qd = self._split(x)
        return np.concatenate((qd, self.acceleration_from_terms(self.model_terms(q.tolist(), qd.tolist()), self._command(u).tolist())))

    def kinetic_energy(self, q, qd) -> float:
        """T = ½ q̇ᵀ M(q) q̇ (J)."""
        q, qd = self._state(q, qd)
        return 0.5 * float(qd @ self.mass_matrix(q) @ qd)

    def elastic_energy(self, q) -> float:
        """V = ½ qᵀ K q (J)."""
        q = as_vector("q", q, self.n, NonFiniteStateError)
        return 0.5 * float(self.stiffness @ (q * q))
