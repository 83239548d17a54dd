"""The simplest user safety filter (docs/safety-filter.md): clip the nominal command to ±limit_hPa.

Not safe by any measure — it knows nothing of the plate — it shows the plug-in contract
(controllers.safety_filter): a class whose constructor takes its parameters and whose
call `(estimate, u_nom) -> (N,) array of hPa` returns the command. Run it with

    softcbf run mujoco_contact --filter examples/clip_filter.py:ClipFilter --filter-param limit_hPa=100 --duration 5
    softcbf run camera_loop --filter examples/clip_filter.py:ClipFilter --filter-param limit_hPa=100 --duration 5
    softcbf study run examples/clip_filter_study.toml --out runs/clip_study
    softcbf hardware examples/hardware_emulated.toml --filter examples/clip_filter.py:ClipFilter --filter-param limit_hPa=100

The loop clips whatever a filter returns to the pressure limits, refuses non-finite
commands (hold, then vent) and records both the filter's return (u_filter) and what was
sent (u).
"""

import numpy as np


class ClipFilter:
    def __init__(self, limit_hPa: float = 100.0):
        self.limit = limit_hPa

    def __call__(self, estimate, u_nom):
        return np.clip(u_nom, -self.limit, self.limit)
