"""The MuJoCo ground truth as a `Plant` (docs/ground-truth.md; model in `softcbf_mj.physics.mjcf`).

Each control period (control_dt, s) holds the pressure command u (hPa, shape (N,)) and
advances the physics by control_dt / physics_dt steps of MuJoCo's `implicitfast`
integrator, then reports, at the end of the period (after `mj_forward`, so every
derived quantity belongs to the reported state):

- q_i = Σ_j θ_ij, q̇_i = Σ_j θ̇_ij (rad, rad/s): the length and velocity of the fixed
  tendon `seg{i}_bend` over segment i's hinges;
- segment_ends (N+1, 2) (m): the `base` site, the `seg{i}_end` sites; the last row is
  the tip r, the centre of the `tip` sphere (placed on `seg{N}_end`);
- contact_forces (P,) (N): per facet, the measured force: the ideal plate's spring force
  max(0, k_k Δ_k) with Δ_k the plate's displacement along its outward normal (the ground
  truth), or a flexure's gauge reading max(0, k_g x_g), the clamp reaction along the gauge
  axis (docs/beyond-the-paper.md#flexure-plate; what the hardware measures);
- u_applied (N,) (hPa): the pressure acting, the actuator force in actuator space
  (the gear carries λ_i, so this is τ_i / λ_i), after the ctrlrange clamp and the
  first-order pressure dynamics;
- extras: `plate_displacement_m` (P,) (m): the ideal plate's Δ_k, or a flexure's deflection
  along n̂ at the contact point (0 without contact); `force_solver_N` (P,) (N), the normal
  contact force MuJoCo's solver applies between the arm and each plate (mj_contactForce,
  summed over contacts: the true contact force); `force_tangential_N` (P,) (N), the
  magnitude of the summed tangential (friction) contact force, 0 when frictionless; and
  `warning_<name>` counts for every MuJoCo warning raised. With flexure plates also
  `contact_s_m` (P,) (m): where the arm touches the sheet, the distance from the clamp
  along the sheet at rest of the contact carrying the largest normal force (NaN without
  contact), and `contact_stiffness_N_per_m` (P,) (N/m): the sheet's static stiffness there
  (`SheetInModel.stiffness`: the hinge chain in series with the gauge; NaN without contact).
  Contact points are the sheet's surface points of MuJoCo's contacts (midpoint moved by
  half the penetration).

Reading the state costs next to nothing beside the physics only if it stays out of Python's
per-array calls: q, q̇, the segment ends, the measured forces, u_applied and the plates' Δ come
from MuJoCo's arrays (views of the data bound once) in one compiled call
(`softcbf_mj.physics.plant_kernel.read_state`, numpy's values bit for bit); the contact forces come from
the contact list's fields, each of whose reads builds an array in MuJoCo's bindings, read once a period as
whole arrays (dist and pos only for a flexure's point; nothing without contact) with `efc_force`, in a
second compiled call (`plant_kernel.plate_contacts`: `mj_contactForce`'s forces, bit for bit) instead of
one `mj_contactForce` call and Python's arithmetic a contact.

Command delay (`softcbf_mj.physics.plant`: the model's custom numeric `command_delay` δ > 0, s,
`ArmModelConfig.command_delay`): the command written to the actuators over a period is the one
`step` was given δ / control_dt periods earlier (`CommandDelay`, filled with u0 at `reset`);
a δ that is not a whole number of control periods is refused when the plant is built.

Table friction (`softcbf_mj.physics.table_friction`: the model's custom numeric `table_friction` μ > 0,
`ArmModelConfig.table_friction`): each physics step is then taken from Python as `mj_step1`, the
friction forces on the arm's links from the velocities just computed (`data.xfrc_applied`),
`mj_step2`; the extras add `table_friction_power_W` (W, ≤ 0), the friction power Σ_k f_k · v_k
averaged over the control period's physics steps. Without it (μ = 0, the default) the control
period's physics steps after the first are one `mj_step(…, nstep=steps_per_control − 1)` call.

The first physics step of a period reuses the reported state's `mj_forward`. `mj_step` is
`mj_step1` (the checks `mj_checkPos`, `mj_checkVel`, then the position and velocity stages:
kinematics, collision, constraint rows, passive forces — most of a forward's cost) followed by
`mj_step2` (actuation with the new ctrl, acceleration, constraint solver, integration), exactly
so for the Euler, implicit and implicitfast integrators (MuJoCo's docs). The stages read qpos,
qvel and the mocap poses, not ctrl, so at the start of a period they are those the reporting
`mj_forward` computed: the first step runs the checks and `mj_step2` only, and gives what
`mj_step` gives, bit for bit (tests/test_mujoco_plant.py). Should qpos, qvel or the mocap
poses differ from what that forward saw (the data was edited between steps, or a check reset
it), the stages are computed again (`mj_step1`). With RK4 (not split by MuJoCo) and no table
friction every physics step is `mj_step`.

`mj_step2` of that first step need not solve again either. It is `mj_fwdActuation` (actuator
forces and act_dot from ctrl and act), `mj_fwdAcceleration` (the smooth acceleration from the
passive, bias, applied and actuator forces), `mj_fwdConstraint` (the constraint solve, warm-started
from qacc_warmstart, which only integration writes), `mj_sensorAcc`, `mj_checkAcc`, then the
integrator (`mj_implicit` for the implicit ones, `mj_Euler`). The reporting `mj_forward` ran the same
stages with the old ctrl. ctrl acts on the forces only through the actuators (no `mjcb_control`), so
when `mj_fwdActuation` with the new ctrl leaves actuator_force and qfrc_actuator as they were, and
qfrc_applied and xfrc_applied are untouched, every input of the acceleration, constraint and sensor
stages is the one that forward saw, and their outputs (qacc, efc_force, sensordata) are those it
left, bit for bit. This holds for actuators with pressure dynamics (the force is λ·act; ctrl moves
only act_dot, which the integrator reads); an ideal actuator (no pressure lag: the force is λ·ctrl)
changes the forces and takes the whole `mj_step2`, as does `mjENBL_FWDINV` (its check runs there).
The first step is then `mj_fwdActuation`, `mj_checkAcc` and the integrator: a control period solves
the constraints steps_per_control times, as bare `mj_step` does, not once more for the report.
Assumed: no `mjcb_control` callback (nor user actuator callbacks or plugins that read ctrl beyond
the forces), and the model is not changed between steps without an `mj_forward`.
"""

from __future__ import annotations

import dataclasses
import math
import platform
import re
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

import softcbf_mj
from controllers.core.lazy_import import lazy_module
from softcbf_mj.physics.flexure import SheetInModel
from softcbf_mj.physics.mjcf import ArmModelConfig, build_model
from softcbf_mj.physics.plant import COMMAND_DELAY_NUMERIC, CommandDelay, PlantState, delay_periods, steps_per_control
from softcbf_mj.physics.table_friction import TableFriction, table_friction_of

MUJOCO_VERSION: str = mujoco.__version__
# Short names of MuJoCo's warnings (inertia, contactfull, …, badctrl) by index into data.warning.
WARNINGS: dict[int, str] = {
    int(value): name.removeprefix("mjWARN_").lower()
    for name, value in mujoco.mjtWarning.__members__.items()
    if name.startswith("mjWARN_")
}

# Integrators whose physics step MuJoCo splits exactly into mj_step1 + mj_step2 (not RK4).
# Whether MuJoCo's contacts carry an adhesion that `mj_contactForce` takes off the normal force (MuJoCo >= 4.0.1).
CONTACT_ADHESION: bool = hasattr(mujoco.MjContact, "adhesion")

SPLIT_INTEGRATORS = frozenset(int(i) for i in (mujoco.mjtIntegrator.mjINT_EULER, mujoco.mjtIntegrator.mjINT_IMPLICIT,
                                               mujoco.mjtIntegrator.mjINT_IMPLICITFAST))

# Units of the `PlantState.extras` this plant reports (for run records).
EXTRAS_UNITS: dict[str, str] = {
    "plate_displacement_m": "m",
    "force_solver_N": "N",
    "force_tangential_N": "N",
    "contact_s_m": "m (from the sheet's clamp; NaN: no contact)",
    "contact_stiffness_N_per_m": "N/m (NaN: no contact)",
    "table_friction_power_W": "W (arm-table friction power, mean over the control period, <= 0)",
    **{f"warning_{name}": "count (cumulative)" for name in WARNINGS.values()},
}

plant_kernel = lazy_module("softcbf_mj.physics.plant_kernel")  # numba loads on the first state (controllers.core.lazy_import)
_ACTUATOR = re.compile(r"seg(\d+)_pressure")
_PLATE_JOINT = re.compile(r"plate(\d+)_(?:slide|gauge)")


def command_delay_of(model: mujoco.MjModel) -> float:
    """δ of a model (s): its custom numeric `command_delay`, or 0 (none) when it has none."""
    index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, COMMAND_DELAY_NUMERIC)
    return float(model.numeric_data[model.numeric_adr[index]]) if index >= 0 else 0.0


def _names(model: mujoco.MjModel, obj: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, obj, i) or "" for i in range(count)]


def _numbered(names: list[str], pattern: re.Pattern[str], what: str) -> int:
    """How many of `names` match pattern with numbers 1..K; raises if the numbering has gaps."""
    numbers = sorted(int(m.group(1)) for m in map(pattern.fullmatch, names) if m)
    if numbers != list(range(1, len(numbers) + 1)):
        raise ValueError(f"the model's {what} must be numbered 1..K without gaps, got {numbers}")
    return len(numbers)


class MujocoPlant:
    """The discretised arm and its compliant plates in MuJoCo, stepped at a fixed control rate.

    Build it from parameters with `from_config` (an `ArmModelConfig` and/or its fields as
    keywords), from an MJCF file with `from_xml`, or from a compiled model. Attributes
    read from the model: `u_min`, `u_max` (hPa, the ctrlrange), `gains` (λ, N·m/hPa, the
    actuator gears), `plate_stiffness` (N/m), `n_segments`, `n_facets`, and per segment
    the qpos / dof addresses of its hinges, `hinge_qpos` and `hinge_dofs` (lists of arrays).
    Ids and addresses the state is read from (public for the batched plant,
    `softcbf_mj.physics.mujoco_batch_plant`): `actuator_ids` and `tendon_ids` (N,), `site_ids`
    (N,: `base`, `seg1_end` … `seg{N-1}_end`), `tip_geom`, `plate_qpos` and `plate_dofs`
    (P,), `act_adr` (N,: −1 where the actuator has no pressure dynamics). `table_friction`:
    the arm-table friction (`TableFriction`) when the model carries μ > 0, else None.
    The model is read by name: actuators `seg{i}_pressure`, tendons `seg{i}_bend`, hinges
    `seg{i}_j{j}`, sites `base` and `seg{i}_end`, geom `tip`, per facet an ideal plate
    (joint `plate{k}_slide`) or a flexure (joint `plate{k}_gauge`, `SheetInModel`), whose
    geoms are those of the bodies below body `plate{k}`. `plate_stiffness` is the spring of
    that joint: the plate's (ideal) or the gauge's (flexure); `sheets` maps the facet index
    (0-based) of each flexure to its `SheetInModel`.
    """

    def __init__(self, model: mujoco.MjModel, control_dt: float = 1e-3) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.control_dt = float(control_dt)
        self.physics_dt = float(model.opt.timestep)
        self.steps_per_control = steps_per_control(self.control_dt, self.physics_dt)

        n = _numbered(_names(model, mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu), _ACTUATOR, "actuators seg{i}_pressure")
        if n == 0:
            raise ValueError("the model has no actuators named seg{i}_pressure")
        self.n_segments = n
        self.actuator_ids = [model.actuator(f"seg{i}_pressure").id for i in range(1, n + 1)]
        self.tendon_ids = [model.tendon(f"seg{i}_bend").id for i in range(1, n + 1)]
        self.hinge_qpos: list[np.ndarray] = []  # per segment: qpos addresses of its hinges
        self.hinge_dofs: list[np.ndarray] = []  # per segment: their dof addresses
        for i in range(1, n + 1):
            hinges, j = [], 1
            while mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"seg{i}_j{j}") >= 0:
                hinges.append(model.joint(f"seg{i}_j{j}"))
                j += 1
            if not hinges:
                raise ValueError(f"the model has no hinges seg{i}_j1, seg{i}_j2, …")
            self.hinge_qpos.append(np.array([h.qposadr[0] for h in hinges]))
            self.hinge_dofs.append(np.array([h.dofadr[0] for h in hinges]))
        self.site_ids = [model.site("base").id] + [model.site(f"seg{i}_end").id for i in range(1, n)]
        self.tip_geom = model.geom("tip").id

        p = _numbered(_names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt), _PLATE_JOINT, "plate joints plate{k}_slide or plate{k}_gauge")
        self.n_facets = p
        flexures = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"plate{k}_gauge") >= 0 for k in range(1, p + 1)]
        plate_joints = [model.joint(f"plate{k}_{'gauge' if flexure else 'slide'}") for k, flexure in enumerate(flexures, 1)]
        self.plate_qpos = np.array([jnt.qposadr[0] for jnt in plate_joints], dtype=int)
        self.plate_dofs = np.array([jnt.dofadr[0] for jnt in plate_joints], dtype=int)
        self.plate_stiffness = np.array([model.jnt_stiffness[jnt.id] for jnt in plate_joints])
        self.sheets = {k - 1: SheetInModel.from_model(model, k) for k, flexure in enumerate(flexures, 1) if flexure}
        plate_roots = {model.body(f"plate{k}").id: k - 1 for k in range(1, p + 1)}
        roots = model.body_rootid[model.geom_bodyid].tolist()  # per geom: the root body of its body
        base = model.body("base").id
        # per geom: its plate's facet (-1: none), and whether it is part of the arm (below `base`)
        self._facet_of_geom = np.array([plate_roots.get(root, -1) for root in roots], dtype=np.int64)
        self._on_arm = np.array([root == base for root in roots], dtype=bool)
        self._pyramidal = int(model.opt.cone) == int(mujoco.mjtCone.mjCONE_PYRAMIDAL)  # how efc_force holds a contact
        self._no_dist, self._no_points = np.zeros(0), np.zeros((0, 2))  # `_plate_contacts` without points
        # the ids the state reads (`softcbf_mj.physics.plant_kernel.read_state`'s `index`), and MuJoCo's arrays it reads
        # them from: views of the data bound once (their shapes are the model's; reading an attribute of the
        # data builds a new array each time)
        self._state_index = np.array([*self.tendon_ids, *self.actuator_ids, *self.site_ids, self.tip_geom,
                                      *self.plate_qpos], dtype=np.int64)
        self._actuator_index = np.array(self.actuator_ids)
        data = self.data
        self._ctrl = data.ctrl
        self._state_arrays = (data.qpos, data.ten_length, data.ten_velocity, data.site_xpos, data.geom_xpos,
                              data.actuator_force)
        # what the position and velocity stages read (`_stage_inputs`): qpos, qvel and, if any, the mocap poses
        self._stage_arrays = (data.qpos, data.qvel, *((data.mocap_pos, data.mocap_quat) if model.nmocap else ()))
        # what the acceleration stages read beside them (`_force_inputs`): the applied and the actuator forces
        self._force_arrays = (data.qfrc_applied, data.xfrc_applied, data.actuator_force, data.qfrc_actuator)
        self._fwdinv = bool(model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_FWDINV)
        self._implicit = int(model.opt.integrator) in (int(mujoco.mjtIntegrator.mjINT_IMPLICIT),
                                                       int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))
        self._warning_counts = data.warning.number  # (mjNWARNING,) int, a view of the data's warning stats

        self.u_min = model.actuator_ctrlrange[self.actuator_ids, 0].copy()
        self.u_max = model.actuator_ctrlrange[self.actuator_ids, 1].copy()
        self.gains = model.actuator_gear[self.actuator_ids, 0].copy()
        self.act_adr = model.actuator_actadr[self.actuator_ids].copy()  # -1: no pressure dynamics
        mu = table_friction_of(model)
        self.table_friction = TableFriction(model, mu) if mu > 0 else None
        self._friction_power = 0.0  # W, mean over the last control period
        # mj_step1 + mj_step2 is mj_step for these integrators (MuJoCo's docs; RK4 is not split)
        self._split_steps = int(model.opt.integrator) in SPLIT_INTEGRATORS
        self._forwarded: tuple[bytes, ...] = ()  # `_stage_inputs` at the last `_forward`
        self._forwarded_forces: tuple[bytes, ...] = ()  # `_force_inputs` at the last `_forward`
        self.command_delay = command_delay_of(model)  # s; the FIFO below when > 0 (module docstring)
        periods = delay_periods(self.command_delay, self.control_dt)
        self.delay = CommandDelay(periods, (1, n)) if periods else None
        self.reset(np.zeros(n))

    # -- construction -------------------------------------------------------------

    @classmethod
    def from_config(
        cls, config: ArmModelConfig | None = None, control_dt: float = 1e-3, **changes: Any
    ) -> "MujocoPlant":
        """Build the model of `config` with `changes` applied to its fields.

        E.g. `MujocoPlant.from_config(robot=my_robot, H=H, h=h, plate_stiffness=11.16,
        links_per_segment=10, tau_p=0.05, physics_dt=1e-4)`; omitted fields keep the
        defaults of `ArmModelConfig` (the reference robot and the paper's plate).
        """
        config = dataclasses.replace(config or ArmModelConfig(), **changes)
        steps_per_control(control_dt, config.physics_dt)  # fail before compiling
        return cls(build_model(config), control_dt)

    @classmethod
    def from_xml(cls, path: str | Path, control_dt: float = 1e-3) -> "MujocoPlant":
        """Load an MJCF file (e.g. models/softcbf_arm/scene.xml); its timestep is the physics step."""
        return cls(mujoco.MjModel.from_xml_path(str(path)), control_dt)

    @staticmethod
    def versions() -> dict[str, str]:
        """Versions that change this plant's behaviour (for run records)."""
        return {"softcbf_mj": softcbf_mj.__version__, "mujoco": MUJOCO_VERSION, "python": platform.python_version()}

    # -- Plant protocol -----------------------------------------------------------

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None, u0: np.ndarray | None = None) -> PlantState:
        """Rest at bending angles q0 (rad, (N,)), each spread equally over its segment's hinges.

        qd0 (rad/s) is spread likewise (default 0). The plates start undeflected and at
        rest. The pressures start at u0 (hPa, default 0): the actuator states and the
        command are both set to it. Time restarts at 0.
        """
        q0 = self._vector(q0, "q0")
        qd0 = np.zeros(self.n_segments) if qd0 is None else self._vector(qd0, "qd0")
        u0 = np.zeros(self.n_segments) if u0 is None else self._vector(u0, "u0")
        outside = (u0 < self.u_min) | (u0 > self.u_max)
        if np.any(outside):
            raise ValueError(
                f"u0 must lie within the ctrlrange [{self.u_min.tolist()}, {self.u_max.tolist()}] hPa, got {u0.tolist()}"
            )
        mujoco.mj_resetData(self.model, self.data)
        for i in range(self.n_segments):
            self.data.qpos[self.hinge_qpos[i]] = q0[i] / len(self.hinge_qpos[i])
            self.data.qvel[self.hinge_dofs[i]] = qd0[i] / len(self.hinge_dofs[i])
        self.data.ctrl[self.actuator_ids] = u0
        if self.delay is not None:
            self.delay.reset(u0[None, :])
        dynamic = self.act_adr >= 0
        self.data.act[self.act_adr[dynamic]] = u0[dynamic]
        self._forward()
        self._friction_power = 0.0
        self._load_contact_kernel()
        return self.state()

    def step(self, u: np.ndarray) -> PlantState:
        """Hold u (hPa, (N,), finite) for one control period and return the state at its end.

        u is NOT clipped here: MuJoCo clamps it to each actuator's ctrlrange (the
        pressure limits of `RobotParams`), and `u_applied` reports what acted.
        """
        model, data, friction = self.model, self.data, self.table_friction
        u = self._vector(u, "u")
        self._ctrl[self._actuator_index] = u if self.delay is None else self.delay.apply(u[None, :])[0]
        if friction is None and not self._split_steps:
            mujoco.mj_step(model, data, nstep=self.steps_per_control)
        elif friction is None:
            self._first_step2(self._first_step1())
            mujoco.mj_step(model, data, nstep=self.steps_per_control - 1)
        else:
            energy_rate = 0.0
            for substep in range(self.steps_per_control):
                if substep == 0:
                    self._first_step1()
                else:
                    mujoco.mj_step1(model, data)
                energy_rate += friction.apply(data)
                mujoco.mj_step2(model, data)
            self._friction_power = energy_rate / self.steps_per_control
        self._forward()
        return self.state()

    def state(self) -> PlantState:
        """The state of the current data (after `mj_forward`, if you edited it)."""
        n, p = self.n_segments, self.n_facets
        # one new array holds every fixed-size value: q, qd, segment ends, contact forces, u_applied and spring
        # (plant_kernel), then the solver's normal and tangential forces (`_plate_contacts`); the state's arrays
        # are views of it (about 1 µs an array fewer to build, on the loop's every period)
        values = np.zeros(5 * n + 2 + 4 * p)
        plant_kernel.read_state(*self._state_arrays, self._state_index, self.plate_stiffness, values)
        ends, applied, solver = 2 * n, 4 * n + 2 + p, 5 * n + 2 + 2 * p
        spring = values[applied + n:solver]  # the plate's Δ or the gauge's x_g, m
        normal, tangential = values[solver:solver + p], values[solver + p:]
        points = self._plate_contacts(normal, tangential, bool(self.sheets))
        displacement = spring.copy() if self.sheets else spring
        extras: dict[str, float | np.ndarray] = {
            "plate_displacement_m": displacement,
            "force_solver_N": normal,
            "force_tangential_N": tangential,
        }
        if self.sheets:
            where = np.full(self.n_facets, np.nan)
            stiffness = np.full(self.n_facets, np.nan)
            for k, sheet in self.sheets.items():
                point = points[k]
                displacement[k] = 0.0
                if np.all(np.isfinite(point)):
                    relative = point - sheet.origin
                    displacement[k] = float(sheet.normal @ relative)
                    where[k] = float(sheet.along @ relative)
                    stiffness[k] = float(sheet.stiffness(where[k]))
            extras["contact_s_m"] = where
            extras["contact_stiffness_N_per_m"] = stiffness
        if self.table_friction is not None:
            extras["table_friction_power_W"] = self._friction_power
        counts = self._warning_counts.tolist()
        if any(counts):
            for index, count in enumerate(counts):
                if count:
                    extras[f"warning_{WARNINGS[index]}"] = float(count)
        return PlantState(t=self.data.time, q=values[:n], qd=values[n:ends],
                          segment_ends=values[ends:applied - p].reshape(n + 1, 2),
                          contact_forces=values[applied - p:applied], u_applied=values[applied:applied + n], extras=extras)

    # -- internals ----------------------------------------------------------------

    def _forward(self) -> None:
        """`mj_forward` of the state to report, and a note of the inputs it saw (`_first_step1`)."""
        data = self.data
        mujoco.mj_forward(self.model, data)
        self._forwarded = self._stage_inputs()
        self._forwarded_forces = self._force_inputs()

    def _stage_inputs(self) -> tuple[bytes, ...]:
        """What MuJoCo's position and velocity stages read from the data: qpos, qvel, the mocap poses."""
        return tuple([array.tobytes() for array in self._stage_arrays])

    def _force_inputs(self) -> tuple[bytes, ...]:
        """The forces MuJoCo's acceleration stages read beside those stages' outputs: qfrc_applied,
        xfrc_applied, actuator_force, qfrc_actuator."""
        return tuple([array.tobytes() for array in self._force_arrays])

    def _first_step1(self) -> bool:
        """`mj_step1` of a control period's first physics step (module docstring): its checks,
        and its position and velocity stages only if their inputs have changed since `_forward`.
        True when they had not (the forward's stages stand)."""
        model, data = self.model, self.data
        mujoco.mj_checkPos(model, data)
        mujoco.mj_checkVel(model, data)
        if self._stage_inputs() != self._forwarded:  # edited, or reset by a check: compute them
            mujoco.mj_step1(model, data)
            return False
        return True

    def _first_step2(self, forwarded: bool) -> None:
        """`mj_step2` of a control period's first physics step (module docstring): after `mj_fwdActuation`
        with the new ctrl, the acceleration, constraint and sensor stages only if their inputs differ from
        those of `_forward` (`forwarded`: its position and velocity stages stand)."""
        model, data = self.model, self.data
        if not forwarded or self._fwdinv:
            mujoco.mj_step2(model, data)
            return
        mujoco.mj_fwdActuation(model, data)
        if self._force_inputs() != self._forwarded_forces:  # ctrl moved the forces (or they were edited)
            mujoco.mj_step2(model, data)  # its mj_fwdActuation gives what the one above gave
            return
        mujoco.mj_checkAcc(model, data)
        if self._implicit:
            mujoco.mj_implicit(model, data)
        else:
            mujoco.mj_Euler(model, data)

    def _vector(self, value: np.ndarray, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (self.n_segments,):
            raise ValueError(f"{name} must have shape ({self.n_segments},), got {arr.shape}")
        if not all(map(math.isfinite, arr.tolist())):  # Python floats: faster than numpy for N ~ 2
            raise ValueError(f"{name} must be finite, got {arr.tolist()}")
        return arr

    def _load_contact_kernel(self) -> None:
        """Run `plant_kernel.plate_contacts` once over the current contact list, empty or not (`_plate_contacts`
        with `always`), into scratch arrays: numba loads it (or compiles it, on a cold cache) here, before a loop
        starts, not at the loop's first contact, where it stalled a real-time loop (the emulated board's watchdog
        vented: tests/test_hardware_warm_up.py). The contact list's fields have the same array types at any length."""
        self._plate_contacts(np.zeros(self.n_facets), np.zeros(self.n_facets), False, always=True)

    def _plate_contacts(self, normal: np.ndarray, tangential: np.ndarray, points: bool,
                        always: bool = False) -> np.ndarray | None:
        """Per facet, MuJoCo's contact forces between the arm and the plate (`mj_contactForce`'s), written into
        `normal` and `tangential` ((P,) N, zeros on entry): the summed normal force and the magnitude of the
        summed tangential force. Returns, with `points`, the sheet-surface point (world x, y, m; (P, 2)) of each
        facet's strongest contact (NaN: none), else None (the ideal plate does not report it).

        One compiled call over the contact list's fields (`plant_kernel.plate_contacts`): each read of a field
        of MuJoCo's contact list, and each `mj_contactForce` call, builds an array in MuJoCo's bindings, so the
        fields are read once a period as whole arrays (dist and pos only for the points); `always`: the kernel runs
        also over an empty list (`_load_contact_kernel`)."""
        data = self.data
        where = np.full((self.n_facets, 2), np.nan) if points else self._no_points
        if not data.ncon and not always:  # no contact: the list's wrapper and its fields are not built
            return where if points else None
        contact = data.contact  # MuJoCo's contact list, ncon long
        dist, pos = (contact.dist, contact.pos) if points else (self._no_dist, self._no_points)
        adhesion = contact.adhesion if CONTACT_ADHESION else np.zeros(data.ncon)
        plant_kernel.plate_contacts(contact.geom, contact.efc_address, contact.dim, contact.friction, adhesion,
                                    contact.frame, dist, pos, data.efc_force, self._pyramidal, self._facet_of_geom,
                                    self._on_arm, points, normal, tangential, where)
        return where if points else None
