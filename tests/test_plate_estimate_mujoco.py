"""The plate learned online on the MuJoCo plant (controllers.governors.energy_governor.plate_estimate): a short closed loop.

c-erg over the standard box with `plate_estimate` on mujoco_contact (1 kHz, exact rod state, Δ = 1e-4 rad: the rod's
measured deviation from the PCC balance at rest against the plate is ≈ 3e-6 rad), the 150 hPa push for 4 s at the
box's worst corner (plate 20 % stiffer and 2 mm nearer, gain × 1.1, arm × 0.9, damping × 0.7, τ_p 0.02 s): the
measured margin stays > 0 while the certified plates narrow and stay around the true one.
"""

import json

import numpy as np
import pytest


@pytest.mark.slow
def test_a_mujoco_push_at_the_box_corner_learns_the_plate_and_holds(tmp_path):
    from scenarios import get
    from softcbf_mj.outputs.runio import load_timeseries

    get("mujoco_contact").run(tmp_path, duration=4.0, filter="c-erg:standard-box",
                              filter_params={"plate_estimate": True, "gain_noise_rad": 1e-4},
                              nominal="step", nominal_params="seed=0;low_hPa=150;high_hPa=150", true_gain_scale=1.1,
                              true_stiffness_scale=0.9, true_damping_scale=0.7, tau_p=0.02, plate_stiffness=13.392,
                              facet_offset=-0.002, progress=False)
    run = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))["runs"][0]
    series = load_timeseries(tmp_path / run["timeseries"])[0]
    assert run["rho_min_meas"] > 0.0 and run["t_violation_s"] == 0.0
    lo, hi = series["plate_lo"], series["plate_hi"]
    offset_lo, offset_hi = series["plate_offset_lo_m"], series["plate_offset_hi_m"]
    assert np.all(lo <= 1.2) and np.all(hi >= 1.2)  # the true plate (1.2, −2 mm) stays in the hull
    assert np.all(offset_lo <= -0.002) and np.all(offset_hi >= -0.002)
    assert lo[-1] > 0.8 and offset_hi[-1] < 0.002  # and the hull narrowed
