"""The physics behind real PX4 SITL's HIL interface: four rotors, a rigid body with its slung load, a ground.

``sim_bridge.sitl.px4_hil`` serves this to PX4's ``simulator_mavlink`` module, so that the real PX4 stack (its
commander, EKF2, attitude and rate controllers, control allocator) flies a vehicle that carries a load on a cable,
which PX4's own SIH cannot simulate.

Rotors: PX4's four motor outputs (0..1, HIL_ACTUATOR_CONTROLS ``controls[0:4]``) are thrusts ``T_i = T_max u_i``
(linear in the output: PX4's THR_MDL_FAC 0, which the launcher sets) through a first-order lag of the vehicle's
``motor_time_constant``. The rotors sit as PX4's square X numbering has them (airframe 10040's layout, the one the
launcher gives PX4's allocator): rotor 0 front right, 1 rear left, 2 front left, 3 rear right, at the vehicle's
``arm_length`` from the centre; rotors 0 and 1 have a positive moment coefficient (``CA_ROTORi_KM`` > 0: a
reaction torque ``+c T`` about body FRD z), 2 and 3 a negative one. In body FRD a rotor at ``(px, py)`` pushing
``T`` up (``-z``) makes the torque ``(-py T, px T, km c T)``.

Ground: the vehicle rests on the plane z = 0 (model NWU) on landing gear tall enough for the load to hang free (as
``sim_bridge.emulator``); it lifts off when the thrust exceeds the total weight, and a descent through z = 0 puts it
at rest there, level, with the cable hanging.

Frames: the plant's (``sim_bridge.plant.dynamics``): world NWU, body FLU, SI units; the wire's NED / FRD is
``sim_bridge.sitl.hil_sensors``'s business.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from estimators.model.vehicle import Vehicle
from sim_bridge.plant.dynamics import apply_drag, derivative, make_state, plant_params, rk4_step, tension

#: PX4's square X layout (``CA_ROTORi_PX``, ``CA_ROTORi_PY`` as unit signs, FRD) and each rotor's moment sign
#: (``CA_ROTORi_KM``'s sign): the launcher gives PX4's allocator exactly this
ROTOR_LAYOUT: tuple[tuple[float, float, float], ...] = (
    (1.0, 1.0, 1.0),
    (-1.0, -1.0, 1.0),
    (1.0, -1.0, -1.0),
    (-1.0, 1.0, -1.0),
)


def rotor_wrench(vehicle: Vehicle, thrusts: Sequence[float]) -> tuple[float, float, float, float]:
    """Collective thrust (N, along body up) and torques (N m, body **FLU**) of the four rotors' thrusts (N)."""
    a = vehicle.arm_length / math.sqrt(2.0)  # the perpendicular arm of an X frame
    c = vehicle.yaw_moment_coefficient
    tx = ty = tz = 0.0
    for (sx, sy, km), t in zip(ROTOR_LAYOUT, thrusts, strict=True):
        tx += -sy * a * t  # FRD torque (-py T, px T, km c T) ...
        ty += sx * a * t
        tz += km * c * t
    return sum(thrusts), tx, -ty, -tz  # ... to FLU: (x, -y, -z)


class HilVehicle:
    """The plant of one vehicle with its load, stepped by PX4's motor outputs (see the module docstring).

    vehicle: the TRUE vehicle (masses, cable, inertia, arm, motors, drag); plant_dt: the integration step (s).
    """

    def __init__(self, vehicle: Vehicle, plant_dt: float = 0.001) -> None:
        if not vehicle.mass_load > 0.0:
            raise ValueError("the HIL physics needs a vehicle with a load (mass_load > 0)")
        if vehicle.frame != "x":
            raise ValueError(f"the HIL physics flies PX4's X layout; the vehicle's frame is {vehicle.frame!r}")
        self.vehicle = vehicle
        self.p = plant_params(vehicle, "rigid")
        self.h = plant_dt
        self.x = make_state()
        self.u = [0.0] * 13
        self.thrusts = [0.0, 0.0, 0.0, 0.0]
        self.on_ground = True
        self.weight = vehicle.total_mass * vehicle.gravity
        tau = vehicle.motor_time_constant
        self._lag = 1.0 if tau <= 0.0 else 1.0 - math.exp(-plant_dt / tau)

    def step(self, outputs: Sequence[float], n: int = 1) -> None:
        """Advance ``n`` plant steps with PX4's motor outputs ``outputs`` (4, each clipped to 0..1) held."""
        t_max = self.vehicle.motor_thrust_max
        cmd = [t_max * min(1.0, max(0.0, float(o))) if math.isfinite(o) else 0.0 for o in outputs[:4]]
        v = self.vehicle
        for _ in range(n):
            for i in range(4):
                self.thrusts[i] += self._lag * (cmd[i] - self.thrusts[i])
            thrust, tx, ty, tz = rotor_wrench(v, self.thrusts)
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


__all__ = ["ROTOR_LAYOUT", "HilVehicle", "rotor_wrench"]
