"""The plant's contact forces from the contact list's whole arrays (`softcbf_mj.physics.plant_kernel.plate_contacts`)
are `mj_contactForce`'s, summed per facet in the contact list's order, bit for bit: through runs with several
contacts at once, frictional ones, the flexure's contact points, MuJoCo's pyramidal and elliptic cones, and a
contact's adhesion."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from softcbf_mj.physics.mjcf import ArmModelConfig, build_model
from softcbf_mj.physics.mujoco_plant import MujocoPlant


def reference_contacts(plant: MujocoPlant) -> tuple[list[float], list[float], list[list[float]]]:
    """Per facet, from `mj_contactForce` one contact at a time: the summed normal force, the norm of the summed
    tangential force (world frame) and the surface point of the strongest contact (NaN: none), in Python floats."""
    model, data, p = plant.model, plant.data, plant.n_facets
    roots = model.body_rootid[model.geom_bodyid].tolist()
    plates = {model.body(f"plate{k}").id: k - 1 for k in range(1, p + 1)}
    base = model.body("base").id
    normal, summed = [0.0] * p, [[0.0, 0.0, 0.0] for _ in range(p)]
    strongest, where = [0.0] * p, [[math.nan, math.nan] for _ in range(p)]
    force = np.zeros(6)
    for c in range(data.ncon):
        contact = data.contact[c]
        geom1, geom2 = int(contact.geom[0]), int(contact.geom[1])
        if plates.get(roots[geom1], -1) >= 0 and roots[geom2] == base:
            k, sign = plates[roots[geom1]], -1.0
        elif plates.get(roots[geom2], -1) >= 0 and roots[geom1] == base:
            k, sign = plates[roots[geom2]], 1.0
        else:
            continue
        mujoco.mj_contactForce(model, data, c, force)
        pressing, f1, f2 = force[:3].tolist()
        frame = contact.frame.tolist()
        normal[k] += pressing
        for j in range(3):
            summed[k][j] += f1 * frame[3 + j] + f2 * frame[6 + j]
        if pressing > strongest[k]:
            strongest[k] = pressing
            where[k] = [float(contact.pos[j]) + 0.5 * float(contact.dist) * (sign * frame[j]) for j in range(2)]
    return normal, [math.sqrt(x * x + y * y + z * z) for x, y, z in summed], where


def _plant(cone: str, **changes) -> MujocoPlant:
    model = build_model(ArmModelConfig(**changes))
    if cone == "elliptic":
        model.opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    return MujocoPlant(model)


@pytest.mark.parametrize("cone, changes", [
    ("pyramidal", {}),
    ("pyramidal", dict(plate="flexure", tip_friction=0.5)),
    ("elliptic", dict(plate="flexure", tip_friction=0.5)),
], ids=["ideal", "flexure-friction", "flexure-friction-elliptic"])
def test_the_contact_forces_are_mj_contact_forces(cone, changes):
    plant = _plant(cone, **changes)
    plant.reset(np.zeros(2))
    most, frictional, pressed = 0, 0.0, 0.0
    for k in range(600):
        u = np.array([150.0, 150.0]) if k < 350 else np.array([60.0, 150.0 - 0.2 * k])
        state = plant.step(u)
        normal, tangential, where = reference_contacts(plant)
        assert state.extras["force_solver_N"].tobytes() == np.array(normal).tobytes(), k
        assert state.extras["force_tangential_N"].tobytes() == np.array(tangential).tobytes(), k
        if plant.sheets:
            for facet, sheet in plant.sheets.items():
                point = np.array(where[facet])
                expected = float(sheet.along @ (point - sheet.origin)) if np.all(np.isfinite(point)) else math.nan
                assert np.array_equal(state.extras["contact_s_m"][facet], expected, equal_nan=True), k
        most, frictional, pressed = max(most, plant.data.ncon), max(frictional, *tangential), max(pressed, *normal)
    assert pressed > 0.1  # the run presses the plate
    if plant.sheets:
        assert most >= 2 and frictional > 0.0  # several contacts at once, with friction


def test_a_contacts_adhesion_is_taken_off_its_normal_force():
    """MuJoCo's net interface force (mj_contactForce subtracts the contact's adhesion): an adhesion written into
    the contact list moves the plant's normal force as it moves mj_contactForce's."""
    plant = _plant("pyramidal")
    plant.reset(np.zeros(2))
    for _ in range(400):
        plant.step(np.array([150.0, 150.0]))
        if plant.data.ncon:
            break
    assert plant.data.ncon
    without, _, _ = reference_contacts(plant)
    plant.data.contact.adhesion[:] = 0.125
    normal, _, _ = reference_contacts(plant)
    assert normal[0] == without[0] - 0.125 * plant.data.ncon  # MuJoCo took it off
    assert plant.state().extras["force_solver_N"].tobytes() == np.array(normal).tobytes()



@pytest.mark.parametrize("cone", ["pyramidal", "elliptic"])
def test_any_constraint_forces_of_several_contacts_give_mj_contact_forces(cone):
    """Both tangential directions and every pyramid edge: at a state with several frictional contacts, constraint
    forces drawn at random (the planar arm's own use only the second tangent) still give `mj_contactForce`'s sums."""
    plant = _plant(cone, plate="flexure", tip_friction=0.5)
    plant.reset(np.zeros(2))
    for _ in range(600):
        plant.step(np.array([150.0, 150.0]))
        if plant.data.ncon >= 2:
            break
    assert plant.data.ncon >= 2 and min(plant.data.contact.dim) == 3
    rng = np.random.default_rng(7)
    for _ in range(20):
        plant.data.efc_force[:] = rng.normal(0.0, 1.0, plant.data.nefc)
        normal, tangential, _ = reference_contacts(plant)
        state = plant.state()
        assert state.extras["force_solver_N"].tobytes() == np.array(normal).tobytes()
        assert state.extras["force_tangential_N"].tobytes() == np.array(tangential).tobytes()


def test_the_contact_kernel_loads_at_reset_before_any_contact():
    """A fresh process: the plant's reset away from the plate loads `plate_contacts` (numba: from its cache, or
    compiled), so a loop's first contact does not stall a real-time loop on it (tests/test_hardware_warm_up.py)."""
    import subprocess
    import sys

    script = ("import numpy as np\n"
              "from softcbf_mj.physics.mjcf import ArmModelConfig, build_model\n"
              "from softcbf_mj.physics.mujoco_plant import MujocoPlant\n"
              "from softcbf_mj.physics import plant_kernel\n"
              "plant = MujocoPlant(build_model(ArmModelConfig()))\n"
              "plant.reset(np.zeros(plant.n_segments))\n"
              "print(plant.data.ncon, len(plant_kernel.plate_contacts.signatures))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["0", "1"]
