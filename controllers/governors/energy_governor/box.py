"""One box for the falsifier and the filter: c-erg's certified intervals from a study file's error box.

A study file (`softcbf study`, docs/studies.md; e.g. studies/mismatch_box_contact.toml) states a lab's uncertainty as
`[vary.NAME]` tables (dist "uniform" with low and high, or "choice" with values) over the scenario's mismatch
parameters; the falsifier searches that box. `box_parameters(study)` turns the same tables into the contact
certificate's intervals (`controllers.governors.energy_governor.certificate`), so a lab states its uncertainty once:

| the box's `vary` name | unit | c-erg's parameters |
|---|---|---|
| plate_stiffness | N/m | stiffness_lo_ratio, stiffness_hi_ratio = low, high / [fixed] assumed_plate_stiffness |
| facet_offset | m | plate_offset_lo_m, plate_offset_hi_m |
| true_gain_scale | 1 | gain_lo_ratio, gain_hi_ratio |
| true_stiffness_scale | 1 | arm_stiffness_lo_ratio, arm_stiffness_hi_ratio |
| true_damping_scale | 1 | damping_lo_ratio (= low: any damping above it is covered) |
| tau_p | s | actuator_tau_lo_s, actuator_tau_hi_s |
| command_delay | s | command_delay_lo_s, command_delay_hi_s |

(command_delay, the time from the filter's call to the command acting at the valves, is simulated in whole
control periods (the ground truth's `command_delay`), so a box that a study can search states it as "choice" of
such delays, e.g. tests/data/delay_box.toml; the certificate reads the least and greatest.)

A name the certificate leaves to its estimate margins (κ and the gain estimate's Δ: `SENSING`, the camera's
latency, pixel noise and dropped frames) is passed over; any other name is refused (an error the certificate does
not cover, e.g. facet_angle, must not be read as certified). Reading the file (`read_box`) uses tomllib; nothing
here imports MuJoCo or the scenarios.

`STANDARD_BOX` is the standard box's physical errors (docs/studies.md; studies/mismatch_box_contact.toml, whose reading
tests/test_certificate_box.py checks against it) as c-erg's intervals, stated here as numbers so that the preset
`c-erg:standard-box` (`parameters.STANDARD_BOX_SETTING`: the recommended setting over this box) needs no file at run time.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path

INTERVALS = {"facet_offset": ("plate_offset_lo_m", "plate_offset_hi_m"),
             "true_gain_scale": ("gain_lo_ratio", "gain_hi_ratio"),
             "true_stiffness_scale": ("arm_stiffness_lo_ratio", "arm_stiffness_hi_ratio"),
             "tau_p": ("actuator_tau_lo_s", "actuator_tau_hi_s"),
             "command_delay": ("command_delay_lo_s", "command_delay_hi_s")}
"""The box's names whose interval [low, high] is a pair of c-erg parameters as it stands (module docstring)."""

SENSING = ("latency", "pixel_noise", "drop_rate", "saved_frames_hz", "seed")
"""The box's names the certificate leaves to its estimate margins (κ, Δ): passed over."""

STANDARD_BOX = {"stiffness_lo_ratio": 0.8, "stiffness_hi_ratio": 1.2, "plate_offset_lo_m": -0.002,
                "plate_offset_hi_m": 0.002, "gain_lo_ratio": 0.9, "gain_hi_ratio": 1.1, "arm_stiffness_lo_ratio": 0.9,
                "arm_stiffness_hi_ratio": 1.1, "damping_lo_ratio": 0.7, "actuator_tau_lo_s": 0.02,
                "actuator_tau_hi_s": 0.1}
"""The standard box's physical errors as c-erg's intervals (module docstring): plate stiffness ±20 %, offset ±2 mm,
actuator gain and arm stiffness ±10 %, damping from 0.7 of the model's, valve lag 0.02–0.1 s."""


def interval(name: str, table: Mapping) -> tuple[float, float]:
    """[low, high] of a `[vary.NAME]` table: "uniform" (low, high) or "choice" (the least and greatest value)."""
    dist = table.get("dist")
    if dist == "uniform":
        low, high = float(table["low"]), float(table["high"])
    elif dist == "choice":
        values = [float(v) for v in table["values"]]
        low, high = min(values), max(values)
    else:
        raise ValueError(f"vary.{name}: c-erg certifies a bounded interval (dist 'uniform' or 'choice'), got dist = {dist!r}")
    if not low <= high:
        raise ValueError(f"vary.{name}: low must be <= high = {high!r}, got {low!r}")
    return low, high


def box_parameters(study: Mapping) -> dict[str, float]:
    """c-erg's interval parameters (module docstring's table) from a parsed study file `study` (its `vary` and
    `fixed` tables); ValueError for a name it does not certify or an unbounded distribution."""
    vary, fixed = study.get("vary", {}), study.get("fixed", {})
    out: dict[str, float] = {}
    for name, table in vary.items():
        if name in SENSING:
            continue
        low, high = interval(name, table)
        if name in INTERVALS:
            out.update(zip(INTERVALS[name], (low, high)))
        elif name == "plate_stiffness":
            if "assumed_plate_stiffness" not in fixed:
                raise ValueError("vary.plate_stiffness is in N/m: the box's [fixed] table needs assumed_plate_stiffness "
                                 "(the controller's ψ, N/m) to make it a ratio")
            assumed = float(fixed["assumed_plate_stiffness"])
            out.update(stiffness_lo_ratio=low / assumed, stiffness_hi_ratio=high / assumed)
        elif name == "true_damping_scale":
            out["damping_lo_ratio"] = low
        else:
            raise ValueError(f"the box varies {name}, which c-erg does not certify (it certifies "
                             f"{', '.join(sorted([*INTERVALS, 'plate_stiffness', 'true_damping_scale']))}; "
                             f"{', '.join(SENSING)} are left to κ and Δ)")
    return out


def read_box(path: str | Path) -> dict[str, float]:
    """`box_parameters` of the study file at `path` (TOML); ValueError naming the file if it cannot be read."""
    try:
        with open(path, "rb") as handle:
            study = tomllib.load(handle)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"box = {str(path)!r}: cannot read it as a study file ({exc})") from exc
    try:
        return box_parameters(study)
    except ValueError as exc:
        raise ValueError(f"box = {str(path)!r}: {exc}") from exc
