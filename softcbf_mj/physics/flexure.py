"""The flexure plate (docs/beyond-the-paper.md#flexure-plate): a clamped cantilever sheet in a force gauge, as on the hardware.

The hardware's plate is a flexible ABS sheet clamped at one end into a force gauge; its
spring constant was calibrated with masses at its tip. Unlike the rigid plate on a slide
spring (the "ideal" plate, `softcbf_mj.physics.mjcf`), its stiffness depends on where it
is touched and it rotates as it bends.

Beam (Euler–Bernoulli, small deflection). Sheet of length ℓ, thickness t, width w (along
z) and Young's modulus E: bending stiffness EI = E w t³ / 12 (N·m²). A normal point load
F at distance s from the clamp deflects the loaded point by F s³ / (3 EI), so the
stiffness seen there is

    K_EB(s) = 3 EI / s³   (N/m),   the tip's K_EB(ℓ) = 3 EI / ℓ³,

and the sheet there turns by F s² / (2 EI) rad (it does not only translate along the
normal: the paper's assumption 2 fails). Its first bending mode has ω₁ = 1.8751² √(EI /
(ρ w t ℓ⁴)) (rad/s, ρ the density).

Discretisation (as the arm's cells, docs/ground-truth.md). The sheet is cut into n equal cells of length
c = ℓ / n with a hinge at the centre of each, s_j = (j − ½) c, of stiffness EI / c
(N·m/rad): the first half cell is part of the clamp. A normal load F at s then turns hinge
j (s_j < s) by F (s − s_j) c / EI, and the loaded point moves by

    δ(s) = F Σ_{s_j < s} (s − s_j)² c / EI,

the midpoint rule of ∫₀ˢ (s − x)² dx / EI: at the tip δ = F ℓ³ (1 − 1/(4 n²)) / (3 EI),
0.25 % stiffer than Euler–Bernoulli at n = 10 (`chain_stiffness`). Damping: hinge damping
β·(EI / c) (stiffness-proportional, β = 2 ζ / ω₁) gives the first mode the damping ratio ζ
and damps the higher modes more (ζ_i = β ω_i / 2).

Gauge. The clamp sits on a slide joint along the facet's outward normal n̂ (the gauge
axis) with stiffness k_g (N/m); the gauge reads the clamp reaction along that axis,
F_gauge = k_g x_g (x_g the clamp's displacement, > 0 outward). It adds its compliance in
series: the stiffness at s is 1 / (δ(s)/F + 1/k_g) (`chain_stiffness`).

Placement. The sheet's surface at rest lies on the facet line (shifted by the arm's tip
radius, as the ideal plate), from the clamp at σ = `clamp_at` to its free end at
σ = `free_end_at`, where σ is the position along the facet line from the foot of the
perpendicular from the base, along t̂ = (−n̂_y, n̂_x) (m). Defaults: the clamp at −0.055 m
and the free end at −0.205 m on the paper's facet (ℓ = 0.15 m). The tip of the paper's
run (mujoco_contact, 40 s, None/Low/High) touches the facet at σ ∈ [−0.195, −0.172] m
(the arm's reach ends at σ = −0.199 m), so the free end lies just beyond every contact and
the clamp inside the reach: the arm touches the sheet 10–33 mm from its free end, where it
is 1.1–1.9× stiffer than at the calibration point (the tip, as the paper calibrated).

Default sheet (ABS, documented in models/softcbf_arm/README.md): E = 2 GPa, ρ = 1040 kg/m³,
ℓ = 0.15 m, w = 0.04 m (the ideal plate's height) and the thickness t = 1.23044 mm whose
calibration as the paper did it (`softcbf_mj.physics.flexure_calibration`: 0.16 N at the free end)
gives the paper's k = 11.16 N/m. Euler–Bernoulli alone would give t = (4 k ℓ³ / (E w))^(1/3)
= 1.23491 mm (`thickness_for_tip_stiffness`); the 14 mm deflection at that load stiffens the
sheet by ≈ 1 % (large deflection), which the calibration includes, as the paper's did.

Units: SI (m, kg, s, N, Pa).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from vocabulary.settings import setting

ABS_YOUNGS_MODULUS = setting("sheet_youngs_modulus").default  # Pa, ABS (chosen: typical 1.8–2.4 GPa)
ABS_DENSITY = 1040.0  # kg/m³, ABS
FIRST_MODE_BETA_L = 1.8751040687  # β₁ℓ of a clamped-free beam


def thickness_for_tip_stiffness(stiffness: float, length: float, width: float, youngs_modulus: float) -> float:
    """Thickness t (m) whose Euler–Bernoulli tip stiffness 3 E (w t³/12) / ℓ³ is `stiffness` (N/m)."""
    for name, value in (("stiffness", stiffness), ("length", length), ("width", width), ("youngs_modulus", youngs_modulus)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value}")
    return (4.0 * stiffness * length**3 / (youngs_modulus * width)) ** (1.0 / 3.0)


DEFAULT_LENGTH = 0.15  # m
DEFAULT_WIDTH = setting("sheet_width").default  # m
# m: calibrated in MuJoCo as the paper did (0.16 N at the free end, tools/calibrate_flexure.py
# --fit 11.16) this sheet gives k = 11.160 N/m; Euler–Bernoulli's 11.16 N/m thickness is 1.23491 mm
# (`thickness_for_tip_stiffness`), 1 % softer at that load: the 14 mm deflection stiffens the sheet.
DEFAULT_THICKNESS = setting("sheet_thickness").default


@dataclass(frozen=True)
class FlexureParams:
    """One flexure plate: sheet, discretisation, gauge and placement (units in the module docstring).

    | field              | default   | unit  | source                                   |
    |--------------------|-----------|-------|------------------------------------------|
    | clamp_at           | −0.055    | m     | chosen (paper run's contact path)        |
    | free_end_at        | −0.205    | m     | chosen (beyond the reach, −0.199 m)      |
    | thickness          | 1.23044e-3| m     | calibrated k = 11.16 N/m (paper)         |
    | width              | 0.04      | m     | chosen (the ideal plate's height)        |
    | youngs_modulus     | 2e9       | Pa    | ABS                                      |
    | density            | 1040      | kg/m³ | ABS                                      |
    | links              | 10        | —     | convergence study (model README)         |
    | damping_ratio      | 0.2       | —     | chosen (first mode, as the ideal plate)  |
    | gauge_stiffness    | 1e4       | N/m   | chosen (a stiff load cell: 0.1 % of δ)   |
    | gauge_mass         | 0.05      | kg    | chosen (clamp and load cell)             |
    | gauge_damping_ratio| 0.7       | —     | chosen                                   |
    | calibration_fraction| 1.0      | —     | paper (masses at the tip)                |

    `calibration_fraction`: the calibration point's distance from the clamp as a fraction of ℓ.
    A field that is a setting (clamp_at … calibration_fraction: `sheet_<field>` of `vocabulary.settings`)
    takes its default from there, the one home of a default; the table shows those values.
    """

    clamp_at: float = setting("sheet_clamp_at").default
    free_end_at: float = setting("sheet_free_end_at").default
    thickness: float = DEFAULT_THICKNESS
    width: float = DEFAULT_WIDTH
    youngs_modulus: float = ABS_YOUNGS_MODULUS
    density: float = ABS_DENSITY
    links: int = setting("sheet_links").default
    damping_ratio: float = 0.2
    gauge_stiffness: float = 1.0e4
    gauge_mass: float = 0.05
    gauge_damping_ratio: float = 0.7
    calibration_fraction: float = setting("sheet_calibration_fraction").default

    def __post_init__(self) -> None:
        for name in ("thickness", "width", "youngs_modulus", "density", "gauge_stiffness", "gauge_mass"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        for name in ("damping_ratio", "gauge_damping_ratio"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        if not (math.isfinite(self.clamp_at) and math.isfinite(self.free_end_at) and self.length > 0):
            raise ValueError(
                f"clamp_at and free_end_at must be finite and differ (the sheet's length), got {self.clamp_at}, {self.free_end_at} m"
            )
        if int(self.links) != self.links or self.links < 1:
            raise ValueError(f"links must be an integer >= 1, got {self.links}")
        object.__setattr__(self, "links", int(self.links))
        if not (math.isfinite(self.calibration_fraction) and 0 < self.calibration_fraction <= 1):
            raise ValueError(f"calibration_fraction must lie in (0, 1] (1: the free end), got {self.calibration_fraction}")

    @property
    def length(self) -> float:
        """ℓ, m."""
        return abs(self.free_end_at - self.clamp_at)

    @property
    def direction(self) -> float:
        """+1 if the sheet runs from the clamp along +t̂, −1 along −t̂."""
        return 1.0 if self.free_end_at > self.clamp_at else -1.0

    @property
    def bending_stiffness(self) -> float:
        """EI = E w t³ / 12, N·m²."""
        return self.youngs_modulus * self.width * self.thickness**3 / 12.0

    @property
    def cell(self) -> float:
        """c = ℓ / n, m."""
        return self.length / self.links

    @property
    def hinge_stiffness(self) -> float:
        """EI / c, N·m/rad."""
        return self.bending_stiffness / self.cell

    @property
    def mass(self) -> float:
        """ρ ℓ w t, kg."""
        return self.density * self.length * self.width * self.thickness

    @property
    def first_mode(self) -> float:
        """ω₁ = 1.8751² √(EI / (ρ w t ℓ⁴)), rad/s."""
        return FIRST_MODE_BETA_L**2 * math.sqrt(self.bending_stiffness / (self.density * self.width * self.thickness * self.length**4))

    @property
    def hinge_damping(self) -> float:
        """β EI / c with β = 2 ζ / ω₁, N·m·s/rad."""
        return 2.0 * self.damping_ratio / self.first_mode * self.hinge_stiffness

    @property
    def gauge_damping(self) -> float:
        """2 ζ_g √(k_g m_g), N·s/m."""
        return 2.0 * self.gauge_damping_ratio * math.sqrt(self.gauge_stiffness * self.gauge_mass)

    @property
    def calibration_s(self) -> float:
        """Distance of the calibration point from the clamp, m."""
        return self.calibration_fraction * self.length

    def hinge_positions(self) -> np.ndarray:
        """s_j = (j − ½) c, m, shape (n,)."""
        return (np.arange(self.links) + 0.5) * self.cell

    def euler_bernoulli_stiffness(self, s: float | np.ndarray) -> np.ndarray:
        """3 EI / s³ (N/m) at distance s (m) from the clamp: the continuous sheet on a rigid clamp."""
        s = np.asarray(s, dtype=float)
        return 3.0 * self.bending_stiffness / s**3

    def chain_stiffness(self, s: float | np.ndarray, gauge: bool = True) -> np.ndarray:
        """Static stiffness (N/m) of the hinge chain at s (m): 1 / (Σ_{s_j<s} (s − s_j)²/(EI/c) [+ 1/k_g])."""
        return chain_stiffness(s, self.hinge_positions(), np.full(self.links, self.hinge_stiffness),
                               self.gauge_stiffness if gauge else math.inf)


def chain_stiffness(s: float | np.ndarray, hinge_s: np.ndarray, hinge_stiffness: np.ndarray, gauge_stiffness: float) -> np.ndarray:
    """Normal stiffness (N/m) at distance s (m, any shape) along a hinge chain on a gauge.

    Hinges at s_j (m, (n,)) of stiffness k_j (N·m/rad), the gauge in series (k_g N/m,
    `math.inf`: rigid): 1 / (Σ_{s_j < s} (s − s_j)² / k_j + 1 / k_g). Small deflection.
    """
    s = np.asarray(s, dtype=float)
    arm = np.maximum(s[..., None] - np.asarray(hinge_s, dtype=float), 0.0)
    compliance = np.sum(arm**2 / np.asarray(hinge_stiffness, dtype=float), axis=-1) + 1.0 / gauge_stiffness
    return 1.0 / compliance


@dataclass(frozen=True)
class SheetInModel:
    """Flexure plate k of a compiled model (names as `softcbf_mj.physics.mjcf` writes them), at rest.

    clamp_body: body id of `plate{k}` (the clamp); gauge_qpos: qpos address of
    `plate{k}_gauge`; gauge_stiffness (N/m); origin (2,) m: the clamp end of the sheet's
    surface at rest (world x, y); normal (2,): the gauge axis n̂ (outward); along (2,): the
    sheet's direction from the clamp; bodies: body ids of the clamp and the links in order;
    starts (n+1,) m: where each body's part of the sheet begins (0, then the hinges s_j);
    hinge_stiffness (n,) N·m/rad.
    """

    clamp_body: int
    gauge_qpos: int
    gauge_stiffness: float
    origin: np.ndarray
    normal: np.ndarray
    along: np.ndarray
    bodies: tuple[int, ...]
    starts: np.ndarray
    hinge_stiffness: np.ndarray

    @classmethod
    def from_model(cls, model: mujoco.MjModel, k: int) -> "SheetInModel":
        """Read sheet k (1-based) from `model`; raises if the model has no joint `plate{k}_gauge`."""
        gauge = model.joint(f"plate{k}_gauge")
        clamp = model.body(f"plate{k}")
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, clamp.quat)
        rotation = rotation.reshape(3, 3)
        bodies, starts, stiffness, s = [clamp.id], [0.0], [], 0.0
        j = 1
        while mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"plate{k}_link{j}") >= 0:
            body = model.body(f"plate{k}_link{j}")
            s += abs(float(body.pos[1]))
            bodies.append(body.id)
            starts.append(s)
            stiffness.append(float(model.jnt_stiffness[model.joint(f"plate{k}_h{j}").id]))
            j += 1
        sign = math.copysign(1.0, float(model.body(f"plate{k}_link1").pos[1])) if j > 1 else 1.0
        return cls(
            clamp_body=clamp.id, gauge_qpos=int(gauge.qposadr[0]), gauge_stiffness=float(model.jnt_stiffness[gauge.id]),
            origin=np.array(clamp.pos[:2], dtype=float), normal=rotation[:2, 0].copy(), along=sign * rotation[:2, 1],
            bodies=tuple(bodies), starts=np.array(starts), hinge_stiffness=np.array(stiffness),
        )

    def point(self, s: float) -> tuple[int, np.ndarray]:
        """The body carrying the surface point at distance s (m) from the clamp and that point in its frame (m, (3,))."""
        j = int(np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.bodies) - 1))
        sign = float(self.along @ np.array([-self.normal[1], self.normal[0]]))  # ±1: the sheet runs along ±y of every body
        return self.bodies[j], np.array([0.0, sign * (s - self.starts[j]), 0.0])

    def stiffness(self, s: float | np.ndarray) -> np.ndarray:
        """Static normal stiffness (N/m) at s (m) of this chain on its gauge (`chain_stiffness`)."""
        return chain_stiffness(s, self.starts[1:], self.hinge_stiffness, self.gauge_stiffness)
