"""The simplest user safety filter (docs/safety-filter.md): clip the nominal command to ±limit_hPa.

Not safe by any measure — it knows nothing of the plate — it shows the plug-in contract
(controllers.contract.safety_filter): a class whose constructor takes its parameters and whose
call `(estimate, u_nom) -> (N,) array of hPa` returns the command. Run it, from the
repository root, with a nominal that pushes into the plate (150 hPa from t = 0:
u_nom = 150 sin(2π 0.25 (t + 1)) hPa) so that the filter has something to do:

    .venv/bin/softcbf run mujoco_contact --filter examples/clip_filter.py:ClipFilter --filter-param limit_hPa=100 \
        --amplitude 150 --frequency 0.25 --t0 1 --duration 5
    .venv/bin/softcbf run camera_loop --filter examples/clip_filter.py:ClipFilter --filter-param limit_hPa=100 \
        --amplitude 150 --frequency 0.25 --t0 1 --duration 5
    .venv/bin/softcbf study run examples/clip_filter_study.toml --out runs/clip_study
    .venv/bin/softcbf hardware examples/hardware_emulated.toml --filter examples/clip_filter.py:ClipFilter \
        --filter-param limit_hPa=100

On mujoco_contact (5 s) it lowers the peak plate force from 0.637 N (`--filter none`) to
0.401 N, and still violates F_max = 0.16 N (ρ_meas −1.51; none −2.98): capping the pressure
is not force safety.

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
