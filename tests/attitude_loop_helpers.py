"""A closed loop for the attitude-level law: the nonlinear plant (``sim_bridge.plant.dynamics``, rigid body) behind an
autopilot-like inner cascade written here from PX4's structure (quaternion attitude P -> body-rate P loop ->
torque clipped to the mixer's authority), with the setpoint delayed by a fixed time. The inner loop's gains and
the delay can differ from what the law assumes: that is what the robustness tests vary."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from estimators.model.flatness import flat_constants
from estimators.model.frames import euler_to_quaternion
from estimators.model.rotations import quat_mul
from estimators.model.vehicle import Vehicle
from offboard.control import smc_attitude
from offboard.control.smc import ControllerMemory
from offboard.harness.sim import truth_control_state
from sim_bridge.plant import dynamics


@dataclass
class Cascade:
    """The autopilot's loops as flown: attitude P (1/s: roll/pitch, yaw), rate bandwidth (1/s per axis)."""

    att_p: float = 6.5
    yaw_p: float = 2.8
    rate_bw: tuple[float, float, float] = (18.0, 18.0, 5.0)
    delay_s: float = 0.0


def fly(
    vehicle: Vehicle,
    params: smc_attitude.AttitudeParams,
    cascade: Cascade,
    reference,
    duration: float,
    start: tuple[float, float, float] = (0.0, 0.0, 1.0),
    psi0: float = 0.0,
    rate_hz: float = 250.0,
    h: float = 1e-3,
    swing0: tuple[float, float] = (0.0, 0.0),
    disturbance=None,
) -> dict[str, np.ndarray]:
    """Fly ``reference(t) -> (fx, fy, z, psi)`` jets for ``duration`` s from ``start``; returns logged arrays."""
    p = dynamics.plant_params(vehicle, "rigid")
    ay, ax = swing0
    r = (math.sin(ay), math.sin(ax), -math.sqrt(max(0.0, 1 - math.sin(ay) ** 2 - math.sin(ax) ** 2)))
    x = dynamics.make_state(position=start, euler=(0.0, 0.0, psi0), cable=r)
    k = flat_constants(vehicle)
    mem = ControllerMemory()
    tmax = (vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max)
    inertia = vehicle.inertia
    n_ctrl = max(1, round(1.0 / (rate_hz * h)))
    n_delay = round(cascade.delay_s / h)
    hover = smc_attitude.hover_command(params, psi0)
    queue: deque = deque([hover] * (n_delay + 1), maxlen=n_delay + 1)
    cmd = hover
    log: dict[str, list] = {k_: [] for k_ in ("t", "x", "cmd", "sat")}
    steps = round(duration / h)
    for i in range(steps):
        t = i * h
        if i % n_ctrl == 0:
            s = truth_control_state(x, k)
            fx, fy, z, psi = reference(t)
            cmd, mem = smc_attitude.step(t, s, fx, fy, z, psi, mem, params)
            log["t"].append(t)
            log["x"].append(list(x))
            log["cmd"].append(tuple(cmd))
        queue.append(cmd)
        c = queue[0]
        # attitude P on the quaternion error (body axes), then the rate loop's torque
        q = euler_to_quaternion(x[6], x[7], x[8])
        qs = euler_to_quaternion(c.phi_sp, c.theta_sp, c.psi_sp)
        qe = quat_mul((q[0], -q[1], -q[2], -q[3]), qs)
        sgn = 1.0 if qe[0] >= 0 else -1.0
        e = (2 * sgn * qe[1], 2 * sgn * qe[2], 2 * sgn * qe[3])
        wsp = (cascade.att_p * e[0], cascade.att_p * e[1], cascade.yaw_p * e[2])
        phi, theta = x[6], x[7]
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
        w = (x[9] - st * x[11], cf * x[10] + sf * ct * x[11], -sf * x[10] + cf * ct * x[11])
        tau = [inertia[j] * cascade.rate_bw[j] * (wsp[j] - w[j]) for j in range(3)]
        sat = False
        for j in range(3):
            if abs(tau[j]) > tmax[j]:
                tau[j], sat = math.copysign(tmax[j], tau[j]), True
        if i % n_ctrl == 0:
            log["sat"].append(sat)
        u = dynamics.make_input(c.thrust, tau)
        if disturbance is not None:
            dist = disturbance(t)
            u[4:13] = dist
        x = dynamics.rk4_step(x, u, p, h)
        if not all(math.isfinite(v) for v in x) or abs(x[0]) > 1e3:
            break
    return {k_: np.array(v) for k_, v in log.items()}


def hold_reference(fx: float = 0.0, fy: float = 0.0, z: float = 1.0, psi: float = 0.0):
    """A constant reference: jets of order 0..6 for fx, fy; 0..2 for z, psi."""
    jet = lambda v, n: (v,) + (0.0,) * n  # noqa: E731
    out = (jet(fx, 6), jet(fy, 6), jet(z, 2), jet(psi, 2))
    return lambda t: out
