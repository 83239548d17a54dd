"""Predict the arm's state over the estimate's age and the command delay (docs/safety-filter.md, docs/beyond-the-paper.md#filters-beyond-the-paper).

A filter called at time t gets an estimate (q, q̇) captured at t_c ≤ t; the command it
returns acts at the valves from t_a = t + δ (δ: the command delay, s). Between t_c and
t_a the valves saw the filter's earlier commands, each from its own application time.
This module keeps that command history and integrates the model across it:

    M(q) q̈ + C(q, q̇) q̇ + D q̇ + K q = Λ p − J_r(q)ᵀ Σ_i n̂_i ψ(n_i(r(q)))   (docs/model.md#rppr-dynamics, docs/model.md#force-safe-set)
    ṗ = (u(t) − p) / τ_p      (τ_p > 0),      p = u(t)   (τ_p = 0, ideal valve)

(p: the acting pressure, hPa; the plate term, the facets pushing back along their
normals, only when a `plate` is given: the contact-aware energy governor's world.)
u(t) is piecewise constant: u_k from its application time until the next one. p(t)
follows from the history alone (open loop): it starts at 0 hPa at `reset` (vented
valves, the arm at rest) and is advanced exactly, p(t + s) = u + (p(t) − u) e^{−s/τ_p}.

The arm is integrated with the two-stage L-stable Rosenbrock method ROS2 (the PCC
plant's default; γ = 1 + 1/√2, W = I − γhJ̃, J̃ = [[0, I], [−M⁻¹K, −M⁻¹D]]) with steps of at
most `step_s` (default 1 ms; each interval of constant u is split into equal steps) and, per
step, p held at its exact mean over the step (the PCC plant's rule). Without a plate, each
interval is one call of the compiled kernel `controllers.model.pcc_model.advance` (the PCC plant's
integrator, any N); with a plate, one call of `controllers.model.plate_prediction.advance_with_plate`
(the kernel's two ROS2 stages, `ros2_first` and `ros2_second`, per step with the facets' push added
to q̈ in between; ψ a LinearStiffness or PowerLawStiffness, compiled: the per-step Python loop it
replaced, ≈ 50 µs a step, set the contact-aware governor's camera-rate p99).
tests/test_energy_governor.py compares it with a fine integration.

The history keeps, per command, its application time and the exact pressure then, and
drops records older than `horizon_s` (default 2 s) before the latest application time;
look-ups bisect it. `horizon_s` also caps a prediction's span: `can_predict(t_start, t_end)`
holds when t_end − t_start ≤ horizon_s and the history reaches back to t_start
(`oldest_time`), and `predict` refuses anything else. So a prediction costs at most
⌈horizon_s/step_s⌉ steps per interval of constant command (2000 at the defaults): an
estimate 1000 s old is refused at once instead of being integrated over 10⁶ steps
(the energy governor calls it "stale").
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from controllers.model.dynamics import PCCDynamics
from controllers.core.lazy_import import lazy_module
from controllers.model.safe_set import ForceSafeSet, LinearStiffness, PowerLawStiffness

pcc_model = lazy_module("controllers.model.pcc_model")  # numba loads on the first kernel call (controllers.core.lazy_import)
plate_prediction = lazy_module("controllers.model.plate_prediction")


class StatePredictor:
    """Command history, pressure estimate and model integration for one arm (see the module docstring).

    dynamics: the model; actuator_tau: τ_p (s, 0: ideal valve); step_s: largest
    integration step (s); horizon_s: how far back (s) the history reaches; plate: the
    environment whose facets push back on the tip (None: they do not).
    """

    def __init__(self, dynamics: PCCDynamics, actuator_tau: float, step_s: float = 1e-3, horizon_s: float = 2.0,
                 plate: ForceSafeSet | None = None) -> None:
        if not (math.isfinite(actuator_tau) and actuator_tau >= 0):
            raise ValueError(f"actuator_tau must be finite and >= 0 s, got {actuator_tau}")
        if not (math.isfinite(step_s) and step_s > 0):
            raise ValueError(f"step_s must be finite and > 0 s, got {step_s}")
        if not (math.isfinite(horizon_s) and horizon_s > 0):
            raise ValueError(f"horizon_s must be finite and > 0 s, got {horizon_s}")
        self.dynamics = dynamics
        self.n = dynamics.n
        self.tau = float(actuator_tau)
        self.step_s = float(step_s)
        self.horizon_s = float(horizon_s)
        self.plate = plate
        if plate is not None:
            law = plate.stiffness
            if type(law) not in (LinearStiffness, PowerLawStiffness):
                raise ValueError(f"the plate's stiffness law must be LinearStiffness or PowerLawStiffness (compiled in "
                                 f"controllers.model.plate_prediction), got {type(law).__name__}")
            linear = isinstance(law, LinearStiffness)
            self._law = (0 if linear else 1, float(law.k), 1.0 if linear else float(law.exponent))
            self._facets = np.column_stack((plate.environment.normals, plate.environment.offsets))
        self.reset()

    def reset(self) -> None:
        """Vented valves since t = −inf: p = u = 0 hPa, no commands."""
        # Record k: the command u_k acting from time t_k and the pressure p_k at t_k (exact).
        self._times: list[float] = [-math.inf]
        self._commands: list[np.ndarray] = [np.zeros(self.n)]
        self._pressures: list[np.ndarray] = [np.zeros(self.n)]

    def copy(self) -> "StatePredictor":
        """A predictor with the same model and a copy of this one's command history (one per simulation of a
        batched governor, `EnergyGovernor.filter_batch`); the records' arrays are never changed in place, so
        the copy shares them."""
        twin = object.__new__(StatePredictor)
        twin.__dict__.update(self.__dict__)
        twin._times, twin._commands, twin._pressures = list(self._times), list(self._commands), list(self._pressures)
        return twin

    def record(self, t_apply: float, u: np.ndarray) -> None:
        """The command u (N,) hPa acts from t_apply (s) on; times must not decrease."""
        if t_apply < self._times[-1]:
            raise ValueError(f"t_apply must not decrease: got {t_apply} after {self._times[-1]}")
        p = self._advance(self._pressures[-1], self._commands[-1], t_apply - self._times[-1])
        self._times.append(float(t_apply))
        self._commands.append(np.array(u, dtype=float))
        self._pressures.append(p)
        cutoff = t_apply - self.horizon_s
        drop = bisect.bisect_right(self._times, cutoff) - 1  # keep the record acting at the cutoff
        if drop > 0:
            del self._times[:drop], self._commands[:drop], self._pressures[:drop]

    @property
    def oldest_time(self) -> float:
        """The earliest time (s) the predictor knows the command and pressure at (−inf after reset)."""
        return self._times[0]

    @property
    def latest_time(self) -> float:
        """The application time (s) of the latest recorded command (−inf after reset): `record` refuses earlier ones."""
        return self._times[-1]

    def can_predict(self, t_start: float, t_end: float) -> bool:
        """Whether `predict` can go from t_start to t_end (s): oldest_time ≤ t_start ≤ t_end ≤ t_start + horizon_s."""
        return self._times[0] <= t_start <= t_end <= t_start + self.horizon_s

    def command_at(self, t: float) -> np.ndarray:
        """The command acting at the valves at time t (s): (N,) hPa."""
        return self._commands[max(bisect.bisect_right(self._times, t) - 1, 0)]

    def _advance(self, p: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        if self.tau == 0.0 or math.isinf(dt):
            return u.copy()
        return u + (p - u) * math.exp(-dt / self.tau)

    def _pieces(self, t_start: float, t_end: float) -> tuple[np.ndarray, list[tuple[float, float, np.ndarray]]]:
        """p at t_start and the intervals (a, b, u) of constant command u covering [t_start, t_end]."""
        if t_start < self._times[0]:
            raise ValueError(f"t_start = {t_start} s is older than the kept history (from {self._times[0]} s)")
        times, commands = self._times, self._commands
        i = bisect.bisect_right(times, t_start) - 1
        p = self._advance(self._pressures[i], commands[i], t_start - times[i])
        pieces: list[tuple[float, float, np.ndarray]] = []
        a = t_start
        while a < t_end:
            b = min(times[i + 1], t_end) if i + 1 < len(times) else t_end
            if b > a:
                pieces.append((a, b, commands[i]))
            a, i = b, i + 1
        return p, pieces

    def pressure_at(self, t: float) -> np.ndarray:
        """The acting pressure p(t): (N,) hPa."""
        return self._pieces(t, t)[0]

    def predict(self, t_start: float, q, qd, t_end: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q̇, p) at t_end from (q, q̇) at t_start (≤ t_end) through the recorded commands."""
        if not t_end - t_start <= self.horizon_s:
            raise ValueError(f"t_end - t_start must be <= horizon_s = {self.horizon_s} s, got {t_end - t_start} s")
        x = np.array([[float(v) for v in q] + [float(v) for v in qd]])
        p, pieces = self._pieces(t_start, t_end)
        p = p[None, :].copy()
        n, params = self.n, self.dynamics.parameter_rows
        core = self.dynamics.model_terms(x[0, :n].tolist(), x[0, n:].tolist())
        kin, dyn = core.kin[None, :].copy(), core.dyn[None, :].copy()
        for a, b, u in pieces:
            steps = max(1, math.ceil((b - a) / self.step_s - 1e-9))
            h = (b - a) / steps
            decay = math.exp(-h / self.tau) if self.tau > 0 else 0.0  # τ_p = 0: p = u (the ideal valve)
            mean = self.tau / h * -math.expm1(-h / self.tau) if self.tau > 0 else 0.0
            if self.plate is None:
                pcc_model.advance(0, x, u[None, :], p, params, kin, dyn, h, steps, decay, mean)
                continue
            plate_prediction.advance_with_plate(x[0], u, p[0], params, h, steps, decay, mean, self._facets, *self._law)
        return x[0, :n].copy(), x[0, n:].copy(), p[0].copy()
