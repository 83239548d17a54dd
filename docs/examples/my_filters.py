"""Two user safety filters (docs/extending.md): the simplest one, and one that uses its context.

Run either with the plug-in registry, e.g.
    softcbf run mujoco_contact --filter docs/examples/my_filters.py:ClipFilter --filter-param limit_hPa=100
    softcbf run mujoco_contact --filter docs/examples/my_filters.py:RestShapeScaler --filter-param margin_m=0.002
"""

from __future__ import annotations

import numpy as np

from controllers.model.pcc import tip_position
from controllers.contract.safety_filter import FilterContext, FilterOutput


class ClipFilter:
    """u = clip(u_nom, −limit, +limit) (hPa). A bare array return means "this is u"."""

    def __init__(self, limit_hPa: float = 100.0):
        if not limit_hPa > 0:
            raise ValueError(f"limit_hPa must be > 0 hPa, got {limit_hPa}")
        self.limit = limit_hPa

    def __call__(self, estimate, u_nom):
        return np.clip(u_nom, -self.limit, self.limit)


class RestShapeScaler:
    """u = s·u_nom with the largest s ∈ {1, 1 − 1/steps, …, 0} whose rest shape keeps the tip
    `margin_m` (m) inside the force-safe set P.

    The rest shape of a held command u is q_u = K⁻¹Λu (rad; K, Λ from the robot model);
    its tip r(q_u) must satisfy margin_i(r) = h'_i − H'_i r ≥ margin_m ‖H'_i‖ for every row
    of P. Quasi-static: it ignores the state (no transient guarantee), a teaching example.
    """

    def __init__(self, margin_m: float = 0.001, steps: int = 50, *, context: FilterContext):
        if not margin_m >= 0:
            raise ValueError(f"margin_m must be >= 0 m, got {margin_m}")
        if not steps >= 1:
            raise ValueError(f"steps must be >= 1, got {steps}")
        robot = context.robot
        self.rest_gain = robot.array("gains") / robot.array("stiffness")  # K⁻¹Λ, rad/hPa
        self.lengths = robot.array("lengths")
        self.H = np.asarray(context.safe_set.H_prime, dtype=float)
        self.h = np.asarray(context.safe_set.h_prime, dtype=float)
        self.margin = margin_m * np.hypot(self.H[:, 0], self.H[:, 1])
        self.scales = np.linspace(1.0, 0.0, steps + 1)

    def _inside(self, u: np.ndarray) -> bool:
        tip = tip_position(self.rest_gain * u, self.lengths)
        return bool(np.all(self.h - self.H @ tip >= self.margin))

    def __call__(self, estimate, u_nom) -> FilterOutput:
        u_nom = np.asarray(u_nom, dtype=float)
        for s in self.scales:
            if self._inside(s * u_nom):
                return FilterOutput(s * u_nom, action="scaled" if s < 1 else "nominal",
                                    diagnostics={"scale": float(s)}, diagnostic_units={"scale": "1"})
        return FilterOutput(np.zeros_like(u_nom), action="vent", infeasible=True,
                            diagnostics={"scale": 0.0}, diagnostic_units={"scale": "1"})


RestShapeScaler.parameter_docs = {"margin_m": "rest-shape tip margin inside P [m]",
                                  "steps": "scales tried between 1 and 0 [-]"}
