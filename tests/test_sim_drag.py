"""``slung sim``'s plant feels the vehicle file's still-air drag as the emulator's does (SIH_KDV, SIH_KDW), and the
compiled sweep engine flies the same drag as the scalar one (``tests/test_sweep.py``)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from estimators.model.vehicle import Vehicle
from offboard.control import reference_patterns as patterns
from offboard.control import smc
from offboard.harness import sim
from offboard.logs.runlog import PlantSetup
from sim_bridge.plant import dynamics


def test_unpowered_vehicle_slows_and_stops_turning_as_its_drag_says() -> None:
    """Motors off, no load, 20 m up at 3 m/s north and 2 rad/s of roll: the horizontal velocity decays as
    exp(-k t / M) and the roll rate as exp(-k_w t / I_phi) (the paper's attitude model: eta'' = tau / I); without
    drag they stay."""
    base = Vehicle(mass_load=0.0)
    params = smc.ControllerParams(
        vehicle=base, gains=smc.Gains.from_poles(), thrust_min=0.0, thrust_max=0.0, torque_max=(0.0, 0.0, 0.0)
    )
    sc = sim.Scenario(
        "coast",
        "unpowered, moving and rolling",
        1.0,
        patterns.hover(0.0, 0.0, 20.0),
        dynamics.make_state(
            position=(0, 0, 20), velocity=(3.0, 0, 0), euler_rate=(2.0, 0.0, 0.0), cable=(0.0, 0.0, -1.0)
        ),
    )
    dragged = replace(base, linear_drag=0.5, angular_drag=0.02)
    log = sim.run(sc, dragged, params, sim.SimConfig())
    t = log.column("t")
    assert np.all(log.column("u") == 0.0) and np.all(log.column("tau_phi") == 0.0)
    vx, roll_rate = log.column("vx"), log.column("phi_rate")
    # the drag is that of each 1 ms step's start, held over the step (as the emulator's plant holds it): the decay
    # is (1 - k h / M)^n, 5e-4 from the exponential after 1 s (n (k h / M)^2 / 2)
    n = np.round(t / 1e-3)
    np.testing.assert_allclose(vx, 3.0 * (1.0 - 0.5 * 1e-3 / base.mass_vehicle) ** n, rtol=1e-9)
    np.testing.assert_allclose(roll_rate, 2.0 * (1.0 - 0.02 * 1e-3 / base.inertia[0]) ** n, rtol=1e-9)
    np.testing.assert_allclose(vx, 3.0 * np.exp(-0.5 * t / base.mass_vehicle), rtol=1e-3)
    assert roll_rate[-1] < 0.9 * 2.0 and vx[-1] < 0.5 * 3.0  # the decay is large enough to be seen
    free = sim.run(sc, base, params, sim.SimConfig())
    assert free.column("vx") == pytest.approx(np.full_like(t, 3.0)) and free.column("phi_rate")[-1] == 2.0


def test_px4_sih_in_a_move_feels_its_drag_in_closed_loop() -> None:
    """The px4-sih vehicle file (SIH_KDV 1 N per m/s on its 1 kg, no load) flying a 6 m rest-to-rest move in 8 s:
    the logged motion obeys ``M a = u n_x - k v_x`` with k fitted from the log (finite differences of the
    velocity at the 1 kHz ticks, the thrust and its direction logged at each) at the file's 1.0; the same vehicle
    without drag fits 0. The law does not model the drag, so it flies the move with more tilt."""
    from estimators.model.rotations import thrust_direction
    from estimators.model.vehicle import load_vehicle

    v = load_vehicle("px4-sih")
    assert v.linear_drag == 1.0 and v.mass_load == 0.0
    ref = patterns.rest_to_rest((0.0, 0.0, 2.0), (6.0, 0.0, 2.0), 1.0, 8.0).replace(duration=10.0)
    fitted, tilt = {}, {}
    for name, veh in (("drag", v), ("none", replace(v, linear_drag=0.0, angular_drag=0.0))):
        sc = sim.Scenario("move", "6 m in 8 s", 10.0, ref, setup=PlantSetup((0.0, 0.0, 2.0)))
        log = sim.run(sc, veh, smc.ControllerParams.for_vehicle(veh), sim.SimConfig())
        t, vx, u = log.column("t"), log.column("vx"), log.column("u")
        nx = np.array(
            [thrust_direction(a, b, c)[0] for a, b, c in zip(*(log.column(k) for k in ("phi", "theta", "psi")))]
        )
        dt = np.diff(t)
        assert np.allclose(dt, dt[0])
        acc = np.diff(vx) / dt  # over each tick, with the tick's thrust held: compare with the tick's forces
        force = u[:-1] * nx[:-1]
        vmid = 0.5 * (vx[:-1] + vx[1:])
        moving = np.abs(vmid) > 0.2
        # M a - u n_x = -k v: least squares over the ticks in motion
        resid = veh.mass_vehicle * acc[moving] - force[moving]
        fitted[name] = float(-np.dot(resid, vmid[moving]) / np.dot(vmid[moving], vmid[moving]))
        tilt[name] = float(np.max(np.abs(log.column("theta"))))
    assert fitted["drag"] == pytest.approx(1.0, abs=0.03), fitted
    assert abs(fitted["none"]) < 0.03, fitted
    assert tilt["drag"] > tilt["none"] + math.radians(2.0), tilt
