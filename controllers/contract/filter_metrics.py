"""Per-run figures of a safety filter (docs/beyond-the-paper.md#filters-beyond-the-paper) from its recorded commands and call times.

Inputs: t (T,) s, increasing; u, u_nom (T, N) hPa (what the filter returned and the
nominal command it was given, per record row); filter_us (T,) µs per filter call, NaN
on rows without a call (loops that record every tick and call the filter less often).
The figures use the call rows (finite filter_us; every row if there is none), each
standing for the time until the next call (the last one for the median interval): a
zero-order-hold loop's u and u_nom change only there.

- u_dev_rms_hPa, u_dev_max_hPa: RMS and max of |u_i − u_nom,i| over the calls and segments.
- blocked_s: total time the filter held u more than `BLOCK_THRESHOLD_HPA` (2 hPa) beyond
  a retreating u_nom. u_nom,i retreats at call k when it moves towards 0 hPa (the
  arm's rest shape) since the previous call: s_k = sign(u_nom,i[k] − u_nom,i[k−1]) ≠ 0
  and sign(u_nom,i[k−1]) = −s_k; u is beyond it when s_k (u_i − u_nom,i) < −2 hPa, i.e.
  u stays on the side u_nom is leaving. A call counts once if any segment is blocked.
  blocked_longest_s: the longest run of consecutive blocked calls (s).
  (A filter holding back an *advancing* u_nom — its job near the plate — is not blocked.)
- switches_per_s: sign changes of u_i − u_nom,i (zeros within `SWITCH_DEADBAND_HPA` of
  0 skipped: + → 0 → − counts once), summed over segments, per second of the calls'
  span (t_last − t_first + the last interval).
- filter_us_median, filter_us_p99: over the finite entries of filter_us (NaN if none).
"""

from __future__ import annotations

import math

import numpy as np

BLOCK_THRESHOLD_HPA = 2.0
SWITCH_DEADBAND_HPA = 1e-6


def governor_figures(t, u, u_nom, filter_us) -> dict[str, float]:
    """The figures above as a dict of floats (keys: u_dev_rms_hPa, u_dev_max_hPa, blocked_s,
    blocked_longest_s, switches_per_s, filter_us_median, filter_us_p99)."""
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    u_nom = np.asarray(u_nom, dtype=float)
    filter_us = np.asarray(filter_us, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"t must have shape (T,) with T >= 2, got {t.shape}")
    if not np.all(np.diff(t) > 0):
        raise ValueError("t must be strictly increasing")
    if u.ndim != 2 or u.shape != u_nom.shape or u.shape[0] != t.size:
        raise ValueError(f"u and u_nom must both have shape ({t.size}, N), got {u.shape} and {u_nom.shape}")
    if filter_us.shape != t.shape:
        raise ValueError(f"filter_us must have shape {t.shape}, got {filter_us.shape}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(u_nom))):
        raise ValueError("u and u_nom must be finite")
    rows = np.isfinite(filter_us)
    if np.count_nonzero(rows) >= 2:
        t, u, u_nom = t[rows], u[rows], u_nom[rows]
    dev = u - u_nom
    dt = np.append(np.diff(t), float(np.median(np.diff(t))))

    step = np.sign(np.diff(u_nom, axis=0))  # (T−1, N): direction of u_nom's motion at rows 1..T−1
    retreat = (step != 0) & (np.sign(u_nom[:-1]) == -step)
    beyond = step * dev[1:] < -BLOCK_THRESHOLD_HPA
    blocked = np.concatenate(([False], np.any(retreat & beyond, axis=1)))
    longest, run = 0.0, 0.0
    for flag, d in zip(blocked.tolist(), dt.tolist()):
        run = run + d if flag else 0.0
        longest = max(longest, run)

    switches = 0
    for column in dev.T:
        signs = np.sign(column[np.abs(column) > SWITCH_DEADBAND_HPA])
        switches += int(np.count_nonzero(signs[1:] != signs[:-1]))

    calls = filter_us[np.isfinite(filter_us)]
    return {
        "u_dev_rms_hPa": float(np.sqrt(np.mean(dev**2))),
        "u_dev_max_hPa": float(np.max(np.abs(dev))),
        "blocked_s": float(np.sum(dt[blocked])),
        "blocked_longest_s": longest,
        "switches_per_s": switches / float(t[-1] - t[0] + dt[-1]),
        "filter_us_median": float(np.median(calls)) if calls.size else math.nan,
        "filter_us_p99": float(np.percentile(calls, 99)) if calls.size else math.nan,
    }
