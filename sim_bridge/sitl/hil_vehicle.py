"""The physics behind real PX4 SITL's HIL interface: four rotors, a rigid body with its slung load, a ground.

``sim_bridge.sitl.px4_hil`` serves this to PX4's ``simulator_mavlink`` module, so that the real PX4 stack (its
commander, EKF2, attitude and rate controllers, control allocator) flies a vehicle that carries a load on a cable,
which PX4's own SIH cannot simulate.

Rotors: PX4's four motor outputs (0..1, HIL_ACTUATOR_CONTROLS ``controls[0:4]``) are thrusts ``T_i = T_max u_i``
(linear in the output: PX4's THR_MDL_FAC 0, which the launcher sets) through a first-order lag of the vehicle's
``motor_time_constant``: ``sim_bridge.inner.px4_inner.Px4Motors``, the emulator's own model of PX4's motors, with the
rotors where PX4's numbering puts them for the vehicle's frame (``quad_rotors``: for X airframe 10040's layout,
rotor 0 front right, 1 rear left, 2 front left, 3 rear right, the one the launcher gives PX4's allocator) at the
vehicle's ``arm_length``. In body FRD a rotor at ``(px, py)`` pushing ``T`` up (``-z``) makes the torque
``(-py T, px T, s c T)``, ``s`` the sign of its ``CA_ROTORi_KM``.

Ground: the vehicle rests on the plane z = 0 (model NWU) on landing gear tall enough for the load to hang free (as
``sim_bridge.emulator``); it lifts off when the thrust exceeds the total weight, and a descent through z = 0 puts it
at rest there, level, with the cable hanging.

Frames: the plant's (``sim_bridge.plant.dynamics``): world NWU, body FLU, SI units; the wire's NED / FRD is
``sim_bridge.sitl.hil_sensors``'s business.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from estimators.model.frames import frd_to_model_body
from estimators.model.vehicle import Vehicle
from sim_bridge.inner.px4_inner import Px4Motors, quad_rotors
from sim_bridge.plant.dynamics import apply_drag, derivative, make_state, plant_params, rk4_step, tension


class HilVehicle:
    """The plant of one vehicle with its load, stepped by PX4's motor outputs (see the module docstring).

    vehicle: the TRUE vehicle (masses, cable, inertia, arm, motors, drag); plant_dt: the integration step (s).
    """

    def __init__(self, vehicle: Vehicle, plant_dt: float = 0.001) -> None:
        if not vehicle.mass_load > 0.0:
            raise ValueError("the HIL physics needs a vehicle with a load (mass_load > 0)")
        self.vehicle = vehicle
        self.motors = Px4Motors(vehicle, quad_rotors(vehicle.frame), plant_dt)
        self.p = plant_params(vehicle, "rigid")
        self.h = plant_dt
        self.x = make_state()
        self.u = [0.0] * 13
        self.on_ground = True
        self.weight = vehicle.total_mass * vehicle.gravity

    def wrench(self) -> tuple[float, float, float, float]:
        """The rotors' collective thrust (N, along body up) and torques (N m, body **FLU**) now."""
        thrust, rx, ry, rz = self.motors.wrench_frd()
        return (thrust, *frd_to_model_body(rx, ry, rz))

    def step(self, outputs: Sequence[float], n: int = 1) -> None:
        """Advance ``n`` plant steps with PX4's motor outputs ``outputs`` (4, each clipped to 0..1; not finite: 0)
        held."""
        self.motors.command([float(o) if math.isfinite(o) else 0.0 for o in outputs[:4]])
        v = self.vehicle
        for _ in range(n):
            thrust, rx, ry, rz = self.motors.step()
            tx, ty, tz = frd_to_model_body(rx, ry, rz)
            u = self.u
            u[0], u[1], u[2], u[3] = thrust, tx, ty, tz
            apply_drag(u, self.x, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), v.linear_drag, v.angular_drag)
            if self.on_ground and thrust <= self.weight * 1.0001:
                continue
            self.on_ground = False
            x = rk4_step(self.x, u, self.p, self.h)
            if x[2] < 0.0:
                self.on_ground = True
                x = make_state((x[0], x[1], 0.0), euler=(0.0, 0.0, x[8]))
            self.x = x

    def acceleration(self) -> tuple[float, float, float]:
        """The vehicle's world acceleration now (model NWU, m/s^2; zero at rest on the ground): what its
        accelerometer senses, with gravity."""
        if self.on_ground:
            return 0.0, 0.0, 0.0
        d = derivative(0.0, self.x, self.u, self.p)
        return d[3], d[4], d[5]

    # ------------------------------------------------------------------------------------------------ truth ---
    def load_position(self) -> tuple[float, float, float]:
        """The load's position, world NWU (m)."""
        x, l_ = self.x, self.p.l
        return x[0] + l_ * x[12], x[1] + l_ * x[13], x[2] + l_ * x[14]

    def swing(self) -> float:
        """The cable's angle from the downward vertical, rad."""
        r1, r2, r3 = self.x[12], self.x[13], self.x[14]
        return math.atan2(math.hypot(r1, r2), -r3)

    def cable_tension(self) -> float:
        """The cable's tension, N (<= 0: slack)."""
        return tension(self.x, self.u, self.p)


__all__ = ["HilVehicle"]
