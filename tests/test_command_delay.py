"""c-erg's certificate over a command delay interval (controllers.governors.energy_governor.certificate, "command delay"),
against brute force on the PCC model.

The brute force: a 10 Hz loop on the PCC plant (exact state at the call, the commands acting a TRUE delay after the
call, the same for every command), and at every command's true application tick the command is also held for
`HOLD_S` from the plant's state then (a fork): the tip stays in P (ρ ≥ 0) on the loop and on every fork. The arm is
the reference arm with a fifth of its damping and a fast valve (τ_p = 0.01 s): it swings under a step, so when a
command starts to act matters (with the reference damping no delay in [0, 0.3] s broke the single-delay
certificate). κ = 0 and a small ε: the exact state leaves the certificate no estimate error to cover, and nothing
but the certificate keeps the forks inside P. The companion test shows the single delay breaking at the
interval's end (so the first can fail).
"""

import copy
import math

import numpy as np
import pytest

from controllers.governors.energy_governor import ContactEnergyGovernor
from controllers.governors.energy_governor.box import read_box
from controllers.governors.energy_governor.parameters import MAX_DELAY_STATES, delay_states
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext
from softcbf_mj.physics.pcc_plant import PCCPlant

SAFE = paper_safe_set()
ROBOT = reference_robot()
SWINGING = ROBOT.replace(damping=tuple(ROBOT.array("damping") * 0.2))
TICK, PERIOD, TAU, HOLD_S, DURATION = 1e-3, 0.1, 0.01, 0.6, 2.0
DELAYS = (0.0, 0.1)
BASE = {"contact_aware": False, "kappa": 0.0, "energy_margin_J": 1e-7}
INTERVAL = {**BASE, "command_delay_lo_s": DELAYS[0], "command_delay_hi_s": DELAYS[1]}
BOX = "tests/data/delay_box.toml"


def u_nom(t: float) -> np.ndarray:
    """A sinusoid on both segments, 0–300 hPa, period 1 s."""
    return np.full(2, 150.0 + 150.0 * math.sin(2.0 * math.pi * t))


def context(robot=SWINGING, period=PERIOD, delay=0.0, tau=TAU) -> FilterContext:
    return FilterContext(robot, SAFE, robot.array("u_min"), robot.array("u_max"), period, delay, tau)


def least_margin(options: dict, true_delay: float) -> float:
    """The least ρ of the true tip over the loop and every fork (module docstring) for c-erg with `options`, each
    command acting `true_delay` s after its call."""
    gov = ContactEnergyGovernor(context(), **options)
    plant = PCCPlant(SWINGING, SAFE, control_dt=TICK, tau_p=TAU)
    state = plant.reset(np.zeros(2))
    per_call, delay_ticks = int(round(PERIOD / TICK)), int(round(true_delay / TICK))
    pending, acting, worst = [], np.zeros(2), math.inf
    for k in range(int(round(DURATION / TICK))):
        if k % per_call == 0:
            out = gov(Estimate(k * TICK, state.q, state.qd, k * TICK), u_nom(k * TICK))
            pending.append((k + delay_ticks, out.u))
        while pending and pending[0][0] <= k:
            acting = pending.pop(0)[1]
            fork = copy.deepcopy(plant)
            for _ in range(int(round(HOLD_S / TICK))):
                worst = min(worst, float(SAFE.margin(fork.step(acting).tip)))
        state = plant.step(acting)
        worst = min(worst, float(SAFE.margin(state.tip)))
    return worst


INTERIOR = tuple(float(d) for d in np.round(np.random.default_rng(5).uniform(*DELAYS, 2), 3))


@pytest.mark.parametrize("assumed", DELAYS)
@pytest.mark.parametrize("true_delay", DELAYS + INTERIOR)
def test_a_command_certified_for_the_delay_interval_holds_every_delay_in_it(true_delay, assumed):
    """Certified for delays [0, 0.1] s (recorded at either end), the loop and each command held from the state it
    truly acts from stay inside P, at both ends and at random interior delays."""
    assert least_margin({**INTERVAL, "command_delay_s": assumed}, true_delay) >= 0.0


def test_the_single_delay_breaks_at_the_interval_end():
    """The same forks certified for the delay 0.1 s alone: commands acting at once (delay 0) leave P (measured
    ρ −0.70; the test above can fail)."""
    assert least_margin({**BASE, "command_delay_s": DELAYS[1]}, DELAYS[0]) < 0.0


def test_a_zero_width_interval_is_the_single_delay_bit_for_bit():
    """lo = hi = δ: every call's command, action and diagnostics (but the wall time) are those of δ alone, on a
    contact push with the recommended setting's plate and gain intervals."""
    options = {"command_delay_s": 0.02, "stiffness_lo_ratio": 0.8, "stiffness_hi_ratio": 1.2, "gain_lo_ratio": 0.9,
               "gain_hi_ratio": 1.1, "actuator_tau_lo_s": 0.02, "actuator_tau_hi_s": 0.1}
    single = ContactEnergyGovernor(context(ROBOT, tau=0.05), **options)
    interval = ContactEnergyGovernor(context(ROBOT, tau=0.05), command_delay_lo_s=0.02, command_delay_hi_s=0.02,
                                     **options)
    assert interval.model.delay_shifts == (0.0,)
    plant = PCCPlant(ROBOT, SAFE, control_dt=TICK, tau_p=0.05)
    state, pending, acting = plant.reset(np.zeros(2)), [], np.zeros(2)
    for k in range(1500):
        if k % 20 == 0:
            estimate = Estimate(k * TICK, state.q, state.qd, k * TICK)
            a, b = single(estimate, np.full(2, 150.0)), interval(estimate, np.full(2, 150.0))
            np.testing.assert_array_equal(a.u, b.u)
            assert a.action == b.action
            drop = lambda d: {key: v for key, v in d.items() if key != "solve_us"}  # noqa: E731
            np.testing.assert_equal(drop(a.diagnostics), drop(b.diagnostics))
            pending.append((k + 20, a.u))
        while pending and pending[0][0] <= k:
            acting = pending.pop(0)[1]
        state = plant.step(acting)


def test_delay_states_cover_the_interval_at_most_the_spacing_apart():
    assert delay_states(0.02, 0.02, 0.01) == (0.02,)
    assert delay_states(0.0, 0.02, 0.01) == (0.0, 0.01, 0.02)
    states = delay_states(0.0, 0.1, 0.03)
    assert states[0] == 0.0 and states[-1] == 0.1 and len(states) == 5
    assert max(np.diff(states)) <= 0.03


@pytest.mark.parametrize("arguments, message", [
    ({"command_delay_lo_s": 0.02, "command_delay_hi_s": 0.01},
     "command_delay_lo_s must be <= command_delay_hi_s = 0.01, got 0.02"),
    ({"command_delay_lo_s": -0.01}, "command_delay_lo_s must be in"),
    ({"command_delay_lo_s": 0.0, "command_delay_hi_s": 0.5, "command_delay_spacing_s": 0.01},
     f"command_delay_spacing_s must be >= \\(command_delay_hi_s - command_delay_lo_s\\)/{MAX_DELAY_STATES - 1}"),
    ({"command_delay_spacing_s": 0.0}, "command_delay_spacing_s must be in"),
])
def test_delay_parameters_are_checked(arguments, message):
    with pytest.raises(ValueError, match=message):
        ContactEnergyGovernor.check_arguments(arguments)


def test_one_end_given_crosses_the_assumed_delay():
    """hi alone below the assumed δ (lo = δ): refused at construction with the assumed delay named."""
    with pytest.raises(ValueError, match=r"command_delay_lo_s must be <= command_delay_hi_s = 0.01 \(None: the assumed "
                                         r"delay 0.02 s\), got 0.02"):
        ContactEnergyGovernor(context(ROBOT, delay=0.02, tau=0.05), command_delay_hi_s=0.01)


def test_the_box_states_the_delay_interval_once():
    """A box file's `vary.command_delay` is the certified delay interval (controllers.governors.energy_governor.box)."""
    assert read_box(BOX) == pytest.approx({"stiffness_lo_ratio": 0.8, "stiffness_hi_ratio": 1.2,
                                           "actuator_tau_lo_s": 0.02, "actuator_tau_hi_s": 0.1,
                                           "command_delay_lo_s": 0.0, "command_delay_hi_s": 0.02})
    gov = ContactEnergyGovernor(context(ROBOT, tau=0.05), box=BOX)
    assert gov.model.delay_shifts == (0.0, 0.01, 0.02)
    with pytest.raises(ValueError, match="command_delay_hi_s is set by box"):
        ContactEnergyGovernor.check_arguments({"box": BOX, "command_delay_hi_s": 0.05})


def test_batched_rows_are_the_governors_called_in_turn_over_a_delay_interval():
    """filter_batch with a delay interval: row b is, bit for bit, a governor of its own called alone (the covering
    rows of every state go through one kernel call)."""
    from controllers.contract.safety_filter import EstimateBatch

    options = {"command_delay_lo_s": 0.0, "command_delay_hi_s": 0.02, "gain_lo_ratio": 0.9, "gain_hi_ratio": 1.1}
    ctx = context(ROBOT, period=0.02, tau=0.05)
    batched = ContactEnergyGovernor(ctx, **options)
    serial = [ContactEnergyGovernor(ctx, **options) for _ in range(3)]
    rng = np.random.default_rng(3)
    for k in range(40):
        q, qd = rng.uniform(0.0, 0.5, (3, 2)), rng.uniform(-1.0, 1.0, (3, 2))
        u_nom = rng.uniform(0.0, 300.0, (3, 2))
        t = np.full(3, 0.02 * k)
        out = batched.filter_batch(EstimateBatch(t, q, qd, t), u_nom)
        for b, gov in enumerate(serial):
            alone = gov(Estimate(t[b], q[b], qd[b], t[b]), u_nom[b])
            np.testing.assert_array_equal(out.u[b], alone.u)
            assert out.action[b] == alone.action
