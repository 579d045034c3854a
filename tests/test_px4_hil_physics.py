"""The HIL physics that real PX4 flies with a slung load (``sim_bridge.sitl.hil_vehicle``, ``hil_sensors``): the
rotors' torques follow PX4's own effectiveness convention, the vehicle rests on the ground until it can lift the
load, and the sensor messages carry the wire's frames and units. The real exchange with PX4 is flown in
``tests/test_px4_hil.py``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from estimators.model.frames import STANDARD_GRAVITY
from estimators.model.vehicle import load_vehicle
from sim_bridge.sitl.hil_sensors import HOME, MAG_FIELD_NED, HilNoise, HilSensors, lat_lon, pressure_hpa
from sim_bridge.sitl.hil_vehicle import HilVehicle
from sim_bridge.sitl.px4_hil import hil_params

VEHICLE = load_vehicle("px4-hil-load")


def _mav() -> mavlink2.MAVLink:
    return mavlink2.MAVLink(None, srcSystem=1, srcComponent=51)


def test_rotor_torques_follow_px4_effectiveness() -> None:
    """PX4's rotor effectiveness: a rotor at FRD (px, py) pushing up makes (-py T, px T, km T) about FRD; slung's
    model body is FLU (y and z negated)."""
    a = VEHICLE.arm_length / math.sqrt(2.0)
    c = VEHICLE.yaw_moment_coefficient
    plant = HilVehicle(VEHICLE)
    plant.motors.f = [1.0, 0.0, 0.0, 0.0]  # rotor 0: front right, KM > 0
    thrust, tx, ty, tz = plant.wrench()
    assert thrust == 1.0
    assert (tx, ty, tz) == pytest.approx((-a, -a, -c))  # FRD (-a, +a, +c): right side up, nose up, yaw right
    plant.motors.f = [0.0, 0.0, 1.0, 0.0]  # rotor 2: front left, KM < 0
    assert plant.wrench()[1:] == pytest.approx((a, -a, c))
    plant.motors.f = [2.0, 2.0, 2.0, 2.0]  # equal thrusts: no torque
    assert plant.wrench()[1:] == pytest.approx((0.0, 0.0, 0.0))


def test_px4_is_given_the_same_layout() -> None:
    p = hil_params(VEHICLE)
    for i, (px, py, km_sign) in enumerate(((1, 1, 1), (-1, -1, 1), (1, -1, -1), (-1, 1, -1))):
        assert (p[f"CA_ROTOR{i}_PX"], p[f"CA_ROTOR{i}_PY"]) == (px, py)
        assert math.copysign(1.0, p[f"CA_ROTOR{i}_KM"]) == km_sign
    assert p["THR_MDL_FAC"] == 0.0
    hover = VEHICLE.total_mass * VEHICLE.gravity / (4 * VEHICLE.motor_thrust_max)
    assert p["MPC_THR_HOVER"] == pytest.approx(hover, abs=1e-3)


def test_rests_on_the_ground_until_it_lifts_the_load_then_the_load_hangs() -> None:
    plant = HilVehicle(VEHICLE)
    hover = VEHICLE.total_mass * VEHICLE.gravity / (4 * VEHICLE.motor_thrust_max)
    plant.step([0.98 * hover] * 4, 500)
    assert plant.on_ground and plant.x[2] == 0.0
    plant.step([1.1 * hover] * 4, 1000)
    assert not plant.on_ground and plant.x[2] > 0.05
    assert plant.swing() < 1e-6  # a vertical lift does not swing the load
    # hanging at rest-ish the cable carries about the load's weight plus its share of the acceleration
    accel_up = plant.acceleration()[2]
    expected = VEHICLE.mass_load * (VEHICLE.gravity + accel_up)
    assert plant.cable_tension() == pytest.approx(expected, rel=1e-6)
    plant.step([0.0] * 4, 3000)  # motors off: it falls and comes to rest on the ground, level
    assert plant.on_ground and plant.x[2] == 0.0 and plant.x[6] == plant.x[7] == 0.0


def test_sensors_at_rest_on_the_ground_carry_the_wire_units() -> None:
    plant = HilVehicle(VEHICLE)
    plant.x[8] = math.radians(-90.0)  # model yaw is counter-clockwise from north seen from above: nose east
    sensors = HilSensors(plant, np.random.default_rng(0), HilNoise(0, 0, 0, 0, 0, 0, 0))
    m = sensors.sensor(_mav(), 4000, with_mag_baro=True)
    # FRD: the accelerometer at rest reads -g along z (it is pushed up by the ground)
    assert (m.xacc, m.yacc, m.zacc) == pytest.approx((0.0, 0.0, -VEHICLE.gravity), abs=1e-9)
    assert (m.xgyro, m.ygyro, m.zgyro) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    # nose east: body x sees the field's east component, body y (right) the field's south (-north)
    n, e, d = MAG_FIELD_NED
    assert (m.xmag, m.ymag, m.zmag) == pytest.approx((e, -n, d), abs=1e-6)
    assert m.abs_pressure == pytest.approx(pressure_hpa(HOME.alt_m), abs=1e-3)
    assert 950.0 < m.abs_pressure < 960.0  # 488 m above mean sea level
    assert m.pressure_alt == pytest.approx(HOME.alt_m)
    assert m.fields_updated & 0x1FFF == 0x1FFF & ~0x400  # all but differential pressure


def test_gps_and_truth_put_a_point_north_east_and_up_where_it_is() -> None:
    plant = HilVehicle(VEHICLE)
    plant.x[0], plant.x[1], plant.x[2] = 100.0, -50.0, 10.0  # model NWU: 100 m north, 50 m east, 10 m up
    plant.x[3], plant.x[4], plant.x[5] = 1.0, -2.0, 0.5
    sensors = HilSensors(plant, np.random.default_rng(0), HilNoise(0, 0, 0, 0, 0, 0, 0))
    g = sensors.gps(_mav(), 1_000_000)
    lat, lon = lat_lon(HOME, 100.0, 50.0)
    assert (g.lat, g.lon) == (round(lat * 1e7), round(lon * 1e7))
    assert g.lat > HOME.lat_deg * 1e7 and g.lon > HOME.lon_deg * 1e7
    assert g.alt == round((HOME.alt_m + 10.0) * 1000)
    assert (g.vn, g.ve, g.vd) == (100, 200, -50)  # cm/s NED
    assert g.fix_type == 3
    t = sensors.ground_truth(_mav(), 1_000_000)
    assert (t.vx, t.vy, t.vz) == (100, 200, -50)
    assert (t.xacc, t.yacc, t.zacc) == (0, 0, round(-VEHICLE.gravity / STANDARD_GRAVITY * 1000))  # at rest
    # 100 m north is 100 m on PX4's own sphere to within its radius' 0.1 %
    assert (g.lat - round(HOME.lat_deg * 1e7)) * 1e-7 * math.pi / 180 * 6371000.0 == pytest.approx(100.0, rel=2e-3)


def test_a_vehicle_without_a_load_is_refused() -> None:
    with pytest.raises(ValueError, match="load"):
        HilVehicle(load_vehicle("px4-sih"))


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--vehicle", "px4-sih"], "carries no load"),
        (["--instance", "12"], "--instance must be 0..9"),
        (["--speed", "-1"], "--speed must be >= 0"),
        (["--load-sensor", "5000"], "--load-sensor must be 0..1000 Hz"),
        (["--swing", "nan"], "--swing must be a finite angle"),
        (["--duration", "inf"], "--duration must be a finite number"),
        (["--truth", "/nonexistent-dir/truth.csv"], "cannot write the truth file"),
    ],
)
def test_slung_px4_hil_refuses_bad_input_in_one_line(
    args: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from offboard.cli import main

    assert main(["px4-hil", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
