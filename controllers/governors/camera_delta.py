"""A camera's error at rest, measured from a recorded run: the Δ and the scatter that c-erg's gain estimate trusts.

c-erg's gain estimate with `gain_window_s` (`controllers.governors.gain_estimate`, "averaged frames") takes as a sample the
mean ᾱ of the n camera frames of a window at rest (the fitted slope |β_i| ≤ `rest_rad_s`), and trusts it to
Δ + ε_i: ε_i = t_ν(risk) s_i/√n from the residual scatter s_i pooled over the windows (the frame noise, which
averaging shrinks), Δ the worst-case part that averaging does not remove (the camera's systematic error and the
residual motion). This module measures both from a run folder's camera frames (`timeseries/<tuning>_frames.npz`,
written by camera_loop: per frame t (s, exposure), dropped, complete, q_camera (rad) and, in simulation, q_true
(rad, MuJoCo's at exposure); a file without q_true, as a hardware recording of the same series would be, gives
the scatter alone: the hardware mode does not write this file yet), with the governor's own windows (`RestWindow`: the same fit and
rest test, frames at most one window apart; only the windows at rest are pooled here, so that σ is the noise at
rest, where the governor pools every window whose pressure settled):

- scatter: σ_i = s_i per frame and segment (rad, pooled over ν degrees of freedom), its upper value for c-erg's
  `gain_frame_sigma_rad` (`CameraDelta.sigma_upper`), and the bound ε_i of a mean of the median window's n frames
  at `risk`; measurable on hardware too (no truth needed);
- Δ (simulation only, the frames' q_true): the largest |ᾱ_i − mean_f q_true,f,i| over the windows at rest and the
  segments, the error of a window's mean against the truth. It contains the averaged noise η̄ as well as the
  systematic error, so it over-states the systematic part (by about t·σ/√n at the windows' count), which is the
  safe side for `gain_noise_rad`; it is a sample maximum over the recorded windows, not a proven bound: poses
  not visited in the run (another contact position, a far sinusoid peak) may err more (module docstring of
  `controllers.governors.gain_estimate`: 1–2.3e-3 rad at some peaks on the noise-free camera). On hardware the systematic
  error is invisible to the scatter: Δ there needs a reference (a measured pose), and the command says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controllers.governors.gain_estimate import RestWindow

FRAMES_SUFFIX = "_frames.npz"
"""A run folder's camera frames: timeseries/<tuning>_frames.npz (module docstring)."""


@dataclass(frozen=True)
class CameraDelta:
    """One tuning's camera error at rest (module docstring): windows at rest, their median frame count, the pooled
    scatter σ (N,) rad over `dof` degrees of freedom, ε (N,) rad for a mean of `frames` frames at `risk`, and Δ
    (N,) rad, the largest error of a window's mean against the truth per segment (None without truth)."""

    tuning: str
    windows: int
    frames: int
    dof: int
    sigma: np.ndarray
    scatter: np.ndarray
    delta: np.ndarray | None
    risk: float
    window_s: float

    @property
    def sigma_upper(self) -> np.ndarray:
        """σ rounded up for its own estimate's error (N,) rad: s (1 + z_0.999/√(2ν)), s's standard error ≈ σ/√(2ν)
        (the normal approximation of a χ² with ν degrees of freedom; one-sided 0.999)."""
        return self.sigma * (1.0 + 3.09 / np.sqrt(2.0 * self.dof))


def measure(times, q_camera, q_true, usable, window_s: float, rest_rad_s: float, risk: float,
            tuning: str = "") -> CameraDelta:
    """The camera's error at rest from its frames (module docstring): times (F,) s, q_camera (F, N) rad, q_true
    (F, N) rad or None, usable (F,) bool (the frame arrived and was complete). Windows of `window_s` over the usable
    frames, at rest when every fitted |β_i| ≤ rest_rad_s, as c-erg's gain estimate takes them."""
    times, q_camera, usable = np.asarray(times, float), np.asarray(q_camera, float), np.asarray(usable, bool)
    if q_camera.ndim != 2 or times.shape != (q_camera.shape[0],) or usable.shape != times.shape:
        raise ValueError(f"times (F,), q_camera (F, N) and usable (F,) must agree, got {times.shape}, "
                         f"{q_camera.shape}, {usable.shape}")
    if not (window_s > 0.0 and rest_rad_s >= 0.0 and 0.0 < risk < 1.0):
        raise ValueError(f"need window_s > 0, rest_rad_s >= 0 and 0 < risk < 1, got {window_s!r}, {rest_rad_s!r}, "
                         f"{risk!r}")
    truth = None if q_true is None else np.asarray(q_true, float)
    window, errors, counts = RestWindow(q_camera.shape[1]), [], []
    for f in np.flatnonzero(usable & np.all(np.isfinite(q_camera), axis=1)):
        if window.times and times[f] - window.times[-1] > window_s:  # a gap of a window: the arm may have moved
            window.clear()
        window.add(times[f], q_camera[f], None if truth is None else truth[f])
        if window.span() < window_s or len(window.times) < 3:
            continue
        mean, slope, rss, n = window.fit()
        if np.any(np.abs(slope) > rest_rad_s):
            window.drop_oldest()
            continue
        window.pool(rss, n)
        counts.append(n)
        if truth is not None:
            errors.append(np.abs(mean - np.mean(window.inputs, axis=0)))
        window.clear()
    if not counts:
        raise ValueError(f"no window of {window_s:g} s at rest (every |slope| <= {rest_rad_s:g} rad/s) among "
                         f"{int(usable.sum())} usable frames{' of ' + tuning if tuning else ''}: record a run "
                         f"that rests, or widen --rest-rad-s")
    frames = int(np.median(counts))
    sigma = np.sqrt(window.pooled_rss / window.pooled_dof)
    delta = None if truth is None or not np.all(np.isfinite(errors)) else np.max(errors, axis=0)
    return CameraDelta(tuning, len(counts), frames, window.pooled_dof, sigma, window.scatter_bound(frames, risk),
                       delta, risk, window_s)


def measure_folder(run_dir: Path, window_s: float, rest_rad_s: float, risk: float) -> list[CameraDelta]:
    """`measure` for each tuning's camera frames in a run folder (module docstring); ValueError when it has none."""
    paths = sorted(Path(run_dir, "timeseries").glob(f"*{FRAMES_SUFFIX}"))
    if not paths:
        raise ValueError(f"{run_dir} has no camera frames (timeseries/*{FRAMES_SUFFIX}): a camera_loop "
                         f"run folder is needed (the hardware mode writes no frames file yet)")
    out = []
    for path in paths:
        with np.load(path) as data:
            usable = ~data["dropped"].astype(bool) & data["complete"].astype(bool)
            truth = data["q_true"] if "q_true" in data.files else None
            out.append(measure(data["t"], data["q_camera"], truth, usable, window_s, rest_rad_s, risk,
                               path.name[:-len(FRAMES_SUFFIX)]))
    return out


def report_lines(result: CameraDelta) -> list[str]:
    """The printed lines of one tuning's measurement: Δ and ε with how each was measured."""
    def rad(v: np.ndarray) -> str:
        return ", ".join(f"{x:.3g}" for x in v) + " rad"
    lines = [f"{result.tuning}: {result.windows} windows of {result.window_s:g} s at rest, median {result.frames} "
             f"frames each",
             f"  frame scatter σ per segment: {rad(result.sigma)} (residuals about each window's line, pooled over "
             f"{result.dof} degrees of freedom); upper value {rad(result.sigma_upper)} (σ (1 + 3.09/√(2ν)): "
             f"one-sided 0.999, normal approximation of s) for gain_frame_sigma_rad = "
             f"{float(np.max(result.sigma_upper)):.2g}",
             f"  noise bound of a {result.frames}-frame mean ε: {rad(result.scatter)} (Student's t, risk "
             f"{result.risk:g} per segment and sample: statistical, not worst case)"]
    if result.delta is None:
        lines.append("  Δ: not measurable here (no truth in the frames: the camera's systematic error is invisible to "
                     "its scatter; measure it against a reference pose)")
    else:
        lines.append(f"  Δ (gain_noise_rad) ≥ {float(np.max(result.delta)):.3g} rad: the largest error of a window's "
                     f"mean against the simulation's truth (per segment {rad(result.delta)}; a sample maximum over "
                     f"these windows, noise included)")
    return lines
