"""The energy governor's parameters: one frozen, typed declaration, validated once.

Each parameter is one field of `GovernorParams` (e-erg): its type, its default and its declaration
(`controllers.contract.filter_parameters.FilterParameter`: meaning, unit, kind, valid range), so that `PARAMETERS`,
the filters' signatures and `parameter_docs` are all derived from the fields. `ContactGovernorParams` (c-erg)
is the same declaration with the contact certificate's defaults (`certificate` "contact", `contact_aware`
true); the c-erg filter takes neither `certificate` nor `margin_m` (the parked target's margin).

Validation happens once, at construction (`__post_init__`): every field by its declaration (an int given for
a float becomes one), then the rules between fields. What needs the filter's context (the context's delay and
time constant, the table's size, ε against the table) is checked when the model is built
(`controllers.governors.energy_governor.certificate.GovernorModel.build`).

Computational bounds: command_delay_s (and its interval's ends) ≤ MAX_COMMAND_DELAY_S keeps a prediction within the horizon
(δ = 100 s took 2 s per call: 10⁵ integration steps); predictor_step_s ≥ 1e-4 s caps a prediction at
PREDICTION_HORIZON_S/1e-4 = 2·10⁴ steps; bisection_steps ≤ 52; a delay interval's covering set ≤ MAX_DELAY_STATES delays (each one prediction); grid_hPa's table ≤ MAX_TABLE_COMMANDS commands
(1e-6 hPa asked for 639 PiB). Physical ones: κ ≥ 0 (an inflation; ≤ 1000: beyond, it is no estimate error),
ε ≥ 0 and below the table's saturation ½ k_min reach² (`EscapeEnergyTable.saturation_J`, 0.72 J on the
reference arm: a larger ε certifies no step at all), the stiffness ratios
0 ≤ lo ≤ hi, 1e-3 ≤ hi ≤ 1e3, the gain ratios 0.1 ≤ lo ≤ hi ≤ 10 (other than 1 only with the contact
certificate), τ_p ≤ 10 s; the gain estimate's Δ in (0, 1] rad (0 would trust a perfect model), |q̇| ≤ 10 rad/s
for a rest sample, a clearance ≤ 1 m, and estimates ≤ 0.1 s apart for a difference (beyond, no acceleration);
a rest window ≤ 10 s and its risk in [1e-9, 0.5] (below 1e-9 the t tail's round-off, `student_t_quantile`).
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, field, fields

from controllers.core.bounds import Bound
from controllers.governors.energy_governor.box import STANDARD_BOX, read_box
from controllers.contract.filter_parameters import FilterParameter
from controllers.governors.gain_estimate import GAIN_CONTACT
from controllers.governors.quasi_static_governor import PARAMETERS as QSG_PARAMETERS

PREDICTION_HORIZON_S = 2.0
"""The state predictor's horizon (s): an estimate whose prediction span t_a − t_c exceeds it is "stale"."""

MAX_COMMAND_DELAY_S = 0.5 * PREDICTION_HORIZON_S
"""Largest command delay δ (s): half the horizon, so an estimate up to that old can still be predicted."""

STIFFNESS_RATIOS = Bound(0.0, 1e3)
"""Valid plate stiffness ratios (1): a multiple of the model's ψ; hi must also be ≥ 1e-3 (P then grows 1000-fold)."""

GAIN_RATIOS = Bound(0.1, 10.0)
"""Valid actuator gain ratios (1): the true λ as a multiple of the model's; below 0.1 or above 10 the model is no model."""

PLATE_OFFSETS = Bound(-0.05, 0.05, unit="m")
"""Valid plate offsets (m) along a facet's outward normal: within 5 cm of the model's plate (beyond, no model)."""

MAX_DELAY_STATES = 11
"""Most delays the certificate is evaluated at per call over a command delay interval (each one prediction and one
certificate row: the call's cost grows with them)."""

CERTIFICATES = ("park", "contact")
"""The `certificate` values (the parked target, and the contact certificate: `controllers.governors.energy_governor.certificate`)."""


def declared(default: object, meaning: str, unit: str, kind: type = float, bound: Bound | None = None,
             optional: bool = False):
    """A parameter field: its default and its declaration (`FilterParameter`) in the field's metadata."""
    return field(default=default, metadata={"parameter": FilterParameter(meaning, unit, kind, bound, optional)})


@dataclass(frozen=True)
class GovernorParams:
    """The e-erg's parameters (module docstring); the fields' declarations are `PARAMETERS`."""

    margin_m: float = declared(5e-3, "rest-shape tip margin of the target (quasi-static governor) inside P", "m",
                               bound=QSG_PARAMETERS["margin_m"].bound)
    kappa: float = declared(0.5, "relative inflation of the certified energy against estimate/prediction errors", "1",
                            bound=Bound(0.0, 1e3))
    energy_margin_J: float = declared(1e-5, "absolute certificate margin ε; below ½ k_min (1.2 rad)², the escape "
                                      "energy the table resolves (checked at construction)", "J",
                                      bound=Bound(0.0, unit="J"))
    contact_aware: bool = declared(False, "credit the plate's stored energy at the boundary (the plate pushes back)",
                                   "", bool)
    stiffness_lo_ratio: float = declared(1.0, "lowest true plate stiffness as a multiple of the model's ψ (<= hi)", "1",
                                         bound=STIFFNESS_RATIOS)
    stiffness_hi_ratio: float = declared(1.0, "highest true plate stiffness as a multiple of the model's ψ "
                                         "(n_max = ψ⁻¹(F_max/hi))", "1", bound=Bound(1e-3, 1e3))
    command_delay_s: float | None = declared(None, "call → command acting at the valves (None: the context's, "
                                             "unknown = 0)", "s", bound=Bound(0.0, MAX_COMMAND_DELAY_S, unit="s"),
                                             optional=True)
    command_delay_lo_s: float | None = declared(None, "shortest true command delay (<= command_delay_hi_s; None: "
                                                "command_delay_s): the command is certified at the state it acts from "
                                                "for every delay in [lo, hi] (controllers.governors.energy_governor.certificate, "
                                                "\"command delay\")", "s", bound=Bound(0.0, MAX_COMMAND_DELAY_S, unit="s"),
                                                optional=True)
    command_delay_hi_s: float | None = declared(None, "longest true command delay (>= command_delay_lo_s; None: "
                                                "command_delay_s)", "s", bound=Bound(0.0, MAX_COMMAND_DELAY_S, unit="s"),
                                                optional=True)
    command_delay_spacing_s: float = declared(0.01, "largest spacing of the delays the certificate is evaluated at "
                                              "over [command_delay_lo_s, command_delay_hi_s] (its ends always; at most "
                                              f"{MAX_DELAY_STATES} delays, each one prediction per call)", "s",
                                              bound=Bound(1e-3, MAX_COMMAND_DELAY_S, unit="s"))
    actuator_tau_s: float | None = declared(None, "valve pressure time constant τ_p (None: the context's, unknown = 0)",
                                            "s", bound=Bound(0.0, 10.0, unit="s"), optional=True)
    grid_hPa: float = declared(2.5, "command spacing of the escape-energy table; at most "
                               "controllers.energy.escape_energy.MAX_TABLE_COMMANDS commands over the box "
                               "(checked at construction)", "hPa", bound=Bound(0.0, low_open=True, unit="hPa"))
    predictor_step_s: float = declared(1e-3, "largest integration step of the state predictor", "s",
                                       bound=Bound(1e-4, 1e-2, unit="s"))
    bisection_steps: int = declared(12, "halvings of the step towards the target (beyond 52 a double's σ stops "
                                    "changing)", "1", int, Bound(1, 52))
    certificate: str = declared("park", "'park' (the target parks margin_m inside P, Γ over the unsafe set) or "
                                "'contact' (the target is u_nom, Γ to P's boundary, the plate's energy counted per "
                                "facet, κ on the kinetic energy: module docstring)", "", str)
    escape_spacing_rad: float = declared(4e-3, "q-space spacing of the escape-energy table (per √k_i); finer: a "
                                         "tighter Γ̲ near P's boundary, a slower build (2.4 s at 4e-3, 6.7 s at 2e-3 on "
                                         "the reference arm)", "rad", bound=Bound(5e-4, 0.05, unit="rad"))
    gain_lo_ratio: float = declared(1.0, "lowest true actuator gain λ as a multiple of the model's (every segment "
                                    "alike; <= gain_hi_ratio; contact certificate only)", "1", bound=GAIN_RATIOS)
    gain_hi_ratio: float = declared(1.0, "highest true actuator gain λ as a multiple of the model's (the contact "
                                    "certificate holds for every gain in [lo, hi]: module docstring)", "1",
                                    bound=GAIN_RATIOS)
    gain_estimate: bool = declared(False, "narrow [gain_lo_ratio, gain_hi_ratio] online to [ĝ − e, ĝ + e] from rest "
                                   "samples (in contact too: gain_contact) (controllers.governors.gain_estimate; contact "
                                   "certificate only)", "", bool)
    gain_noise_rad: float = declared(5e-3, "bound Δ on the rest samples' deviation from the model's balance per "
                                     "segment (estimate error and residual motion; gain_estimate only)", "rad",
                                     bound=Bound(0.0, 1.0, low_open=True, unit="rad"))
    gain_rest_rad_s: float = declared(0.02, "largest |q̇_i| of a rest sample (gain_estimate only)", "rad/s",
                                      bound=Bound(0.0, 10.0, unit="rad/s"))
    gain_rest_s: float = declared(0.0, "how long every estimate must have been at rest (|q̇_i| <= gain_rest_rad_s) "
                                  "before a rest sample is taken, and between two rest samples: the arm settled, not "
                                  "passing through q̇ = 0 (0: every estimate at rest; gain_estimate only)", "s",
                                  bound=Bound(0.0, 10.0, unit="s"))
    gain_clearance_m: float = declared(5e-3, "least distance of a sample's tip from every facet plane for no contact "
                                       "(nearer: gain_contact; gain_estimate only)", "m", bound=Bound(0.0, 1.0, unit="m"))
    gain_difference_s: float = declared(0.0, "largest spacing of two estimates whose q̇ difference gives q̈ for a "
                                        "moving sample (0: rest samples only; gain_estimate only)", "s",
                                        bound=Bound(0.0, 0.1, unit="s"))
    gain_window_s: float = declared(0.0, "a rest sample is the mean of the estimates over a window this long, the "
                                    "window at rest when its fitted slope |β_i| <= gain_rest_rad_s, trusted to "
                                    "gain_noise_rad + the mean's noise bound from the windows' pooled scatter "
                                    "(controllers.governors.gain_estimate, \"averaged frames\": a noisy camera; 0: one "
                                    "estimate per sample, its q̂̇ tested; gain_estimate only)", "s",
                                    bound=Bound(0.0, 10.0, unit="s"))
    gain_scatter_risk: float = declared(1e-6, "probability per segment and window sample that the mean's camera "
                                        "noise exceeds its scatter bound (Student's t of the pooled scatter; a "
                                        "statistical bound, not a worst case; gain_window_s > 0 only)", "1",
                                        bound=Bound(1e-9, 0.5))
    gain_frame_sigma_rad: float | None = declared(None, "the camera's calibrated frame noise σ per segment (softcbf "
                                                  "calibrate-camera): a window sample's mean is trusted to "
                                                  "gain_noise_rad + z σ/√n (None: the pooled scatter's Student t; "
                                                  "gain_window_s > 0 only)", "rad",
                                                  bound=Bound(0.0, 1.0, low_open=True, unit="rad"), optional=True)
    plate_offset_lo_m: float = declared(0.0, "nearest true plate: its facets' least offset along their outward "
                                        "normal from the model's (< 0: nearer the arm; P is built on the nearest "
                                        "plate; contact certificate only: controllers.governors.energy_governor.plate_certificate, "
                                        "\"plate offset\")", "m", bound=PLATE_OFFSETS)
    plate_offset_hi_m: float = declared(0.0, "farthest true plate: its facets' greatest offset along their outward "
                                        "normal from the model's (>= plate_offset_lo_m)", "m", bound=PLATE_OFFSETS)
    stiffness_by_position: bool = declared(False, "the plate's stiffness varies with where it is touched (a clamped "
                                           "sheet, stiffer nearer its clamp: controllers.governors.energy_governor."
                                           "plate_certificate, \"sheet\"; [stiffness_lo_ratio, stiffness_hi_ratio] then bounds it over "
                                           "the contact positions, e.g. cantilever_stiffness_ratios); contact "
                                           "certificate only", "", bool)
    arm_stiffness_lo_ratio: float = declared(1.0, "lowest true arm stiffness K as a multiple of the model's (every "
                                             "segment alike; with the gain it moves every rest shape, q_u ∝ g/c: "
                                             "controllers.governors.energy_governor.certificate, \"arm stiffness\"; contact "
                                             "certificate only)", "1", bound=GAIN_RATIOS)
    arm_stiffness_hi_ratio: float = declared(1.0, "highest true arm stiffness K as a multiple of the model's "
                                             "(>= arm_stiffness_lo_ratio)", "1", bound=GAIN_RATIOS)
    damping_lo_ratio: float = declared(1.0, "lowest true arm damping D as a multiple of the model's (the valve "
                                       "lag's energy weight β ∝ 1/d; any damping above it is covered; contact "
                                       "certificate only)", "1", bound=GAIN_RATIOS)
    actuator_tau_hi_s: float | None = declared(None, "slowest true valve lag τ_p (the energy weight β ∝ τ_p and the "
                                               "pressure's interval; None: actuator_tau_s alone; contact certificate "
                                               "only: controllers.governors.energy_governor.certificate, \"valve lag\")", "s",
                                               bound=Bound(0.0, 10.0, unit="s"), optional=True)
    actuator_tau_lo_s: float | None = declared(None, "fastest true valve lag τ_p (<= actuator_tau_hi_s; None: "
                                               "actuator_tau_s)", "s", bound=Bound(0.0, 10.0, unit="s"), optional=True)
    box: str = declared("", "a study file (TOML) whose [vary] box sets the certified intervals, the box the "
                        "falsifier searches (controllers.governors.energy_governor.box; '' none; an interval given as well "
                        "is refused)", "", str)
    gain_contact: str = declared("normal", "samples with the tip within gain_clearance_m of a facet: 'normal' (the "
                                 "plate's force along its normal eliminated: frictionless), 'any' (also the "
                                 "tangential: friction), 'off' (none; controllers.governors.gain_estimate; gain_estimate only)",
                                 "", str)

    plate_estimate: bool = declared(False, "learn the plate online: each rest sample in contact with one facet "
                                    "bounds its normal force (the arm as its own force sensor) and penetration, and "
                                    "the certified set of (stiffness, offset) narrows P's boundary and the plate terms "
                                    "(controllers.governors.energy_governor.plate_estimate; needs gain_estimate with "
                                    "gain_contact 'normal', contact_aware, a linear plate law, no stiffness_by_position)",
                                    "", bool)

    def __post_init__(self) -> None:
        for f in fields(self):  # each by its declaration, normalised (an int given for a float becomes one)
            object.__setattr__(self, f.name, f.metadata["parameter"].check(f.name, getattr(self, f.name)))
        if self.box:  # the box's intervals (controllers.governors.energy_governor.box), each checked by its declaration
            for name, value in read_box(self.box).items():
                default = type(self).__dataclass_fields__[name].default
                if getattr(self, name) != default:
                    raise ValueError(f"{name} is set by box = {self.box!r} and given as {getattr(self, name)!r}: "
                                     f"give one of them")
                object.__setattr__(self, name, type(self).__dataclass_fields__[name].metadata["parameter"].check(name, value))
        if self.certificate not in CERTIFICATES:
            raise ValueError(f"certificate must be one of {', '.join(CERTIFICATES)}, got {self.certificate!r}")
        if self.stiffness_lo_ratio > self.stiffness_hi_ratio:
            raise ValueError(f"stiffness_lo_ratio must be <= stiffness_hi_ratio = {self.stiffness_hi_ratio!r}, "
                             f"got {self.stiffness_lo_ratio!r}")
        lo, hi = self.gain_lo_ratio, self.gain_hi_ratio
        if lo > hi:
            raise ValueError(f"gain_lo_ratio must be <= gain_hi_ratio = {hi!r}, got {lo!r}")
        if (lo, hi) != (1.0, 1.0) and self.certificate != "contact":
            raise ValueError(f"gain_lo_ratio and gain_hi_ratio other than 1 need certificate='contact' (the parked "
                             f"target's rest shape assumes the model's gain), got [{lo!r}, {hi!r}]")
        for name, (lo, hi), neutral in (("plate_offset", (self.plate_offset_lo_m, self.plate_offset_hi_m), (0.0, 0.0)),
                                        ("arm_stiffness", (self.arm_stiffness_lo_ratio, self.arm_stiffness_hi_ratio),
                                         (1.0, 1.0))):
            unit = "_m" if name == "plate_offset" else "_ratio"
            if lo > hi:
                raise ValueError(f"{name}_lo{unit} must be <= {name}_hi{unit} = {hi!r}, got {lo!r}")
            if (lo, hi) != neutral and self.certificate != "contact":
                raise ValueError(f"{name}_lo{unit} and {name}_hi{unit} other than {neutral[0]:g} need "
                                 f"certificate='contact', got [{lo!r}, {hi!r}]")
        if self.stiffness_by_position and not (self.certificate == "contact" and self.contact_aware):
            raise ValueError("stiffness_by_position needs certificate='contact' with contact_aware (it changes the "
                             "plate's energy credit)")
        if self.damping_lo_ratio != 1.0 and self.certificate != "contact":
            raise ValueError(f"damping_lo_ratio other than 1 needs certificate='contact', got {self.damping_lo_ratio!r}")
        taus = (self.actuator_tau_lo_s, self.actuator_tau_hi_s)
        if taus != (None, None):
            if self.certificate != "contact":
                raise ValueError(f"actuator_tau_lo_s and actuator_tau_hi_s need certificate='contact', got {list(taus)}")
            if None not in taus and taus[0] > taus[1]:
                raise ValueError(f"actuator_tau_lo_s must be <= actuator_tau_hi_s = {taus[1]!r}, got {taus[0]!r}")
        delays = (self.command_delay_lo_s, self.command_delay_hi_s)
        if None not in delays and delays[0] > delays[1]:
            raise ValueError(f"command_delay_lo_s must be <= command_delay_hi_s = {delays[1]!r}, got {delays[0]!r}")
        if None not in delays and len(delay_states(*delays, self.command_delay_spacing_s)) > MAX_DELAY_STATES:
            raise ValueError(f"command_delay_spacing_s must be >= (command_delay_hi_s - command_delay_lo_s)/"
                             f"{MAX_DELAY_STATES - 1} = {(delays[1] - delays[0]) / (MAX_DELAY_STATES - 1):.6g} s (at most "
                             f"{MAX_DELAY_STATES} delays per call), got {self.command_delay_spacing_s!r}")
        if self.gain_difference_s > 0.0 and (self.arm_stiffness_lo_ratio, self.arm_stiffness_hi_ratio,
                                             self.damping_lo_ratio) != (1.0, 1.0, 1.0):
            raise ValueError(f"gain_difference_s must be 0 with an arm stiffness or damping interval (a moving "
                             f"sample's M q̈ and D q̇ then scale unlike K), got {self.gain_difference_s!r}")
        if self.gain_window_s > 0.0 and self.gain_difference_s > 0.0:
            raise ValueError(f"gain_window_s and gain_difference_s exclude each other (a window sample averages "
                             f"frames at rest, a difference sample differentiates two), got {self.gain_window_s!r} "
                             f"and {self.gain_difference_s!r}")
        if self.gain_contact not in GAIN_CONTACT:
            raise ValueError(f"gain_contact must be one of {', '.join(GAIN_CONTACT)}, got {self.gain_contact!r}")
        if self.plate_estimate and not (self.gain_estimate and self.gain_contact == "normal" and self.contact_aware
                                        and not self.stiffness_by_position):
            raise ValueError("plate_estimate needs gain_estimate with gain_contact='normal' and contact_aware, without "
                             "stiffness_by_position (a linear, frictionless plate: controllers.governors.energy_governor."
                             "plate_estimate)")
        if self.gain_estimate and self.certificate != "contact":
            raise ValueError("gain_estimate needs certificate='contact' (the certificate that covers a gain interval)")

    @property
    def contact(self) -> bool:
        """Whether the contact certificate is in use (`certificate` "contact")."""
        return self.certificate == "contact"


def delay_states(lo: float, hi: float, spacing: float) -> tuple[float, ...]:
    """The delays (s) the certificate is evaluated at over [lo, hi]: both ends and the fewest equally spaced ones
    between them at most `spacing` apart (lo alone when lo = hi; controllers.governors.energy_governor.certificate,
    "command delay")."""
    if lo == hi:
        return (lo,)
    intervals = max(1, math.ceil((hi - lo) / spacing - 1e-9))
    return tuple(lo + (hi - lo) * i / intervals for i in range(intervals)) + (hi,)


def contact_default(name: str, default: object):
    """GovernorParams' field `name` with another default (its declaration kept)."""
    return field(default=default, metadata=GovernorParams.__dataclass_fields__[name].metadata)


@dataclass(frozen=True)
class ContactGovernorParams(GovernorParams):
    """The c-erg's parameters: `GovernorParams` with the contact certificate, the plate's energy credited."""

    contact_aware: bool = contact_default("contact_aware", True)
    certificate: str = contact_default("certificate", "contact")


PARAMETERS = {f.name: f.metadata["parameter"] for f in fields(GovernorParams)}
"""The e-erg's parameters, declared once (the fields of `GovernorParams`): `check_arguments` and the constructor check them."""

CONTACT_FIXED = ("margin_m", "certificate")
"""The parameters the c-erg does not take: its certificate is the contact one, whose target is u_nom itself."""


def parameter_signature(params_type: type, excluded: tuple[str, ...] = ()) -> inspect.Signature:
    """The filter constructor's signature `(context, *, name: kind = default, ...)` from the declaration, in its
    order, without `excluded` (what `controllers.registry` reads: names, defaults and kinds)."""
    out = [inspect.Parameter("context", inspect.Parameter.POSITIONAL_OR_KEYWORD)]
    for f in fields(params_type):
        if f.name not in excluded:
            out.append(inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default,
                                         annotation=parameter_kind(f.metadata["parameter"])))
    return inspect.Signature(out)


def parameter_kind(parameter: FilterParameter) -> object:
    """A declaration's Python type: its kind, or kind | None where None is allowed."""
    return parameter.kind | None if parameter.optional else parameter.kind


RECOMMENDED = {"gain_lo_ratio": 0.9, "gain_hi_ratio": 1.1, "gain_estimate": True, "gain_noise_rad": 0.0015,
               "gain_rest_rad_s": 0.003, "gain_rest_s": 0.2, "energy_margin_J": 2e-6}
"""c-erg's recommended setting for contact tasks (README; `ContactEnergyGovernor`'s first docstring line names it,
`softcbf list` marks it): the actuator gain interval [0.9, 1.1] narrowed online by samples at rest for 0.2 s,
trusted to Δ = 1.5e-3 rad, and ε = 2e-6 J (docs/results.md#the-recommended-filter-over-the-full-battery)."""

STANDARD_BOX_SETTING = {**RECOMMENDED, **STANDARD_BOX}
"""The recommended setting certified over the standard error box's physical errors (`box.STANDARD_BOX`): the preset
`c-erg:standard-box` (docs/beyond-the-paper.md: what it holds and what it delivers)."""

LEARN_PLATE_SETTING = {**STANDARD_BOX_SETTING, "plate_estimate": True, "gain_noise_rad": 1e-4}
"""The standard-box setting learning the plate online (`plate_estimate`) on a plant whose state is exact to
Δ = 1e-4 rad (mujoco_contact at 1 kHz, or a lab's motion capture): the preset `c-erg:learn-plate`. A camera's Δ
(1.5e-3 rad) reads the contact force too loosely to learn anything (docs/beyond-the-paper.md)."""
