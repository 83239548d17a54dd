"""The one table of the time series' columns and their units, shared by the recorder
(`closedloop.record`) and the control step (`closedloop.step`: a filter's diagnostics may not
take these names)."""

TIMESERIES_UNITS = {
    "t": "s (the loop's control time: simulated, or since the hardware run started)",
    "q": "rad (true)",
    "qd": "rad/s (true)",
    "q_est": "rad",
    "qd_est": "rad/s",
    "tip": "m (true)",
    "segment_ends": "m (true)",
    "u_nom": "hPa",
    "u_filter": "hPa (the filter's return, before clipping)",
    "u": "hPa (the command sent: clipped, or the safety monitor's hold / vent)",
    "u_applied": "hPa (at the plant's valves)",
    "contact_force": "N (measured)",
    "rho_pred": "1 (the filter's predicted margin; NaN: no prediction)",
    "rho_meas": "1 (from the measured contact force)",
    "infeasible": "bool (the filter said so, on its call's row)",
    "action": "0 run, 1 hold, 2 vent (the safety monitor)",
    "filter_us": "us (the filter call's wall time; NaN on rows without a call)",
    "t_clock": "s (monotonic clock)",
    "est_age_s": "s (t - t_capture of the estimate)",
    "est_stale": "bool",
    "u_sent": "hPa (what the link sent)",
    "u_measured": "hPa (the board's measured pressure)",
    "link_acked": "bool",
    "link_latency_s": "s",
    "link_lost": "bool",
    "late_s": "s (cycle start after its scheduled time)",
}
