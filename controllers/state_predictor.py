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
plant's default; γ = 1 + 1/√2, W = I − γhJ̃, J̃ = [[0, I], [−M⁻¹K, −M⁻¹D]]) through the
public `PCCDynamics.acceleration_and_mass_unchecked` (Python floats: numpy's per-call
overhead would dominate at N ≈ 2), with steps of at most `step_s` (default 1 ms;
each interval of constant u is split into equal steps) and, per step, p held at its exact
mean over the step (the PCC plant's rule). tests/test_energy_governor.py compares it
with a fine integration. For N = 2 the loop runs on scalars through
`PCCDynamics.acceleration_and_mass_2` (the same operations, so the same floats:
tests/test_fast_paths.py), about 4× faster: the integration is most of a camera-rate call.

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

from controllers.dynamics import PCCDynamics, spd_inverse
from controllers.safe_set import ForceSafeSet

_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


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
        self._normals = [] if plate is None else plate.environment.normals.tolist()
        self._stiffness = dynamics.stiffness.tolist()
        self._damping = dynamics.damping.tolist()
        self.reset()

    def reset(self) -> None:
        """Vented valves since t = −inf: p = u = 0 hPa, no commands."""
        # Record k: the command u_k acting from time t_k and the pressure p_k at t_k (exact).
        self._times: list[float] = [-math.inf]
        self._commands: list[np.ndarray] = [np.zeros(self.n)]
        self._pressures: list[np.ndarray] = [np.zeros(self.n)]

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
        q, qd = [float(v) for v in q], [float(v) for v in qd]
        p, pieces = self._pieces(t_start, t_end)
        p = p.tolist()
        return (self._predict_2 if self.n == 2 else self._predict_n)(q, qd, p, pieces)

    def _predict_n(self, q: list[float], qd: list[float], p: list[float],
                   pieces: list[tuple[float, float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`predict`'s loop for any N: p held at its mean over each step, one `_ros2` step."""
        for a, b, u in pieces:
            steps = max(1, math.ceil((b - a) / self.step_s - 1e-9))
            h = (b - a) / steps
            decay = math.exp(-h / self.tau) if self.tau > 0 else 0.0
            mean = self.tau / h * -math.expm1(-h / self.tau) if self.tau > 0 else 0.0
            u = u.tolist()
            for _ in range(steps):
                acting = [v + (pi - v) * mean for v, pi in zip(u, p)]
                p = [v + (pi - v) * decay for v, pi in zip(u, p)]
                q, qd = self._ros2(q, qd, acting, h)
        return np.array(q), np.array(qd), np.array(p)

    def _predict_2(self, q: list[float], qd: list[float], p: list[float],
                   pieces: list[tuple[float, float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`predict`'s loop for N = 2 on scalars: `_ros2` and `_acceleration_and_mass` written out
        over `PCCDynamics.acceleration_and_mass_2`, the same operations in the same order (so the
        same floats, tested), with the step's constants (γh, γhK, γhD + γ²h²K, ½h) computed
        once per interval instead of once per step."""
        accel, plate = self.dynamics.acceleration_and_mass_2, self.plate
        (k0, k1), (d0, d1) = self._stiffness, self._damping
        (q0, q1), (v0, v1), (p0, p1) = q, qd, p
        for a, b, u in pieces:
            steps = max(1, math.ceil((b - a) / self.step_s - 1e-9))
            h = (b - a) / steps
            decay = math.exp(-h / self.tau) if self.tau > 0 else 0.0
            mean = self.tau / h * -math.expm1(-h / self.tau) if self.tau > 0 else 0.0
            u0, u1 = u.tolist()
            gh = _GAMMA * h
            c0, c1 = gh * k0, gh * k1  # γhK
            e0, e1 = gh * d0 + gh * gh * k0, gh * d1 + gh * gh * k1  # γhD + γ²h²K
            half_h = 0.5 * h
            for _ in range(steps):
                w0, w1 = u0 + (p0 - u0) * mean, u1 + (p1 - u1) * mean  # the acting (mean) pressure
                p0, p1 = u0 + (p0 - u0) * decay, u1 + (p1 - u1) * decay
                # stage 1 at (q, q̇): W = I − γhJ̃ solved through its Schur complement M + γhD + γ²h²K
                a0, a1, m00, m01, m11, i00, i01, i11, tip, jac0, jac1 = accel(q0, q1, v0, v1, w0, w1)
                if plate is not None:
                    a0, a1 = self._plate_acceleration_2(a0, a1, i00, i01, i11, tip, jac0, jac1)
                s00, s01, s11 = m00 + e0, m01 + 0.0, m11 + e1
                det = s00 * s11 - s01 * s01
                t00, t01, t11 = s11 / det, -s01 / det, s00 / det
                r0, r1 = (m00 * a0 + m01 * a1) - c0 * v0, (m01 * a0 + m11 * a1) - c1 * v1
                y0, y1 = t00 * r0 + t01 * r1, t01 * r0 + t11 * r1  # k1 (velocity part)
                x0, x1 = v0 + gh * y0, v1 + gh * y1  # k1 (position part)
                # stage 2 at (q, q̇) + h k1
                z0, z1 = v0 + h * y0, v1 + h * y1
                b0, b1, _, _, _, i00, i01, i11, tip, jac0, jac1 = accel(q0 + h * x0, q1 + h * x1, z0, z1, w0, w1)
                if plate is not None:
                    b0, b1 = self._plate_acceleration_2(b0, b1, i00, i01, i11, tip, jac0, jac1)
                f0, f1, g0, g1 = z0 - 2.0 * x0, z1 - 2.0 * x1, b0 - 2.0 * y0, b1 - 2.0 * y1
                r0, r1 = (m00 * g0 + m01 * g1) - c0 * f0, (m01 * g0 + m11 * g1) - c1 * f1
                n0, n1 = t00 * r0 + t01 * r1, t01 * r0 + t11 * r1  # k2 (velocity part)
                q0, q1 = q0 + half_h * (3.0 * x0 + (f0 + gh * n0)), q1 + half_h * (3.0 * x1 + (f1 + gh * n1))
                v0, v1 = v0 + half_h * (3.0 * y0 + n0), v1 + half_h * (3.0 * y1 + n1)
        return np.array([q0, q1]), np.array([v0, v1]), np.array([p0, p1])

    def _plate_acceleration_2(self, a0: float, a1: float, i00: float, i01: float, i11: float, tip: complex,
                              jac0: complex, jac1: complex) -> tuple[float, float]:
        """`_acceleration_and_mass`'s plate push for N = 2 on scalars (the same floats)."""
        x, y = tip.real, tip.imag
        if not any(self.plate.penetration_at(x, y)):
            return a0, a1
        forces = self.plate.force_at(x, y).tolist()
        if not any(forces):
            return a0, a1
        t0 = t1 = 0.0
        for f, (nx, ny) in zip(forces, self._normals):
            t0 += f * (nx * jac0.real + ny * jac0.imag)
            t1 += f * (nx * jac1.real + ny * jac1.imag)
        t0, t1 = -t0, -t1
        return a0 + (i00 * t0 + i01 * t1), a1 + (i01 * t0 + i11 * t1)

    def _ros2(self, q: list[float], qd: list[float], u: list[float], h: float) -> tuple[list[float], list[float]]:
        """One ROS2 step of length h with the pressure u held (see the module docstring), on Python floats."""
        accel, gh = self._acceleration_and_mass, _GAMMA * h
        acc, mass = accel(q, qd, u)
        ghk = [gh * k for k in self._stiffness]
        schur_inv = spd_inverse([[m + (gh * d + gh * gh * k if j == l else 0.0) for l, m in enumerate(row)]
                              for j, (row, d, k) in enumerate(zip(mass, self._damping, self._stiffness))])

        def solve_w(r_q: list[float], r_v: list[float]) -> tuple[list[float], list[float]]:
            rhs = [sum(m * r for m, r in zip(row, r_v)) - c * rq for row, c, rq in zip(mass, ghk, r_q)]
            k_v = [sum(s * r for s, r in zip(row, rhs)) for row in schur_inv]
            return [rq + gh * kv for rq, kv in zip(r_q, k_v)], k_v

        k1q, k1v = solve_w(qd, acc)
        q2 = [a + h * b for a, b in zip(q, k1q)]
        qd2 = [a + h * b for a, b in zip(qd, k1v)]
        acc2, _ = accel(q2, qd2, u)
        k2q, k2v = solve_w([a - 2.0 * b for a, b in zip(qd2, k1q)], [a - 2.0 * b for a, b in zip(acc2, k1v)])
        return ([a + 0.5 * h * (3.0 * b + c) for a, b, c in zip(q, k1q, k2q)],
                [a + 0.5 * h * (3.0 * b + c) for a, b, c in zip(qd, k1v, k2v)])


    def _acceleration_and_mass(self, q: list[float], qd: list[float], u: list[float]) -> tuple[list[float], list[list[float]]]:
        """q̈ and M at (q, q̇) with pressure u, the plate's push included (see the module docstring)."""
        acc, mass = self.dynamics.acceleration_and_mass_unchecked(q, qd, u)
        if self.plate is None:
            return acc, mass
        ev = self.dynamics.evaluate(q, qd)  # the same state: the dynamics' cached terms
        tip = ev.tip[0]
        forces = self.plate.force_at(tip.real, tip.imag).tolist()
        if not any(forces):
            return acc, mass
        jac = ev.tip_jac.tolist()
        tau = [-sum(f * (nx * j.real + ny * j.imag) for f, (nx, ny) in zip(forces, self._normals)) for j in jac]
        return [a + sum(m * t for m, t in zip(row, tau)) for a, row in zip(acc, spd_inverse(mass))], mass

