"""What an attitude setpoint meets on PX4, for the in-process simulation: the emulator's PX4 inner loops
(``sim_bridge.inner.px4_inner``: quaternion attitude P, rate PID, sequential-desaturation allocator, motors with
lag) with the parameters the emulator's PX4 flavour gives the vehicle, applied as the emulator applies them
(``px4_inner.configure_px4_loops``) (``sim_bridge.modes.flavors.px4_params``:
MC_ROLL_P 4, the stock rate gains scaled to the vehicle's inertia and unit torque), scheduled as the emulator runs
them: attitude P at a quarter of the plant rate, rate loop and allocator at half, motors every plant step.

``slung compare`` flies the attitude-level law (``smc-attitude``) through it in process, as ``slung fly`` flies it
through a real autopilot's loops: the law's attitude and thrust setpoint in, the motors' wrench out. Frames: the
setpoint and the plant state in the model frame (world NWU, body FLU), PX4's side in FRD; wrench
``(thrust N, tau_x, tau_y, tau_z N m, FLU)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from estimators.model.frames import euler_to_quaternion, frd_to_model_body, model_body_to_frd
from estimators.model.rotations import Quat
from estimators.model.vehicle import Vehicle
from sim_bridge.inner.airframe import body_rates
from sim_bridge.inner.px4_inner import (
    Px4Allocator,
    Px4AttitudeControl,
    Px4Motors,
    Px4RateControl,
    allocate_with_saturation_feedback,
    configure_px4_loops,
    quad_rotors,
)


class Px4AttitudePath:
    """PX4's attitude path behind SET_ATTITUDE_TARGET (module docstring). dt: the plant step (s)."""

    def __init__(self, vehicle: Vehicle, dt: float) -> None:
        from sim_bridge.modes.flavors import px4_params

        prm = {name: p.value for name, p in px4_params(vehicle).items()}
        self.att = Px4AttitudeControl()
        self.rate = Px4RateControl(1.0 / (2.0 * dt))
        self.alloc = Px4Allocator(quad_rotors(vehicle.frame))
        rotors = configure_px4_loops(prm.__getitem__, self.att, self.rate, self.alloc)
        assert rotors is not None  # every parameter applied: the rotors among them
        self.motors = Px4Motors(vehicle, rotors, dt)
        self.tmax = vehicle.thrust_max
        self.q_sp: Quat = (1.0, 0.0, 0.0, 0.0)
        self.thrust_sp = 0.0
        self.yaw_rate_ff = 0.0
        self.rate_sp = (0.0, 0.0, 0.0)
        self._k = 0

    def reset(self, thrust_each: float = 0.0) -> None:
        """Motors at ``thrust_each`` (N) each, the integrators cleared."""
        self.motors.reset(thrust_each)
        self.rate.reset_integral()
        self._k = 0

    def set_setpoint(self, phi: float, theta: float, psi: float, thrust: float, yaw_rate_ff: float = 0.0) -> None:
        """The attitude setpoint (model-frame ZYX angles, rad), collective thrust (N) and a yaw-rate feed-forward
        about the world vertical (rad/s), as a SET_ATTITUDE_TARGET with the attitude mask carries them."""
        self.q_sp = euler_to_quaternion(phi, theta, psi)
        self.thrust_sp = min(max(thrust, 0.0), self.tmax) if math.isfinite(thrust) else 0.0
        self.yaw_rate_ff = yaw_rate_ff

    def wrench(self) -> tuple[float, float, float, float]:
        """The motors' wrench now (thrust N, torques N m FLU)."""
        t, rx, ry, rz = self.motors.wrench_frd()
        tx, ty, tz = frd_to_model_body(rx, ry, rz)
        return t, tx, ty, tz

    def step(self, x: Sequence[float]) -> tuple[float, float, float, float]:
        """One plant step from plant state ``x`` (``sim_bridge.plant.dynamics``): the motors' wrench over it."""
        k = self._k
        self._k = k + 1
        if k & 3 == 0:  # attitude P at 250 Hz on a 1 kHz plant
            self.rate_sp = self.att.update(euler_to_quaternion(x[6], x[7], x[8]), self.q_sp, self.yaw_rate_ff)
        if k & 1 == 0:  # rate PID and allocator at 500 Hz
            gyro = model_body_to_frd(*body_rates(x[6], x[7], x[9], x[10], x[11]))
            tn = self.rate.update(model_body_to_frd(*self.rate_sp), gyro, False)
            u = allocate_with_saturation_feedback(self.alloc, self.rate, tn, self.thrust_sp / self.tmax)
            self.motors.command(u)
        t, rx, ry, rz = self.motors.step()
        tx, ty, tz = frd_to_model_body(rx, ry, rz)
        return t, tx, ty, tz


__all__ = ["Px4AttitudePath"]
