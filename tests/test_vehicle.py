"""estimators/model/vehicle.py: defaults, TOML round trip, and one-line VehicleFileError (a UserError) for bad files."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle, VehicleFileError, load_vehicle, vehicle_to_toml


def test_default_is_paper_table1() -> None:
    v = load_vehicle(None)
    assert v == Vehicle()
    assert (v.mass_vehicle, v.mass_load, v.cable_length, v.gravity) == (0.5, 0.2, 0.3, 9.8)
    assert v.inertia == (0.1, 0.1, 0.1)
    assert v.hover_thrust == pytest.approx(0.7 * 9.8)
    assert v.thrust_max / v.hover_thrust == pytest.approx(16.0 / 6.86)  # thrust-to-weight ~2.3
    assert 0.0 < v.hover_thrust_normalized < 0.5
    assert v.pendulum_frequency == pytest.approx(math.sqrt(0.7 * 9.8 / (0.5 * 0.3)))
    # X mixer around hover: df = min(1.715, 4 - 1.715) N, tau = 4 df d / sqrt(2)
    assert v.roll_pitch_torque_max == pytest.approx(4 * 1.715 * 0.17 / math.sqrt(2.0))
    assert v.yaw_torque_max == pytest.approx(4 * 1.715 * 0.016)


def test_toml_round_trip(tmp_path: Path) -> None:
    v = Vehicle(
        name="test rig",
        mass_vehicle=1.234,
        mass_load=0.0,
        cable_length=0.75,
        gravity=9.80665,
        inertia=(0.011, 0.012, 0.021),
        arm_length=0.225,
        yaw_moment_coefficient=0.013,
        motor_thrust_max=7.5,
        motor_time_constant=0.0,
    )
    path = tmp_path / "rig.toml"
    path.write_text(vehicle_to_toml(v), encoding="utf-8")
    assert load_vehicle(path) == v
    assert load_vehicle(str(path)) == v
    path.write_text(vehicle_to_toml(Vehicle()), encoding="utf-8")
    assert load_vehicle(path) == Vehicle()


def test_partial_file_keeps_defaults(tmp_path: Path) -> None:
    path = tmp_path / "p.toml"
    path.write_text("[load]\nmass_kg = 0.1\ncable_length_m = 1\n", encoding="utf-8")
    v = load_vehicle(path)
    assert (v.mass_load, v.cable_length, v.mass_vehicle) == (0.1, 1.0, 0.5)


def _error(tmp_path: Path, text: str) -> str:
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(VehicleFileError) as info:
        load_vehicle(path)
    assert isinstance(info.value, UserError)
    msg = str(info.value)
    assert "\n" not in msg and msg
    assert str(path) in msg  # the message names the file
    return msg


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[vehicle]\nmass = 0.5\n", "vehicle.mass"),  # unknown key (unit missing from the name)
        ("[motors]\ncount = 4\n", "motors.count"),  # unknown section
        ('[vehicle]\nmass_kg = "heavy"\n', "heavy"),  # not a number
        ("[vehicle]\nmass_kg = true\n", "vehicle.mass_kg"),  # a bool is not a number
        ("[vehicle]\ninertia_kg_m2 = [0.1, 0.1]\n", "inertia"),
        ('[vehicle]\ninertia_kg_m2 = [0.1, "a", 0.1]\n', "inertia"),
        ("[vehicle]\nname = 3\n", "name"),
        ("vehicle = 3\n", "[vehicle]"),  # a section that is not a table
        ("[vehicle]\nmass_kg = -0.5\n", "mass_vehicle"),  # negative mass
        ("[load]\nmass_kg = -0.1\n", "mass_load"),
        ("[vehicle]\ninertia_kg_m2 = [0.1, -0.1, 0.1]\n", "inertia"),
        ("[load]\ncable_length_m = 0\n", "cable_length"),
        ("[environment]\ngravity_m_s2 = nan\n", "gravity"),
        ("[vehicle]\nmotor_thrust_max_n = 1.0\n", "cannot hover"),  # 4 N total < 6.86 N weight
        ("[vehicle\nmass_kg = 1\n", "not valid TOML"),
    ],
)
def test_bad_files_give_one_line_user_errors(tmp_path: Path, text: str, needle: str) -> None:
    assert needle in _error(tmp_path, text)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(VehicleFileError) as info:
        load_vehicle(tmp_path / "nope.toml")
    assert "cannot read vehicle file" in str(info.value) and "\n" not in str(info.value)


def test_heavier_load_can_make_hover_impossible() -> None:
    with pytest.raises(VehicleFileError, match="cannot hover"):
        Vehicle(mass_load=1.2)  # (0.5 + 1.2) * 9.8 = 16.7 N > 16 N
    assert Vehicle(mass_load=1.1).hover_thrust < Vehicle().thrust_max


def test_named_vehicles_ship_and_are_consistent() -> None:
    """--vehicle NAME: the shipped files load, and their facts agree with each other (docs in each file)."""
    from estimators.model.vehicle import named_vehicles

    assert {"paper-table1", "px4-sih", "ardupilot-sitl-quad"} <= set(named_vehicles())
    assert load_vehicle("paper-table1") == Vehicle()  # the built-in default, as a file
    sih = load_vehicle("px4-sih")
    assert (sih.mass_vehicle, sih.mass_load, sih.inertia, sih.motor_thrust_max) == (1.0, 0.0, (0.025, 0.025, 0.03), 5.0)
    assert sih.moment_arm == pytest.approx(0.2)  # SIH_L_ROLL, perpendicular
    # SIH's thrust is linear in the command (THR_MDL_FAC 0): MPC_THR_HOVER 0.5 vs the physical 0.49
    assert sih.hover_throttle == 0.5 and sih.hover_thrust_normalized == pytest.approx(0.49, abs=0.005)
    ap = load_vehicle("ardupilot-sitl-quad")
    assert (ap.mass_vehicle, ap.mass_load, ap.cable_length, ap.arm_length) == (3.0, 1.2, 1.0, 0.175)
    assert ap.inertia == (0.023, 0.023, 0.046) and ap.hover_throttle == 0.51

    # ArduPilot's throttle curve (MOT_THST_EXPO 0.65) maps the hover throttles, bare (0.39) and loaded (0.51),
    # to the weights within 10 % of the file's thrust limit
    def thrust_fraction(u: float, e: float = 0.65) -> float:
        return (1.0 - e) * u + e * u * u

    for mass, u in ((3.0, 0.39), (4.2, 0.51)):
        assert mass * ap.gravity / thrust_fraction(u) == pytest.approx(ap.thrust_max, rel=0.1)
    for v in (sih, ap):
        assert v.thrust_max > 1.5 * v.hover_thrust  # room to manoeuvre


def test_unknown_vehicle_name_lists_the_shipped_ones() -> None:
    with pytest.raises(VehicleFileError, match="px4-sih"):
        load_vehicle("no-such-quad")


def test_plus_frame_torque_uses_the_two_motors_off_the_axis(tmp_path: Path) -> None:
    x = Vehicle()
    plus = Vehicle(frame="+")
    f_hover = x.hover_thrust / 4.0
    df = min(f_hover, x.motor_thrust_max - f_hover)
    assert plus.roll_pitch_torque_max == pytest.approx(2.0 * df * x.arm_length)
    assert x.roll_pitch_torque_max == pytest.approx(4.0 * df * x.arm_length / math.sqrt(2.0))
    path = tmp_path / "plus.toml"
    path.write_text(vehicle_to_toml(Vehicle(frame="+", hover_throttle=0.4)), encoding="utf-8")
    assert load_vehicle(path) == Vehicle(frame="+", hover_throttle=0.4)
    path.write_text('[vehicle]\nframe = "h"\n', encoding="utf-8")
    with pytest.raises(VehicleFileError, match="frame"):
        load_vehicle(path)
