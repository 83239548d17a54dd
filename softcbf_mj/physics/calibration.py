"""Calibration of the PCC model's stiffness K, damping D and pressure gain Λ from motion data.

Model (docs/model.md#rppr-dynamics), one equation per segment i, N·m:

    τ_i := [M(q) q̈ + C(q, q̇) q̇]_i = λ_i u_i − k_i q_i − d_i q̇_i

M and C come from the controller's own `PCCDynamics` (masses, lengths and inertias are
known: the paper's), so each segment is an independent linear least-squares problem
in θ_i = (k_i, d_i, λ_i):  τ_i = [−q_i, −q̇_i, u_i] θ_i.

Scale ambiguity. Without M, free motion only fixes θ_i up to a common factor (statics
give λ_i/k_i, the decay gives d_i/k_i). Taking M as known fixes the factor: the fitted
θ are those that make the PCC model with ITS M reproduce q̈. A model whose M is wrong
therefore gets θ scaled to compensate, which is what the controller's predictions need
but not the values a different body was built with. The MuJoCo rod is such a body: a
uniform rod bent at constant curvature has M_22 = m L²/20, the augmented-body model
m L²/16 + I/4 = m L²/12 (1.67×), so segment 2's fitted θ come out 33–39 % above the
rod's k, d, λ while λ/k stays exact (models/softcbf_arm/README.md, "Calibration").
`rod_inertial_torque` gives the rod's own M q̈ + C q̇ instead (for checking the method).

Signals (SI; pressure in hPa). Inputs are uniformly sampled arrays t (T,) s, q (T, N)
rad, u (T, N) hPa, optionally q̇ (T, N) rad/s:
- derivatives by central differences of the samples, q̇_k = (q_{k+1} − q_{k−1})/(2Δt) and
  q̈_k = (q̇_{k+1} − q̇_{k−1})/(2Δt) when q̇ is recorded (MuJoCo), else (e.g. camera data)
  q̈_k = (q_{k+1} − 2q_k + q_{k−1})/Δt². These are exact averages of the continuous q̇, q̈
  over [t_{k−1}, t_{k+1}] with one kernel (a box, resp. a hat), and the same kernel
  turns a zero-order-held u into (u_{k−1} + u_k)/2 exactly; q and a continuous pressure
  are their own averages to O(Δt²). So the equation holds for the differenced signals
  even across pressure steps, where q̈ jumps and the PCC model's fast mode (≈ −3.7e3 s⁻¹)
  makes q̇ change within a fraction of a period: using the sampled q̇_k there instead of
  the box average biased segment 2 by 4 %. For smooth signals the relative error at
  angular frequency ω is ω²Δt²/6 (resp. /12): 1.6e-4 at 5 Hz and 1 kHz, 2 % at 1 Hz
  and 12.8 Hz (camera).
- smoothing: q, q̇, q̈ and u then all pass through the same Savitzky–Golay smoother
  (the least-squares polynomial of degree `polyorder` over a centred window of
  `window_s` seconds, evaluated at its centre). Linear filters commute with the
  differences, so one zero-phase filter applied to every signal keeps the linear
  equation exact while removing the rod's high-mode wiggles and measurement noise above
  ≈ 1/window_s (M(q) q̈ and C q̇ are nonlinear, but q is smooth on the window's scale).
  (Savitzky–Golay derivative filters would not do: their responses are not iω times
  the smoother's, which biased a q-only fit by 1–2 %.) The first and last (window + 1)/2
  samples are dropped (no edge extrapolation).
- `u_kind="pressure"`: u[k] is the pressure acting at t[k] (a pressure sensor; the
  MuJoCo plant's `u_applied`). `u_kind="command"`: u[k] is the command held over
  [t[k], t[k+1]) (zero-order hold); the pressure acting is reconstructed with the
  first-order model ṗ = (u − p)/τ_p, exact for piecewise-constant u:
  p[k+1] = p[k] + (u[k] − p[k])(1 − e^{−Δt/τ_p}), p[0] = `p0`. With τ_p = 0 (ideal
  actuator) the value at t[k] is the mean (u[k−1] + u[k])/2 of the two periods around
  it (u[−1] = p0), the average the differences above see.

Fit quality per segment: R² of τ_i (1 − SS_res/SS_tot, SS_tot about the mean), the
residual RMS (N·m), the condition number of the column-scaled regressor, and the
relative error of each fitted value against the nominal `RobotParams`.

Excitation (`babbling_commands`) and recording (`record`) produce such data from any
`Plant`; the MuJoCo recording uses a model without plates, so there is no contact.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal

import mujoco
import numpy as np

from controllers.model.dynamics import PCCDynamics
from controllers.model.params import RobotParams
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.physics.plant import Plant

FITTED = ("stiffness", "damping", "gains")  # RobotParams fields the fit replaces, θ order
UKind = Literal["pressure", "command"]
InertialTorque = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
_UNIFORM_TOL = 1e-3  # max relative deviation of a sampling interval from the mean
_MIN_SAMPLES = 30  # ten per fitted parameter


# -- excitation and recording -----------------------------------------------------------


def babbling_commands(
    duration: float,
    dt: float,
    u_min,
    u_max,
    seed: int = 0,
    hold_s: tuple[float, float] = (0.1, 0.6),
    chirp_hz: tuple[float, float] = (0.2, 5.0),
    step_share: float = 0.6,
    chirp_share: float = 0.3,
) -> np.ndarray:
    """Motor babbling: (T, N) pressure commands (hPa) at period dt (s), T = duration/dt.

    Per segment, independently: random steps (levels uniform within ±step_share of the
    half-range, held for times uniform in hold_s) plus a linear chirp from chirp_hz[0]
    to chirp_hz[1] over the run (amplitude chirp_share of the half-range, random phase),
    centred on the middle of [u_min, u_max]. step_share + chirp_share ≤ 1 keeps every
    command within the limits. Seeded: the same arguments give the same commands.
    """
    u_min, u_max = np.atleast_1d(np.asarray(u_min, float)), np.atleast_1d(np.asarray(u_max, float))
    if u_min.shape != u_max.shape or not np.all(u_min < u_max):
        raise ValueError(f"need u_min < u_max per segment, got {u_min.tolist()} and {u_max.tolist()}")
    if not (step_share >= 0 and chirp_share >= 0 and step_share + chirp_share <= 1):
        raise ValueError(f"need step_share, chirp_share >= 0 with sum <= 1, got {step_share}, {chirp_share}")
    if not (0 < hold_s[0] <= hold_s[1]) or not (0 < chirp_hz[0] <= chirp_hz[1]):
        raise ValueError(f"hold_s and chirp_hz must be increasing positive pairs, got {hold_s}, {chirp_hz}")
    steps = int(round(duration / dt))
    if steps < 2:
        raise ValueError(f"duration must cover at least two periods of {dt} s, got {duration}")
    rng = np.random.default_rng(seed)
    centre, half = (u_max + u_min) / 2, (u_max - u_min) / 2
    t = np.arange(steps) * dt
    phase = 2 * np.pi * (chirp_hz[0] * t + (chirp_hz[1] - chirp_hz[0]) * t * t / (2 * duration))
    out = np.empty((steps, len(centre)))
    for i in range(len(centre)):
        levels = np.empty(steps)
        k = 0
        while k < steps:
            hold = max(1, int(round(rng.uniform(*hold_s) / dt)))
            levels[k : k + hold] = rng.uniform(-step_share, step_share)
            k += hold
        chirp = chirp_share * np.sin(phase + rng.uniform(0, 2 * np.pi))
        out[:, i] = centre[i] + half[i] * (levels + chirp)
    return out


@dataclass(frozen=True)
class Recording:
    """Samples at the control rate: t (T,) s; q, qd (T, N) rad, rad/s; u (T, N) hPa, the
    pressure acting at t (the plant's `u_applied`); command (T, N) hPa, held over [t, t + Δt)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    u: np.ndarray
    command: np.ndarray

    def save(self, path: str | Path) -> None:
        """Write an .npz with keys t, q, qd, u, command (the format `load_arrays` reads)."""
        np.savez_compressed(path, **dataclasses.asdict(self))


def record(plant: Plant, commands: np.ndarray, q0: np.ndarray | None = None) -> Recording:
    """Apply `commands` (T, N) hPa, one per control period, from rest at q0 (default straight)."""
    commands = np.asarray(commands, dtype=float)
    n = plant.n_segments
    if commands.ndim != 2 or commands.shape[1] != n:
        raise ValueError(f"commands must have shape (T, {n}), got {commands.shape}")
    steps = len(commands)
    t, q, qd, u = np.empty(steps), np.empty((steps, n)), np.empty((steps, n)), np.empty((steps, n))
    state = plant.reset(np.zeros(n) if q0 is None else np.asarray(q0, dtype=float))
    for k, command in enumerate(commands):
        t[k], q[k], qd[k], u[k] = state.t, state.q, state.qd, state.u_applied
        state = plant.step(command)
    return Recording(t, q, qd, u, commands.copy())


def free_mujoco_plant(**fields: Any) -> MujocoPlant:
    """A MuJoCo plant of `ArmModelConfig` fields without plates (no contact possible)."""
    return MujocoPlant.from_config(H=np.zeros((0, 2)), h=(), **fields)


def load_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """Arrays t, q, u (and qd if present) from an .npz (e.g. `Recording.save`, camera logs)."""
    with np.load(path) as data:
        missing = {"t", "q", "u"} - set(data.files)
        if missing:
            raise ValueError(f"{path}: missing array(s) {sorted(missing)}; need t (T,), q (T, N), u (T, N), optional qd")
        return {k: data[k] for k in ("t", "q", "u", "qd") if k in data.files}


# -- signal processing ----------------------------------------------------------------


def savgol_weights(window: int, polyorder: int) -> np.ndarray:
    """Savitzky–Golay smoothing weights w (window,): Σ_j w_j y[k + j − h], h = (window − 1)/2,
    is the value at k of the least-squares polynomial of degree `polyorder` through y[k−h..k+h]."""
    if window % 2 != 1 or window < polyorder + 2:
        raise ValueError(f"window must be odd and >= polyorder + 2 = {polyorder + 2} samples, got {window}")
    x = np.arange(window) - (window - 1) / 2
    return np.linalg.pinv(x[:, None] ** np.arange(polyorder + 1))[0]


def _filter(y: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Apply filter weights along axis 0, 'valid' part only: (T, N) → (T − window + 1, N)."""
    return np.column_stack([np.correlate(col, weights, mode="valid") for col in y.T])


def acting_pressure(u: np.ndarray, dt: float, tau_p: float, p0) -> np.ndarray:
    """Pressure (T, N) hPa acting at each sample for zero-order-held commands u (T, N); see the module docstring."""
    if tau_p == 0:
        before = np.vstack((np.asarray(p0, float) * np.ones((1, u.shape[1])), u[:-1]))
        return 0.5 * (before + u)
    decay = 1.0 - math.exp(-dt / tau_p)
    p = np.empty_like(u)
    p[0] = p0
    for k in range(len(u) - 1):
        p[k + 1] = p[k] + (u[k] - p[k]) * decay
    return p


def pcc_inertial_torque(robot: RobotParams) -> InertialTorque:
    """M(q) q̈ + C(q, q̇) q̇ (N·m) of the controller's model, row by row: (T, N) arrays in, (T, N) out."""
    dyn = PCCDynamics(robot)

    def torque(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        out = np.empty_like(q)
        for k in range(len(q)):
            ev = dyn.evaluate(q[k], qd[k])
            # bias = C q̇ + D q̇ + K q; removing the model's own D q̇ + K q leaves C q̇.
            out[k] = ev.mass @ qdd[k] + ev.bias - dyn.damping * qd[k] - dyn.stiffness * q[k]
        return out

    return torque


def rod_inertial_torque(plant: MujocoPlant) -> InertialTorque:
    """M q̈ + C q̇ (N·m) of the MuJoCo rod bent at constant curvature (every hinge of segment i
    at q_i/n_i), projected on q: τ_i = (1/n_i) Σ_{j ∈ i} [M_θ θ̈ + c_θ(θ, θ̇)]_j. With this in
    place of the PCC model's, the fit recovers the k, d, λ the rod was built with, up to
    the rod's departure from constant curvature (for checking the method, not for use).
    """
    model = plant.model
    data = mujoco.MjData(model)
    hinges = list(zip(plant.hinge_qpos, plant.hinge_dofs))
    result = np.empty(model.nv)

    def torque(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        out = np.empty_like(q)
        for k in range(len(q)):
            data.qpos[:], data.qvel[:], data.qacc[:] = 0.0, 0.0, 0.0
            for i, (qadr, dadr) in enumerate(hinges):
                n = len(qadr)
                data.qpos[qadr], data.qvel[dadr], data.qacc[dadr] = q[k, i] / n, qd[k, i] / n, qdd[k, i] / n
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            mujoco.mj_comVel(model, data)
            mujoco.mj_rne(model, data, 1, result)
            out[k] = [result[dadr].sum() / len(dadr) for _, dadr in hinges]
        return out

    return torque


# -- the fit ----------------------------------------------------------------------------


@dataclass(frozen=True)
class SegmentFit:
    """One segment's least-squares fit of τ_i = [−q_i, −q̇_i, u_i] (k_i, d_i, λ_i)."""

    stiffness: float  # N·m/rad
    damping: float  # N·m·s/rad
    gain: float  # N·m/hPa
    r2: float  # of τ_i
    residual_rms: float  # N·m
    target_rms: float  # N·m, RMS of τ_i
    condition: float  # of the column-scaled regressor


@dataclass(frozen=True)
class CalibrationResult:
    """Fitted parameters (`params`: `nominal` with K, D, Λ replaced) and fit quality."""

    params: RobotParams
    nominal: RobotParams
    segments: tuple[SegmentFit, ...]
    samples: int
    window: int
    polyorder: int
    dt: float

    def relative_errors(self) -> dict[str, list[float]]:
        """(fitted − nominal)/nominal per field of FITTED and for λ/k, per segment."""
        def rel(fitted: np.ndarray, nominal: np.ndarray) -> list[float]:
            return ((fitted - nominal) / nominal).tolist()

        out = {f: rel(self.params.array(f), self.nominal.array(f)) for f in FITTED}
        ratio = [p.array("gains") / p.array("stiffness") for p in (self.params, self.nominal)]
        out["gain_over_stiffness"] = rel(*ratio)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "robot": self.params.to_dict(),
            "nominal": self.nominal.to_dict(),
            "relative_error": self.relative_errors(),
            "segments": [dataclasses.asdict(s) for s in self.segments],
            "samples": self.samples,
            "window_samples": self.window,
            "window_s": self.window * self.dt,
            "polyorder": self.polyorder,
            "dt_s": self.dt,
        }

    def table(self) -> str:
        """Plain-text table: fitted vs nominal values, relative errors and fit quality."""
        err = self.relative_errors()
        lines = ["seg   k [N·m/rad] (err)     d [N·m·s/rad] (err)   λ [N·m/hPa] (err)       λ/k err     R²        resid RMS [N·m]  cond"]
        for i, s in enumerate(self.segments):
            lines.append(
                f"{i + 1:3d}  {s.stiffness:9.5f} ({100 * err['stiffness'][i]:+6.2f}%)  "
                f"{s.damping:9.5f} ({100 * err['damping'][i]:+6.2f}%)  "
                f"{s.gain:10.4e} ({100 * err['gains'][i]:+6.2f}%)  "
                f"{100 * err['gain_over_stiffness'][i]:+7.3f}%  {s.r2:.6f}  {s.residual_rms:12.3e}  {s.condition:6.1f}"
            )
        return "\n".join(lines)


def _odd_window(samples: float, polyorder: int) -> int:
    """The odd window length nearest `samples`, at least polyorder + 2."""
    window = 2 * int(round((samples - 1) / 2)) + 1
    smallest = polyorder + 2 + (polyorder + 3) % 2  # odd
    return max(window, smallest)


def _uniform_dt(t: np.ndarray) -> float:
    steps = np.diff(t)
    if len(steps) < 1 or not np.all(steps > 0):
        raise ValueError("t must be strictly increasing with at least two samples")
    dt = float(np.mean(steps))
    worst = float(np.max(np.abs(steps - dt)) / dt)
    if worst > _UNIFORM_TOL:
        raise ValueError(f"t must be uniformly sampled (intervals within {_UNIFORM_TOL:.0e} of the mean), "
                         f"got a deviation of {worst:.2g}; resample first")
    return dt


def fit_pcc_parameters(
    t,
    q,
    u,
    nominal: RobotParams,
    qd=None,
    *,
    u_kind: UKind = "pressure",
    tau_p: float = 0.0,
    p0: float | np.ndarray = 0.0,
    window_s: float = 0.021,
    polyorder: int = 3,
    skip_s: float = 0.0,
    inertial_torque: InertialTorque | None = None,
) -> CalibrationResult:
    """Fit K, D, Λ per segment from recorded arrays (see the module docstring for the maths).

    t (T,) s, uniformly sampled; q (T, N) rad; u (T, N) hPa (`u_kind`, `tau_p` and `p0`
    say what it is); qd (T, N) rad/s or None (then differentiated from q). `nominal`
    gives M's masses, lengths and inertias, the limits and the reference values for the
    errors. window_s: Savitzky–Golay window (s), rounded to an odd number of samples ≥
    polyorder + 2. skip_s: seconds dropped at the start (e.g. start-up transients).
    inertial_torque: (q, q̇, q̈) → M q̈ + C q̇; default the controller's PCC model.
    Returns the fitted parameters (`nominal` with stiffness, damping and gains replaced).
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    arrays = checked_recording(t, nominal.n_segments, q=q, u=u, qd=qd)
    dt = _uniform_dt(t)
    if u_kind == "command":
        if not (math.isfinite(tau_p) and tau_p >= 0):
            raise ValueError(f"tau_p must be >= 0 s, got {tau_p}")
        arrays["u"] = acting_pressure(arrays["u"], dt, tau_p, p0)
    elif u_kind != "pressure":
        raise ValueError(f"u_kind must be 'pressure' or 'command', got {u_kind!r}")
    signals = filtered_signals(arrays, dt, window_s, polyorder, skip_s)
    tau = (inertial_torque or pcc_inertial_torque(nominal))(signals.q, signals.qd, signals.qdd)
    segments = [fit_segment(i, tau[:, i], signals.q[:, i], signals.qd[:, i], signals.u[:, i])
                for i in range(nominal.n_segments)]
    fitted = {f: tuple(getattr(s, a) for s in segments) for f, a in zip(FITTED, ("stiffness", "damping", "gain"))}
    try:
        params = nominal.replace(**fitted)
    except ValueError as exc:
        raise ValueError(f"the fit gave unphysical parameters ({exc}); the data do not excite the arm enough") from None
    return CalibrationResult(params, nominal, tuple(segments), len(signals.q), signals.window, polyorder, dt)


def checked_recording(t: np.ndarray, n: int, **recorded) -> dict[str, np.ndarray]:
    """The recorded arrays that are not None (q, u, qd: (T, N)) as float arrays, each checked to be of shape
    (len(t), n) and finite."""
    arrays = {}
    for name, value in recorded.items():
        if value is None:
            continue
        arr = np.asarray(value, dtype=float)
        if arr.shape != (len(t), n):
            raise ValueError(f"{name} must have shape ({len(t)}, {n}), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
        arrays[name] = arr
    return arrays


@dataclass(frozen=True)
class FilteredSignals:
    """q (rad), q̇ (rad/s), q̈ (rad/s²) and u (hPa) after the one smoothing filter, (S, N) each, from the first
    sample at or after skip_s; `window`: the filter's length in samples."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    u: np.ndarray
    window: int


def filtered_signals(arrays: dict[str, np.ndarray], dt: float, window_s: float, polyorder: int,
                     skip_s: float) -> FilteredSignals:
    """Central differences on the raw samples (q̇ from q always; q̈ from qd when recorded, else from q),
    aligned with samples 1..T−2, then one Savitzky–Golay filter for all (module docstring); refused when
    fewer than the fit's minimum samples remain."""
    window = _odd_window(window_s / dt, polyorder)
    smooth = savgol_weights(window, polyorder)
    q_raw = arrays["q"]
    qd_raw = (q_raw[2:] - q_raw[:-2]) / (2 * dt)
    if "qd" in arrays:
        qdd_raw = (arrays["qd"][2:] - arrays["qd"][:-2]) / (2 * dt)
    else:
        qdd_raw = (q_raw[2:] - 2 * q_raw[1:-1] + q_raw[:-2]) / dt**2
    qf, qdf, qddf, uf = (_filter(y, smooth) for y in (q_raw[1:-1], qd_raw, qdd_raw, arrays["u"][1:-1]))
    # Filtered sample j belongs to t[j + 1 + h], h = (window − 1)/2: drop those before t[0] + skip_s.
    first = max(0, int(math.ceil(skip_s / dt - 1e-9)) - 1 - (window - 1) // 2)
    if len(qf) - first < _MIN_SAMPLES:
        raise ValueError(f"too few samples left to fit ({len(qf[first:])}) after dropping {window + 1} edge samples "
                         "and skip_s")
    return FilteredSignals(qf[first:], qdf[first:], qddf[first:], uf[first:], window)


def fit_segment(i: int, tau: np.ndarray, q: np.ndarray, qd: np.ndarray, u: np.ndarray) -> SegmentFit:
    """Segment i's least-squares fit of τ_i = [−q_i, −q̇_i, u_i] (k_i, d_i, λ_i) on column-scaled regressors;
    each argument (S,)."""
    regressor = np.column_stack((-q, -qd, u))
    scale = np.sqrt(np.mean(regressor**2, axis=0))
    if not np.all(scale > 0):
        raise ValueError(f"segment {i + 1}: a regressor column is identically zero; the data do not excite it")
    scaled = regressor / scale
    theta, *_ = np.linalg.lstsq(scaled, tau, rcond=None)
    residual = tau - scaled @ theta
    sv = np.linalg.svd(scaled, compute_uv=False)
    k, d, lam = theta / scale
    return SegmentFit(
        stiffness=float(k), damping=float(d), gain=float(lam),
        r2=float(1.0 - np.sum(residual**2) / np.sum((tau - tau.mean()) ** 2)),
        residual_rms=float(np.sqrt(np.mean(residual**2))),
        target_rms=float(np.sqrt(np.mean(tau**2))),
        condition=float(sv[0] / sv[-1]),
    )
