"""B MuJoCo ground truths stepped together on `mujoco.batch` (docs/ground-truth.md, docs/beyond-the-paper.md#batched-ground-truth).

Simulation b of the batch is `MujocoPlant(models[b])`: the same model, the same reset,
the same control period (hold u_b, `steps_per_control` steps of the model's
integrator, then the forward stages at the new state) and the same state read-out
(`MujocoPlant`'s docstring), so each row of a `BatchPlantState` equals what that
`MujocoPlant` reports — bit for bit, because `mujoco.batch` promises results
bit-identical to a loop over one MjData per simulation at any thread count (tested
here against `MujocoPlant`, mismatch parameters included).

Per-simulation models (a mismatch study: plate stiffness and position, joint
stiffness and damping, gear, segment lengths, …): `from_configs` compiles one
`ArmModelConfig` per simulation with `build_model`, checks that the models share the
batch model's structure, and writes every model field in which some simulation
differs into the batch's per-simulation copy of that field (`Batch.expand`), derived
constants (`actuator_acc0`, `dof_invweight0`, …) included; `set_const` then re-derives
them in the batch, which changes nothing (tested) but keeps the per-simulation model
consistent if a caller writes an input field afterwards. So no builder formula is
repeated here: whatever `build_model` does for a config, simulation b does.

`reset(q0, ..., ids=[b, ...])` resets only those simulations (`Batch.reset` and
`Batch.forward` on their ids), each as `MujocoPlant.reset` would, the others keeping their
state and time (tested against a fresh `MujocoPlant` and a batch never reset): the vector
environment (`softcbf_mj.env.vector`) restarts one arm's episode that way.

The hot path has no per-simulation Python: one `Batch.step(nstep, stage=ACC)` call per
control period, on `nthread` threads, then numpy reads of bound arrays:
- q_b, q̇_b: `ten_length`, `ten_velocity` of the tendons `seg{i}_bend` (rad, rad/s);
- segment_ends (B, N+1, 2) m: `site_xpos` of `base`, `seg{i}_end`; the tip `geom_xpos`;
- contact_forces (B, P) N: max(0, k_bp Δ_bp), k_bp the plate stiffness of simulation b;
- u_applied (B, N) hPa: `actuator_force` of the pressure actuators;
- extras: `plate_displacement_m` (B, P) m; `force_solver_N` (B, P) N, the constraint
  force on each plate's slide joint (`qfrc_constraint`): with frictionless contacts on
  the plate's face it is the normal contact force between arm and plate that
  `MujocoPlant` sums with `mj_contactForce` (equal to rounding, tested; contacts live
  in MuJoCo's arena, which the batch cannot bind); `warnings` (B, K) counts per
  MuJoCo warning (columns `WARNING_NAMES`, cumulative).

Command delay (`softcbf_mj.physics.plant`, the model's custom numeric `command_delay`): the batch's,
one δ for every simulation, applied as `MujocoPlant` does (`CommandDelay`, the rows' FIFOs in one
array); models with different delays are refused (a scenario's batch key keeps such samples apart).

Arm-table friction (`softcbf_mj.physics.table_friction`, a model with `table_friction` μ > 0) is
refused: it needs Python between the physics steps of every simulation (`MujocoPlant`
takes them one by one), which the batch's single `Batch.step` call per control period
does not allow; run such models on `MujocoPlant`.
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import mujoco.batch
import numpy as np

from softcbf_mj.physics.mjcf import ArmModelConfig, build_model
from softcbf_mj.physics.mujoco_plant import WARNINGS, MujocoPlant, command_delay_of
from softcbf_mj.physics.plant import BatchPlantState, CommandDelay, steps_per_control
from softcbf_mj.physics.table_friction import table_friction_of

EXTRAS_UNITS: dict[str, str] = {
    "plate_displacement_m": "m",
    "force_solver_N": "N",
    "warnings": "count (cumulative) per mujoco_plant.WARNINGS",
}

WARNING_NAMES: tuple[str, ...] = tuple(WARNINGS[i] for i in sorted(WARNINGS))  # the columns of extras["warnings"]

_STAGE_ACC = mujoco.mjtStage.mjSTAGE_ACC.value
_STAGE_NONE = mujoco.mjtStage.mjSTAGE_NONE.value


def _array_fields(model: mujoco.MjModel) -> list[str]:
    return [name for name in dir(model) if not name.startswith("_") and isinstance(getattr(model, name), np.ndarray)]


def per_simulation_fields(base: mujoco.MjModel, models: Sequence[mujoco.MjModel]) -> list[str]:
    """The model fields in which some of `models` differs from `base` (all expandable; raises otherwise).

    Models must share base's structure: a field that `mujoco.batch` cannot give per
    simulation (addresses, counts, assets) must be equal, and so must the options.
    """
    differing, refused = [], []
    for name in _array_fields(base):
        value = getattr(base, name)
        if any(getattr(m, name).shape != value.shape or not np.array_equal(getattr(m, name), value) for m in models):
            (differing if name in mujoco.batch.MODEL_FIELDS else refused).append(name)
    for name in ("timestep", "integrator", "jacobian", "cone", "solver", "iterations", "tolerance"):
        if any(getattr(m.opt, name) != getattr(base.opt, name) for m in models):
            refused.append(f"opt.{name}")
    if refused:
        raise ValueError(f"the models must differ only in per-simulation model fields, but differ in {refused}")
    return differing


class MujocoBatchPlant:
    """B copies of the MuJoCo plant in one `mujoco.batch.Batch` (module docstring).

    `MujocoBatchPlant(model, n_sims)`: every simulation on `model`; `from_configs(configs)`:
    simulation b on `build_model(configs[b])`. `nthread`: the batch's threads (0: all
    CPUs). Attributes: `n_sims`, `n_segments`, `n_facets`, `control_dt`, `physics_dt`,
    `steps_per_control`, `u_min`, `u_max`, `gains`, `plate_stiffness` ((B, N) / (B, P),
    per simulation), `batch` (the `mujoco.batch.Batch`) and `layout`, a `MujocoPlant` of
    the batch model whose ids and addresses the state is read by.
    """

    def __init__(self, model: mujoco.MjModel, n_sims: int, control_dt: float = 1e-3, nthread: int = 1,
                 per_simulation: Sequence[mujoco.MjModel] | None = None) -> None:
        if int(n_sims) != n_sims or n_sims < 1:
            raise ValueError(f"n_sims must be an integer >= 1, got {n_sims}")
        if int(nthread) != nthread or nthread < 0:
            raise ValueError(f"nthread must be an integer >= 0 (0: all CPUs), got {nthread}")
        self.layout = layout = MujocoPlant(model, control_dt)
        self.model = model
        with_friction = [b for b, m in enumerate(per_simulation or [model]) if table_friction_of(m) > 0]
        if with_friction:
            raise ValueError(f"MujocoBatchPlant does not model arm-table friction (table_friction > 0 in simulations "
                             f"{with_friction}); run such models on MujocoPlant")
        delays = sorted({command_delay_of(m) for m in per_simulation or [model]} | {layout.command_delay})
        if len(delays) > 1:
            raise ValueError(f"the simulations of a MujocoBatchPlant must share one command_delay, got {delays} s; "
                             "batch each delay apart")
        self.n_sims, self.n_segments, self.n_facets = int(n_sims), layout.n_segments, layout.n_facets
        self.command_delay = layout.command_delay
        periods = layout.delay.periods if layout.delay is not None else 0
        self.delay = CommandDelay(periods, (self.n_sims, self.n_segments)) if periods else None
        self.control_dt, self.physics_dt = layout.control_dt, layout.physics_dt
        self.steps_per_control = steps_per_control(self.control_dt, self.physics_dt)
        self.batch = batch = mujoco.batch.Batch(model, self.n_sims, int(nthread))
        models = [model] * self.n_sims
        if per_simulation is not None:
            models = list(per_simulation)
            if len(models) != self.n_sims:
                raise ValueError(f"per_simulation must hold n_sims = {self.n_sims} models, got {len(models)}")
            fields = per_simulation_fields(model, models)
            for name in fields:
                values = batch.expand(name)
                for b, m in enumerate(models):
                    values[b] = getattr(m, name)
            if set(fields) & set(mujoco.MjModel._setconst_inputs):
                batch.set_const()
        actuators = layout.actuator_ids
        self.u_min = np.array([m.actuator_ctrlrange[actuators, 0] for m in models])
        self.u_max = np.array([m.actuator_ctrlrange[actuators, 1] for m in models])
        self.gains = np.array([m.actuator_gear[actuators, 0] for m in models])
        plate_joints = [model.joint(f"plate{k}_slide").id for k in range(1, self.n_facets + 1)]
        self.plate_stiffness = np.array([m.jnt_stiffness[plate_joints] for m in models]).reshape(self.n_sims, self.n_facets)
        # Bind every derived field before the first call: a field bound between calls reads 0 until the next one.
        self._qpos, self._qvel = batch.bind("qpos"), batch.bind("qvel")
        self._ctrl, self._act, self._time = batch.bind("ctrl"), batch.bind("act"), batch.bind("time")
        self._ten_length, self._ten_velocity = batch.bind("ten_length"), batch.bind("ten_velocity")
        self._site_xpos, self._geom_xpos = batch.bind("site_xpos"), batch.bind("geom_xpos")
        self._actuator_force, self._qfrc_constraint = batch.bind("actuator_force"), batch.bind("qfrc_constraint")
        self.reset(np.zeros((self.n_sims, self.n_segments)))

    @classmethod
    def from_configs(cls, configs: Sequence[ArmModelConfig], control_dt: float = 1e-3, nthread: int = 1) -> "MujocoBatchPlant":
        """Simulation b runs `build_model(configs[b])`, as `MujocoPlant.from_config(configs[b])` would."""
        if not configs:
            raise ValueError("configs must hold at least one ArmModelConfig, got none")
        for config in configs:
            steps_per_control(control_dt, config.physics_dt)  # fail before compiling
        models = [build_model(config) for config in configs]
        return cls(models[0], len(models), control_dt, nthread, per_simulation=models)

    def _matrix(self, value: np.ndarray | None, name: str, default: float = 0.0, rows: int | None = None) -> np.ndarray:
        shape = (self.n_sims if rows is None else rows, self.n_segments)
        if value is None:
            return np.full(shape, default)
        arr = np.asarray(value, dtype=float)
        if arr.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got {arr.tolist()}")
        return arr

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None, u0: np.ndarray | None = None,
              ids: Sequence[int] | None = None) -> BatchPlantState:
        """`MujocoPlant.reset` of every simulation, or of the simulations `ids` only (the others
        keep their state and time): q0, qd0 (rad, rad/s) and u0 (hPa), each (B, N), or
        (len(ids), N) rows in the order of `ids`. Returns every simulation's state."""
        if ids is None:
            index = np.arange(self.n_sims)
        else:
            index = np.array(ids, dtype=int).reshape(-1)
            if len(index) == 0 or np.any((index < 0) | (index >= self.n_sims)) or len(set(index.tolist())) != len(index):
                raise ValueError(f"ids must be distinct simulations in [0, {self.n_sims - 1}], at least one, got {ids!r}")
        rows = len(index)
        q0, qd0, u0 = (self._matrix(q0, "q0", rows=rows), self._matrix(qd0, "qd0", rows=rows),
                       self._matrix(u0, "u0", rows=rows))
        outside = (u0 < self.u_min[index]) | (u0 > self.u_max[index])
        if np.any(outside):
            raise ValueError(f"u0 must lie within each simulation's ctrlrange, got {u0[np.any(outside, axis=1)].tolist()} hPa outside")
        layout = self.layout
        sims = None if ids is None else np.sort(index)  # mujoco.batch takes sorted ids
        self.batch.reset(ids=sims, stage=_STAGE_NONE)
        for i, (qpos_adr, dof_adr) in enumerate(zip(layout.hinge_qpos, layout.hinge_dofs)):
            self._qpos[np.ix_(index, qpos_adr)] = (q0[:, i] / len(qpos_adr))[:, None]
            self._qvel[np.ix_(index, dof_adr)] = (qd0[:, i] / len(dof_adr))[:, None]
        self._ctrl[np.ix_(index, layout.actuator_ids)] = u0
        if self.delay is not None:
            self.delay.reset(u0, index)
        dynamic = layout.act_adr >= 0
        self._act[np.ix_(index, layout.act_adr[dynamic])] = u0[:, dynamic]
        self.batch.forward(ids=sims)
        return self.state()

    def step(self, u: np.ndarray) -> BatchPlantState:
        """Hold u (hPa, (B, N), finite; clamped by each actuator's ctrlrange) for one control period."""
        u = self._matrix(u, "u")
        self._ctrl[:, self.layout.actuator_ids] = u if self.delay is None else self.delay.apply(u)
        self.batch.step(nstep=self.steps_per_control, stage=_STAGE_ACC)
        return self.state()

    def state(self) -> BatchPlantState:
        """Every simulation's state (fresh arrays)."""
        layout = self.layout
        ends = np.empty((self.n_sims, self.n_segments + 1, 2))
        ends[:, :-1] = self._site_xpos[:, layout.site_ids, :2]
        ends[:, -1] = self._geom_xpos[:, layout.tip_geom, :2]
        displacement = self._qpos[:, layout.plate_qpos]
        return BatchPlantState(
            t=self._time.copy(),
            q=self._ten_length[:, layout.tendon_ids],
            qd=self._ten_velocity[:, layout.tendon_ids],
            segment_ends=ends,
            contact_forces=np.maximum(0.0, self.plate_stiffness * displacement),
            u_applied=self._actuator_force[:, layout.actuator_ids],
            extras={
                "plate_displacement_m": displacement,
                "force_solver_N": self._qfrc_constraint[:, layout.plate_dofs],
                "warnings": self.batch.warning[:, :, 1].copy(),  # mjWarningStat (lastinfo, number)
            },
        )

