"""Vehicle description: the physical constants of a quadrotor carrying a cable-suspended load.

One TOML file describes one vehicle; the emulator (``sim_bridge``), the controller (``offboard``) and the
estimators all read it through this module. It lives in ``estimators`` because that package is the bottom
layer that every other package may import (``estimators`` imports neither ``offboard`` nor ``sim_bridge``).

The built-in default is the vehicle of the paper's Table 1 (M = 0.5 kg, m_c = 0.2 kg, l = 0.3 m,
g = 9.8 m/s^2, I = 0.1 kg m^2 on each axis). The paper gives no arm length, motor limits or yaw-moment
coefficient; the defaults below are those of a typical 0.5 kg, 250-350 mm class quadrotor and are documented
with their reasons in ``docs/model.md``.

All quantities are SI. Keys in the file carry their unit in the name (``mass_kg``, ``cable_length_m``).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from estimators.errors import UserError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on Python 3.10
    import tomli as tomllib


class VehicleFileError(UserError, ValueError):
    """A vehicle description file is missing, unreadable or holds an invalid value (one-line message)."""


@dataclass(frozen=True)
class Vehicle:
    """Physical constants of the quadrotor + load system (SI units).

    Attributes
    ----------
    name: label for reports.
    mass_vehicle: quadrotor mass M, kg.
    mass_load: load mass m_c, kg (0 for a vehicle without a load).
    cable_length: cable length l, m (rigid, massless, attached at the vehicle's centre of mass).
    gravity: g, m/s^2 (the paper uses 9.8).
    inertia: (I_phi, I_theta, I_psi), kg m^2, principal moments about body roll, pitch, yaw axes.
    arm_length: distance d from the centre to each motor, m (X configuration, motors at 45 degrees).
    yaw_moment_coefficient: reaction torque per newton of rotor thrust, m (N m / N).
    motor_thrust_max: maximum thrust of one motor, N.
    motor_time_constant: first-order lag of a motor's thrust, s.
    """

    name: str = "paper-table1"
    mass_vehicle: float = 0.5
    mass_load: float = 0.2
    cable_length: float = 0.3
    gravity: float = 9.8
    inertia: tuple[float, float, float] = (0.1, 0.1, 0.1)
    arm_length: float = 0.17
    yaw_moment_coefficient: float = 0.016
    motor_thrust_max: float = 4.0
    motor_time_constant: float = 0.02

    def __post_init__(self) -> None:
        positive = {
            "mass_vehicle": self.mass_vehicle,
            "cable_length": self.cable_length,
            "gravity": self.gravity,
            "arm_length": self.arm_length,
            "yaw_moment_coefficient": self.yaw_moment_coefficient,
            "motor_thrust_max": self.motor_thrust_max,
        }
        for key, value in positive.items():
            if not (math.isfinite(value) and value > 0.0):
                raise VehicleFileError(f"vehicle {key} must be a finite number > 0, got {value!r}")
        if not (math.isfinite(self.mass_load) and self.mass_load >= 0.0):
            raise VehicleFileError(f"vehicle mass_load must be a finite number >= 0, got {self.mass_load!r}")
        if not (math.isfinite(self.motor_time_constant) and self.motor_time_constant >= 0.0):
            raise VehicleFileError(
                f"vehicle motor_time_constant must be a finite number >= 0, got {self.motor_time_constant!r}"
            )
        if len(self.inertia) != 3 or not all(math.isfinite(i) and i > 0 for i in self.inertia):
            raise VehicleFileError(f"vehicle inertia must be three finite numbers > 0, got {self.inertia!r}")
        if self.thrust_max <= self.total_mass * self.gravity:
            raise VehicleFileError(
                f"vehicle cannot hover: 4 x motor_thrust_max = {self.thrust_max:.3g} N is not above the weight "
                f"{self.total_mass * self.gravity:.3g} N"
            )

    # Derived constants -------------------------------------------------------------------------------
    @property
    def total_mass(self) -> float:
        """M + m_c, kg."""
        return self.mass_vehicle + self.mass_load

    @property
    def thrust_max(self) -> float:
        """Maximum collective thrust, N (four motors at full thrust)."""
        return 4.0 * self.motor_thrust_max

    @property
    def hover_thrust(self) -> float:
        """Collective thrust that holds the vehicle and its load at rest, (M + m_c) g, N."""
        return self.total_mass * self.gravity

    @property
    def hover_thrust_normalized(self) -> float:
        """Hover thrust as a fraction of the maximum, 0..1 (PX4's MPC_THR_HOVER, ArduPilot's MOT_THST_HOVER)."""
        return self.hover_thrust / self.thrust_max

    @property
    def roll_pitch_torque_max(self) -> float:
        """Largest roll or pitch torque the X mixer can give around hover, N m.

        With motors at 45 degrees on an arm of length d, a roll torque moves two motors up and two down by
        df each: tau = 4 df d / sqrt(2). The margin df is the smaller of the headroom above and below hover.
        """
        f_hover = self.hover_thrust / 4.0
        df = min(f_hover, self.motor_thrust_max - f_hover)
        return 4.0 * df * self.arm_length / math.sqrt(2.0)

    @property
    def yaw_torque_max(self) -> float:
        """Largest yaw torque around hover, N m (two motors up, two down, by the same margin)."""
        f_hover = self.hover_thrust / 4.0
        df = min(f_hover, self.motor_thrust_max - f_hover)
        return 4.0 * df * self.yaw_moment_coefficient

    @property
    def pendulum_frequency(self) -> float:
        """Natural frequency of the swing with the vehicle free, sqrt((M + m) g / (M l)), rad/s."""
        return math.sqrt(self.total_mass * self.gravity / (self.mass_vehicle * self.cable_length))

    def with_changes(self, **changes: Any) -> Vehicle:
        """A copy with some constants changed (e.g. a mismatched nominal model for robustness studies)."""
        return replace(self, **changes)


#: TOML key (with its unit) -> Vehicle attribute. The file's keys are the public contract.
_TOML_KEYS: dict[tuple[str, str], str] = {
    ("vehicle", "name"): "name",
    ("vehicle", "mass_kg"): "mass_vehicle",
    ("vehicle", "inertia_kg_m2"): "inertia",
    ("vehicle", "arm_length_m"): "arm_length",
    ("vehicle", "yaw_moment_coefficient_m"): "yaw_moment_coefficient",
    ("vehicle", "motor_thrust_max_n"): "motor_thrust_max",
    ("vehicle", "motor_time_constant_s"): "motor_time_constant",
    ("load", "mass_kg"): "mass_load",
    ("load", "cable_length_m"): "cable_length",
    ("environment", "gravity_m_s2"): "gravity",
}


def vehicle_from_mapping(data: dict[str, Any], source: str = "vehicle file") -> Vehicle:
    """Build a :class:`Vehicle` from a parsed TOML mapping; unknown keys and bad values are errors."""
    kwargs: dict[str, Any] = {}
    for section, table in data.items():
        if not isinstance(table, dict):
            raise VehicleFileError(f"{source}: [{section}] must be a table")
        for key, value in table.items():
            attr = _TOML_KEYS.get((section, key))
            if attr is None:
                known = ", ".join(f"{s}.{k}" for s, k in _TOML_KEYS)
                raise VehicleFileError(f"{source}: unknown key {section}.{key} (known: {known})")
            if attr == "name":
                if not isinstance(value, str):
                    raise VehicleFileError(f"{source}: vehicle.name must be a string")
                kwargs[attr] = value
            elif attr == "inertia":
                if not (isinstance(value, list) and len(value) == 3):
                    raise VehicleFileError(f"{source}: vehicle.inertia_kg_m2 must be a list of three numbers")
                try:
                    kwargs[attr] = tuple(float(v) for v in value)
                except (TypeError, ValueError):
                    raise VehicleFileError(
                        f"{source}: vehicle.inertia_kg_m2 must be numbers, got {value!r}"
                    ) from None
            else:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise VehicleFileError(f"{source}: {section}.{key} must be a number, got {value!r}")
                kwargs[attr] = float(value)
    try:
        return Vehicle(**kwargs)
    except VehicleFileError as exc:
        raise VehicleFileError(f"{source}: {exc}") from None


def load_vehicle(path: str | Path | None) -> Vehicle:
    """Read a vehicle description (TOML); ``None`` gives the paper's Table 1 vehicle."""
    if path is None:
        return Vehicle()
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise VehicleFileError(f"cannot read vehicle file {p}: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise VehicleFileError(f"vehicle file {p} is not valid TOML: {exc}") from None
    return vehicle_from_mapping(data, source=str(p))


def vehicle_to_toml(v: Vehicle) -> str:
    """Serialize a vehicle to the TOML format :func:`load_vehicle` reads (round-trips exactly)."""
    sections: dict[str, list[str]] = {}
    for (section, key), attr in _TOML_KEYS.items():
        value = getattr(v, attr)
        if isinstance(value, str):
            text = f'"{value}"'
        elif isinstance(value, tuple):
            text = "[" + ", ".join(repr(float(x)) for x in value) + "]"
        else:
            text = repr(float(value))
        sections.setdefault(section, []).append(f"{key} = {text}")
    return "\n\n".join(f"[{s}]\n" + "\n".join(lines) for s, lines in sections.items()) + "\n"


__all__ = [
    "Vehicle",
    "VehicleFileError",
    "load_vehicle",
    "vehicle_from_mapping",
    "vehicle_to_toml",
]
