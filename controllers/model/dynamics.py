"""Augmented-body (RPPR) dynamics of the planar PCC arm (docs/model.md#rppr-dynamics).

State x = [q; q̇] ∈ R^{2N} (rad, rad/s); input u ∈ R^N (hPa). Each segment is one
rigid body at its chord midpoint c_i (see `controllers.model.pcc`) with mass m_i (kg),
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
entry points `model_terms`, `evaluate_floats`, `acceleration_from_terms` for the filter and the PCC plant):
the compiled kernels of `controllers.model.pcc_model` at B = 1, the one implementation of the model's
per-step terms for any N (the batched paths use the same kernels). `model_terms` keeps the last
state's terms, so a plant and a filter sharing one `PCCDynamics` evaluate each measured state once; its
`parameter_rows` are then what the plant integrates, so only the testbed's own code shares one (its
benchmarks): a plug-in is handed the robot's parameters and builds a model of its own.
Derivative terms (∂M/∂q, C, the Jacobians of q̈) use the tensor path `pcc.kinematics`; the tests
check both against each other and against finite differences.

Energies: kinetic T = ½ q̇ᵀ M q̇, elastic V = ½ qᵀ K q (J); no gravity (docs/model.md#frames-units-conventions).

The plant's implicit integrators get the analytic Jacobians of q̈ = M⁻¹(Λu − Cq̇ − Dq̇ − Kq):
    ∂q̈/∂q = −M⁻¹ (∂(M q̈ + C q̇)/∂q |_{q̈, q̇ fixed} + K),  ∂q̈/∂q̇ = −M⁻¹ (∂(C q̇)/∂q̇ + D),
using third derivatives of c_i (from `controllers.model.pcc`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from controllers.core.errors import NonFiniteCommandError, NonFiniteStateError, as_vector
from controllers.model.params import RobotParams
from controllers.model.pcc import kinematics_unchecked
from controllers.core.lazy_import import lazy_module

pcc_model = lazy_module("controllers.model.pcc_model")  # numba loads on the first kernel call (controllers.core.lazy_import)

if TYPE_CHECKING:
    from controllers.model.pcc_model import ModelLayout


class ModelTerms(NamedTuple):
    """The model terms of one state (q, q̇): its `kin` (complex) and `dyn` (float) rows of
    `controllers.model.pcc_model` (B = 1), sliced by `layout`."""

    kin: np.ndarray
    dyn: np.ndarray
    layout: ModelLayout

    @property
    def mass(self) -> np.ndarray:
        """M(q): (N, N) (kg·m²), a view."""
        n = self.layout.ends.stop
        return self.dyn[self.layout.mass].reshape(n, n)

    @property
    def mass_inv(self) -> np.ndarray:
        """M⁻¹: (N, N) (1/(kg·m²)), a view."""
        n = self.layout.ends.stop
        return self.dyn[self.layout.mass_inv].reshape(n, n)

    @property
    def force(self) -> np.ndarray:
        """C q̇ + D q̇ + K q: (N,) (N·m), a view."""
        return self.dyn[self.layout.force]

    @property
    def ends(self) -> np.ndarray:
        """Segment ends p_1..p_N (complex x + i·y, m), a view."""
        return self.kin[self.layout.ends]


class DynamicsEval:
    """`PCCDynamics.evaluate`'s model terms at one state (complex numbers are x + i·y, m).

    `tip` holds Python scalars, which the barrier reads every control step; the
    array properties are built on access.
    """

    __slots__ = ("tip", "_core", "_gains")

    def __init__(self, core: ModelTerms, gains: np.ndarray) -> None:
        self.tip = tuple(core.kin[core.layout.tip_terms].tolist())  # (r, ṙ, r̈ at u = 0, ∂r̈/∂u_1, …, ∂r̈/∂u_N): m, m/s, m/s², m/s² per hPa
        self._core, self._gains = core, gains

    @property
    def mass(self) -> np.ndarray:
        """M(q): (N, N) (kg·m²)."""
        return self._core.mass.copy()

    @property
    def bias(self) -> np.ndarray:
        """C q̇ + D q̇ + K q: (N,) (N·m)."""
        return self._core.force.copy()

    @property
    def drift_acc(self) -> np.ndarray:
        """q̈ at u = 0, −M⁻¹(C q̇ + D q̇ + K q): (N,) (rad/s²)."""
        return -self._core.mass_inv @ self._core.force

    @property
    def input_acc(self) -> np.ndarray:
        """M⁻¹ Λ = ∂q̈/∂u: (N, N) (rad/s² per hPa)."""
        return self._core.mass_inv * self._gains

    @property
    def tip_terms(self) -> np.ndarray:
        """`tip` as a complex array of shape (N+3,)."""
        return np.array(self.tip)

    @property
    def tip_jac(self) -> np.ndarray:
        """J_r: (N,) complex (m/rad)."""
        return self._core.kin[self._core.layout.tip_jac].copy()

    @property
    def tip_jac_dot(self) -> np.ndarray:
        """J̇_r: (N,) complex (m/(rad·s))."""
        return self._core.kin[self._core.layout.tip_jac_dot].copy()


class PCCDynamics:
    """M, C, K, D, Λ, f, g and q̈ of an N-segment PCC arm with parameters `params`."""

    def __init__(self, params: RobotParams) -> None:
        self.params = params
        self.n = params.n_segments
        self.lengths = params.array("lengths")
        self.stiffness = params.array("stiffness")
        self.damping = params.array("damping")
        self.gains = params.array("gains")
        self._masses = params.array("masses")
        self.parameter_rows = pcc_model.parameter_rows(params)  # (1, 5N + N²): the kernels' parameters
        self.layout = pcc_model.ModelLayout.of(self.n)
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
        """The per-step model terms at (q, q̇) (Python float lists (N,), unchecked): `pcc_model.model_terms`.

        The last state's terms are kept: in a closed loop whose plant and filter share this
        object, the filter reads the state the plant has just evaluated (`keep`).
        """
        last_q, last_qd, last = self._last
        if q == last_q and qd == last_qd:
            return last
        kin, dyn = pcc_model.model_terms(np.array((q,)), np.array((qd,)), self.parameter_rows)
        core = ModelTerms(kin[0], dyn[0], self.layout)
        self._last = (q[:], qd[:], core)
        return core

    def keep(self, q: list[float], qd: list[float], kin: np.ndarray, dyn: np.ndarray) -> ModelTerms:
        """Take (kin, dyn), rows computed elsewhere by `pcc_model` at (q, q̇) with these parameters (a
        plant's integrator), as the last state's terms (`model_terms`); returns them."""
        core = ModelTerms(kin, dyn, self.layout)
        self._last = (q[:], qd[:], core)
        return core

    def evaluate_floats(self, q: list[float], qd: list[float]) -> DynamicsEval:
        """`evaluate` on Python float lists; no input checks."""
        return DynamicsEval(self.model_terms(q, qd), self.gains)

    def evaluate(self, q, qd) -> DynamicsEval:
        """All per-step quantities of the filter at (q, q̇) in one pass."""
        q, qd = self._state(q, qd)
        return self.evaluate_floats(q.tolist(), qd.tolist())

    def acceleration_from_terms(self, core: ModelTerms, u: list[float]) -> list[float]:
        """q̈ = M⁻¹(Λu − C q̇ − D q̇ − K q) from `core` and a Python float list u."""
        return pcc_model.accelerations(core.dyn[None, :], self.parameter_rows, np.array((u,)))[0].tolist()

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

    def acceleration_and_mass_unchecked(self, q: list[float], qd: list[float], u: list[float]) -> tuple[list[float], np.ndarray]:
        """`acceleration_and_mass` on Python float lists (N,), unchecked: (q̈ as a list, M (N, N) read-only view).

        The caller guarantees finite inputs of length N. Same floats as `acceleration_and_mass` (tested).
        """
        core = self.model_terms(q, qd)
        return self.acceleration_from_terms(core, u), core.mass

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
        sol = -core.mass_inv.dot(lhs)
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
