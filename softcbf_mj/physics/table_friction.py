"""Arm-table friction: the planar arm slides on a table with regularised Coulomb friction (docs/ground-truth.md).

The paper's arm lies on a table: gravity is perpendicular to its plane of motion (x-y),
so the table carries each link's weight m_k g and its friction opposes the link's sliding.
The MuJoCo arm (`softcbf_mj.physics.mjcf`) is a chain of rigid links on hinges about z.

Model. Per moving body k of the arm (every body below `base`; mass m_k kg, centre of mass
x_k, its in-plane velocity v_k = (ẋ_k, ẏ_k) m/s), the table pushes with

    f_k = −μ m_k g v_k / √(‖v_k‖² + v_s²)        (N, in the plane; ‖f_k‖ < μ m_k g)

applied at the centre of mass (`data.xfrc_applied[k, :2]`), with μ = `table_friction`
(dimensionless, ≥ 0), g = `TABLE_GRAVITY` = 9.81 m/s² (the table's support force is the
link's weight: the arm's plane is horizontal and MuJoCo's own gravity stays off) and
v_s = `SLIP_VELOCITY` = 1 mm/s. For ‖v_k‖ ≫ v_s this is Coulomb friction of magnitude
μ m_k g opposing the sliding (relative error ≈ v_s² / (2‖v_k‖²): 0.5 % at 1 cm/s).

The friction power is P = Σ_k f_k · v_k = −μ g Σ_k m_k ‖v_k‖² / √(‖v_k‖² + v_s²) ≤ 0 (W):
friction only dissipates. The plant reports its mean over each control period,
`table_friction_power_W`.

Why regularised (v_s > 0). Exact Coulomb friction is set-valued at v = 0 (stiction: any
force up to μ m g) and needs a constraint solver; a force that is a function of the
velocity can be applied explicitly. The price is creep: below break-away there is no
stiction, a net in-plane force F < μ m_k g on a link lets it slide steadily at
‖v‖ = v_s φ / √(1 − φ²), φ = F / (μ m_k g) (e.g. 0.58 mm/s at half the break-away force),
so an arm held by friction against its own elastic forces drifts slowly towards
equilibrium instead of sticking. v_s = 1 mm/s is small against the arm's sliding speeds
in a pressure step (peak tip speed 0.14, 0.54, 1.0 m/s for 20, 80, 150 hPa on segment 1
without friction) but NOT against the paper's 0.01 Hz sinusoid (median tip speed 2.5–5 mm/s
in `mujoco_contact`, less inboard), where the friction is partly in this viscous regime
(slope μ m_k g / v_s).

Stability (explicit force, physics step dt). The force is evaluated at the start of each
physics step (after `mj_step1`) and held through it (`mj_step2`). Its velocity Jacobian
per link has eigenvalues ≤ μ m_k g / v_s (the largest at v = 0), so the generalised
damping D = Σ_k J_kᵀ ∂f_k/∂v_k J_k ≼ (μ g / v_s) Σ_k m_k J_kᵀ J_k ≼ (μ g / v_s) M
(J_k: the COM's in-plane Jacobian; M: the mass matrix, which adds the links' rotational
inertia; implicitfast's implicit joint damping only enlarges it). The linearised velocity
update v⁺ = (I − dt M⁻¹ D) v is therefore stable when

    μ g dt / v_s < 2        (`check_table_friction` refuses otherwise)

and free of sign flips (monotone decay of a creeping link) when μ g dt / v_s < 1. At the
default dt = 0.1 ms and v_s = 1 mm/s: μ < 2.04 (monotone below 1.02); at the camera
loop's 0.2 ms, μ < 1.02.

Neglected. The friction torque of a link spinning about its own centre of mass
(≈ μ m_k g ℓ_k / 4 for a thin link of length ℓ_k spinning at rate ω ≫ v_s/ℓ_k): the links
are thin and short (1.2 cm at 10 links per segment) and move mostly by translation of
their centres, so the torque is a fraction ℓ_k/(4 r) of the arm's friction moment about
a joint at distance r. The `base` is fixed and needs none; the plates are not on the table.

MuJoCo-native alternatives, and why not:
- joint `frictionloss` (dry friction on a dof, a constant bound on the generalised force):
  the table's friction moment on hinge j is Σ over the links beyond j of (x_k − x_j) × f_k,
  which depends on the configuration and on the velocities of all outboard links (a link
  swung about an inboard hinge slides even if hinge j is still); a constant per-dof bound
  cannot represent it, and friction at rest on the joints would also stop hinges that the
  table does not stop.
- contacts with a table geom (condim 3, friction μ): the friction cone scales with the
  contact's normal force, but the hinge chain has no z degree of freedom, so the normal
  constraint's Jacobian is zero and its force is set by the soft-constraint regularisation
  (solref/solimp and the penetration depth), not by the link's weight m_k g; with the arm's
  plane vertical to MuJoCo's gravity nothing presses the links onto the table at all.
So the force is applied as the externally computed Cartesian force above.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

TABLE_GRAVITY = 9.81  # m/s², the weight the table carries (the arm's plane is horizontal)
SLIP_VELOCITY = 1e-3  # m/s, v_s: the regularisation of the Coulomb law (module docstring)
STABILITY_LIMIT = 2.0  # μ g dt / v_s must stay below it (module docstring)
TABLE_FRICTION_NUMERIC = "table_friction"  # the model's custom numeric that carries μ (absent: 0, off)


def check_table_friction(mu: float, physics_dt: float, gravity: tuple[float, float, float]) -> None:
    """Raise ValueError unless μ (`table_friction`) is finite, ≥ 0, explicit-stable at physics_dt (s)
    and, when > 0, the model's gravity (m/s²) is off (an arm on a table, not in a vertical plane)."""
    if not (math.isfinite(mu) and mu >= 0):
        raise ValueError(f"table_friction must be finite and >= 0 (0: off), got {mu}")
    if mu == 0:
        return
    if any(g != 0 for g in gravity):
        raise ValueError(f"table_friction (an arm lying on a table) cannot be combined with gravity (an arm in a "
                         f"vertical plane); got table_friction = {mu:g} and gravity = {tuple(gravity)} m/s²")
    ratio = mu * TABLE_GRAVITY * physics_dt / SLIP_VELOCITY
    if not ratio < STABILITY_LIMIT:
        largest = STABILITY_LIMIT * SLIP_VELOCITY / (TABLE_GRAVITY * physics_dt)
        raise ValueError(f"table_friction must be < {largest:.4g} at physics_dt = {physics_dt:g} s (explicit "
                         f"stability: mu g dt / v_s < {STABILITY_LIMIT:g} with v_s = {SLIP_VELOCITY:g} m/s), got {mu:g}; "
                         "lower table_friction or physics_dt")


def table_friction_of(model: mujoco.MjModel) -> float:
    """μ of a model: its custom numeric `table_friction`, or 0 (off) when it has none."""
    index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, TABLE_FRICTION_NUMERIC)
    return float(model.numeric_data[model.numeric_adr[index]]) if index >= 0 else 0.0


class TableFriction:
    """The table's friction forces on the arm's moving bodies (module docstring).

    `TableFriction(model, mu)`: every body below `base` but `base` itself; attributes `mu`,
    `bodies` (body ids) and `weights` (μ m_k g per body, N). `apply(data)` writes the forces
    into `data.xfrc_applied` and returns the friction power (W, ≤ 0).
    """

    def __init__(self, model: mujoco.MjModel, mu: float) -> None:
        check_table_friction(mu, float(model.opt.timestep), tuple(model.opt.gravity))
        base = model.body("base").id
        bodies = np.array([b for b in range(model.nbody) if b != base and model.body_rootid[b] == base], dtype=int)
        if bodies.size == 0:
            raise ValueError("the model has no bodies below `base` for table friction to act on")
        self.mu = float(mu)
        self.bodies = bodies
        self.weights = self.mu * TABLE_GRAVITY * model.body_mass[bodies]
        contiguous = np.array_equal(bodies, np.arange(bodies[0], bodies[-1] + 1))
        self._index: slice | np.ndarray = slice(int(bodies[0]), int(bodies[-1]) + 1) if contiguous else bodies
        self._reference = slice(base, base + 1)  # cvel's reference point: the subtree COM of the root, `base`

    def velocities(self, data: mujoco.MjData) -> np.ndarray:
        """In-plane COM velocities v_k (m/s, (K, 2)) of the current position and velocity stages
        (`cvel` about the root's subtree COM, moved to each body's COM `xipos`)."""
        index = self._index
        cvel = data.cvel[index]  # (K, 6): angular, linear, world-aligned at the root's subtree COM
        arm = data.xipos[index] - data.subtree_com[self._reference]
        v = np.empty((cvel.shape[0], 2))
        v[:, 0] = cvel[:, 3] + cvel[:, 1] * arm[:, 2] - cvel[:, 2] * arm[:, 1]
        v[:, 1] = cvel[:, 4] + cvel[:, 2] * arm[:, 0] - cvel[:, 0] * arm[:, 2]
        return v

    def forces(self, velocities: np.ndarray) -> np.ndarray:
        """f_k = −μ m_k g v_k / √(‖v_k‖² + v_s²) (N, (K, 2)) for in-plane velocities (m/s, (K, 2))."""
        scale = self.weights / np.sqrt(np.einsum("ij,ij->i", velocities, velocities) + SLIP_VELOCITY**2)
        return -scale[:, None] * velocities

    def apply(self, data: mujoco.MjData) -> float:
        """Write f_k into `data.xfrc_applied[k, :2]` (at the COM) and return Σ_k f_k · v_k (W, ≤ 0).

        Call after `mj_step1` (positions and velocities computed) and before `mj_step2`."""
        v = self.velocities(data)
        f = self.forces(v)
        data.xfrc_applied[self._index, :2] = f
        return float(np.einsum("ij,ij->", f, v))
