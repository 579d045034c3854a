"""What PX4's ``simulator_mavlink`` reads from a simulator (HIL_SENSOR, HIL_GPS, HIL_STATE_QUATERNION), made from
the plant of ``sim_bridge.sitl.hil_vehicle``: the one place where the HIL physics meets the wire's frames and units.

Wire frames and units (MAVLink common): body **FRD**; accelerometer m/s^2 (specific force), gyro rad/s,
magnetometer gauss, absolute pressure hPa, pressure altitude m (PX4 does not read it), temperature degC; GPS
latitude / longitude in 1e-7 deg, altitude mm above mean sea level, velocities cm/s NED, eph / epv in cm; the ground
truth's quaternion body FRD to world NED, its velocities cm/s NED.

The world: a flat earth around ``HOME`` (PX4's default SITL home, 47.397742 N, 8.545594 E, 488 m), the standard
atmosphere for the barometer, and a constant magnetic field near the World Magnetic Model's at home (EKF2 and the
commander's checks compare the measured field with their own model of it there).

Noise (:class:`HilNoise`): white and seeded, of a calm SITL vehicle, not a measured airframe's; the GPS has no
slow wander, so EKF2's position is better than a real receiver would let it be.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from estimators.model.frames import (
    STANDARD_GRAVITY,
    euler_to_quaternion,
    model_body_to_frd,
    model_quaternion_to_ned,
    model_to_ned_vector,
    ned_to_model_vector,
)
from estimators.model.rotations import body_rates, quat_conj, quat_mul
from sim_bridge.plant.sensors import specific_force_body
from sim_bridge.sitl.hil_vehicle import HilVehicle

#: m, the earth's equatorial radius (WGS-84), for the flat-earth latitude / longitude of a local position
EARTH_RADIUS_M = 6378137.0


class Home(NamedTuple):
    """Where the local frame's origin (the take-off point on the ground) is: degrees, m above mean sea level."""

    lat_deg: float
    lon_deg: float
    alt_m: float


#: PX4 SITL's default home (``PX4_HOME_LAT`` / ``_LON`` / ``_ALT`` unset)
HOME = Home(47.397742, 8.545594, 488.0)
#: the earth's field at HOME, gauss, world NED: 0.4822 gauss, inclination 63.15 deg, declination 3.33 deg east, as
#: PX4's own World Magnetic Model table interpolates it there (``lib/world_magnetic_model``), which EKF2's strength
#: check and its declination use
MAG_FIELD_NED = (0.2174, 0.0126, 0.4302)

# HIL_SENSOR.fields_updated bits
ACCEL_BITS, GYRO_BITS, MAG_BITS = 0x007, 0x038, 0x1C0
BARO_BITS = 0x200 | 0x800 | 0x1000  # absolute pressure, pressure altitude, temperature


@dataclass(frozen=True)
class HilNoise:
    """Standard deviations of the sensors' white noise: accelerometer m/s^2, gyro rad/s, magnetometer gauss,
    barometer hPa, GPS horizontal and vertical position m and velocity m/s."""

    accel: float = 0.05
    gyro: float = 0.005
    mag: float = 0.001
    baro_hpa: float = 0.005
    gps_horizontal: float = 0.05
    gps_vertical: float = 0.1
    gps_velocity: float = 0.03


def world_to_body(x: Any, v: tuple[float, float, float]) -> tuple[float, float, float]:
    """A world NWU vector in the body FLU frame of the plant state ``x`` (its ZYX Euler angles)."""
    q = euler_to_quaternion(x[6], x[7], x[8])
    _, bx, by, bz = quat_mul(quat_mul(quat_conj(q), (0.0, *v)), q)
    return bx, by, bz


def pressure_hpa(alt_m: float) -> float:
    """The standard atmosphere's pressure at ``alt_m`` above mean sea level, hPa (troposphere)."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_m) ** 5.25588


def temperature_c(alt_m: float) -> float:
    """The standard atmosphere's temperature at ``alt_m``, degC."""
    return 15.0 - 0.0065 * alt_m


def lat_lon(home: Home, north_m: float, east_m: float) -> tuple[float, float]:
    """Latitude and longitude (deg) of a point ``north_m``, ``east_m`` from home, on a flat earth."""
    lat = home.lat_deg + math.degrees(north_m / EARTH_RADIUS_M)
    lon = home.lon_deg + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(home.lat_deg))))
    return lat, lon


class HilSensors:
    """The sensor messages of one :class:`HilVehicle` (see the module docstring); ``rng`` the only randomness."""

    def __init__(
        self, plant: HilVehicle, rng: np.random.Generator, noise: HilNoise | None = None, home: Home = HOME
    ) -> None:
        self.plant = plant
        self.rng = rng
        self.noise = noise or HilNoise()
        self.home = home
        n, e, d = MAG_FIELD_NED
        self.mag_world = ned_to_model_vector(n, e, d)

    def _n(self, sd: float, k: int = 3) -> list[float]:
        return [float(v) for v in self.rng.normal(0.0, sd, k)] if sd > 0.0 else [0.0] * k

    def sensor(self, mav: Any, time_usec: int, *, with_mag_baro: bool) -> Any:
        """HIL_SENSOR at ``time_usec``: accelerometer and gyro, and the magnetometer and barometer when asked."""
        x, ns = self.plant.x, self.noise
        f = specific_force_body(x, self.plant.acceleration(), self.plant.vehicle.gravity)
        acc = model_body_to_frd(*f)
        gyr = model_body_to_frd(*body_rates(x[6], x[7], x[9], x[10], x[11]))
        ea, eg = self._n(ns.accel), self._n(ns.gyro)
        bits = ACCEL_BITS | GYRO_BITS
        mag, baro = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        if with_mag_baro:
            em = self._n(ns.mag)
            m = model_body_to_frd(*world_to_body(x, self.mag_world))
            mag = (m[0] + em[0], m[1] + em[1], m[2] + em[2])
            alt = self.home.alt_m + x[2]
            p = pressure_hpa(alt) + self._n(ns.baro_hpa, 1)[0]
            baro = (p, alt, temperature_c(alt))
            bits |= MAG_BITS | BARO_BITS
        return mav.hil_sensor_encode(
            time_usec,
            acc[0] + ea[0],
            acc[1] + ea[1],
            acc[2] + ea[2],
            gyr[0] + eg[0],
            gyr[1] + eg[1],
            gyr[2] + eg[2],
            mag[0],
            mag[1],
            mag[2],
            baro[0],
            0.0,
            baro[1],
            baro[2],
            bits,
            0,
        )

    def gps(self, mav: Any, time_usec: int) -> Any:
        """HIL_GPS at ``time_usec``: a 3D fix with ten satellites."""
        x, ns = self.plant.x, self.noise
        n, e, d = model_to_ned_vector(x[0], x[1], x[2])
        vn, ve, vd = model_to_ned_vector(x[3], x[4], x[5])
        ep, ez, ev = self._n(ns.gps_horizontal, 2), self._n(ns.gps_vertical, 1), self._n(ns.gps_velocity, 3)
        lat, lon = lat_lon(self.home, n + ep[0], e + ep[1])
        alt = self.home.alt_m - d + ez[0]
        vn, ve, vd = vn + ev[0], ve + ev[1], vd + ev[2]
        cog = round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0) % 36000
        return mav.hil_gps_encode(
            time_usec,
            3,
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000.0),
            max(1, round(ns.gps_horizontal * 100.0)),
            max(1, round(ns.gps_vertical * 100.0)),
            round(math.hypot(vn, ve) * 100.0),
            round(vn * 100.0),
            round(ve * 100.0),
            round(vd * 100.0),
            cog,
            10,
            0,
            0,
        )

    def ground_truth(self, mav: Any, time_usec: int) -> Any:
        """HIL_STATE_QUATERNION at ``time_usec``: the exact attitude, rates, position and velocity."""
        x = self.plant.x
        q = model_quaternion_to_ned(*euler_to_quaternion(x[6], x[7], x[8]))
        p, qr, r = model_body_to_frd(*body_rates(x[6], x[7], x[9], x[10], x[11]))
        n, e, d = model_to_ned_vector(x[0], x[1], x[2])
        vn, ve, vd = model_to_ned_vector(x[3], x[4], x[5])
        lat, lon = lat_lon(self.home, n, e)
        f = model_body_to_frd(*specific_force_body(x, self.plant.acceleration(), self.plant.vehicle.gravity))
        mg = [round(c / STANDARD_GRAVITY * 1000.0) for c in f]
        return mav.hil_state_quaternion_encode(
            time_usec,
            [float(c) for c in q],
            p,
            qr,
            r,
            round(lat * 1e7),
            round(lon * 1e7),
            round((self.home.alt_m - d) * 1000.0),
            round(vn * 100.0),
            round(ve * 100.0),
            round(vd * 100.0),
            0,
            0,
            *mg,
        )


__all__ = ["HOME", "MAG_FIELD_NED", "HilNoise", "HilSensors", "Home", "lat_lon", "pressure_hpa", "world_to_body"]
