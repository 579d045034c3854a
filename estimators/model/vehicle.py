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


#: rotor layouts: ``x`` motors at 45 degrees to the body axes, ``+`` motors on the axes
FRAMES = ("x", "+")


class VehicleFileError(UserError, ValueError):
    """A vehicle description file is missing, unreadable or holds an invalid value (one-line message)."""


#: Physically plausible range of each constant (inclusive, SI), from a 10 g micro quadrotor to a 100 kg heavy-lift
#: multirotor, so that a typo (a mass in grams, a length in millimetres, 1e300) is refused with its limit instead
#: of producing a controller with absurd gains. gravity covers the Moon (1.62) to well beyond Earth's 9.78-9.83.
PLAUSIBLE: dict[str, tuple[float, float, str]] = {
    "mass_vehicle": (0.01, 100.0, "kg"),
    "mass_load": (0.0, 50.0, "kg"),
    "cable_length": (0.05, 30.0, "m"),  # 30 m: the longest line flown (docs/model.md, lines 0.5-30 m)
    "gravity": (1.0, 30.0, "m/s^2"),
    "arm_length": (0.01, 5.0, "m"),
    "yaw_moment_coefficient": (1e-4, 0.5, "m"),
    "motor_thrust_max": (0.01, 2000.0, "N"),
    "motor_time_constant": (0.0, 1.0, "s"),
    "linear_drag": (0.0, 100.0, "N/(m/s)"),
    "angular_drag": (0.0, 10.0, "N m/(rad/s)"),
}
INERTIA_RANGE = (1e-6, 100.0)  # kg m^2, each principal moment


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
    linear_drag: aerodynamic drag on the vehicle, a force ``-linear_drag * v`` (N per m/s, world frame, still air),
        e.g. PX4 SIH's SIH_KDV; the plants apply it (the emulator's, ``slung sim`` / compare / sweep's,
        ``sim_bridge.plant.dynamics.apply_drag``), the controllers and filters do not model it.
    angular_drag: aerodynamic damping of the rotation, a torque ``-angular_drag * w`` (N m per rad/s, body axes),
        e.g. PX4 SIH's SIH_KDW; applied and not modelled alike.
    frame: ``"x"`` (motors at 45 degrees to the roll and pitch axes, the default) or ``"+"`` (motors on the axes).
    hover_throttle: the autopilot's normalized throttle at hover with this load (PX4 MPC_THR_HOVER, ArduPilot
        MOT_THST_HOVER learnt in flight), 0..1, or None (unknown: the autopilot's parameter, or the physical
        ``hover_thrust_normalized``). It differs from the thrust fraction when the throttle curve is not linear
        (ArduPilot's MOT_THST_EXPO).
    gains: controller gains set by hand in the file's ``[gains]`` table, (name, value) pairs; the controller that
        reads them checks the names (``offboard.control.smc_attitude.GAIN_NAMES``); empty: every gain derived.
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
    linear_drag: float = 0.0
    angular_drag: float = 0.0
    frame: str = "x"
    hover_throttle: float | None = None
    gains: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        self._check_finite()
        for key, (lo, hi, unit) in PLAUSIBLE.items():
            value = getattr(self, key)
            if not (lo <= value <= hi):
                raise VehicleFileError(
                    f"vehicle {key} = {value!r} {unit} is outside the plausible range {lo:g}..{hi:g} {unit}"
                )
        lo, hi = INERTIA_RANGE
        if not all(lo <= i <= hi for i in self.inertia):
            raise VehicleFileError(
                f"vehicle inertia {self.inertia!r} kg m^2 is outside the plausible range {lo:g}..{hi:g} kg m^2"
            )
        if self.thrust_max <= self.total_mass * self.gravity:
            raise VehicleFileError(
                f"vehicle cannot hover: 4 x motor_thrust_max = {self.thrust_max:.3g} N is not above the weight "
                f"{self.total_mass * self.gravity:.3g} N"
            )

    def _check_finite(self) -> None:
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
        for key in ("motor_time_constant", "linear_drag", "angular_drag"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0.0):
                raise VehicleFileError(f"vehicle {key} must be a finite number >= 0, got {value!r}")
        if self.frame not in FRAMES:
            raise VehicleFileError(f"vehicle frame must be one of {', '.join(FRAMES)}, got {self.frame!r}")
        h = self.hover_throttle
        if h is not None and (isinstance(h, bool) or not isinstance(h, (int, float)) or not 0.0 < h < 1.0):
            raise VehicleFileError(f"vehicle hover_throttle must be a number in (0, 1), got {h!r}")
        if len(self.inertia) != 3 or not all(math.isfinite(i) and i > 0 for i in self.inertia):
            raise VehicleFileError(f"vehicle inertia must be three finite numbers > 0, got {self.inertia!r}")

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
    def moment_arm(self) -> float:
        """Perpendicular distance from a motor to the roll (and pitch) axis, m: ``d / sqrt(2)`` for an X frame,
        ``d`` for the two motors on the other axis of a + frame."""
        return self.arm_length / math.sqrt(2.0) if self.frame == "x" else self.arm_length

    @property
    def roll_pitch_torque_max(self) -> float:
        """Largest roll or pitch torque the mixer can give around hover, N m.

        X frame (motors at 45 degrees on an arm of length d): a roll torque moves two motors up and two down by
        df each, tau = 4 df d / sqrt(2). + frame: only the two motors off the roll axis act, tau = 2 df d. The
        margin df is the smaller of the headroom above and below hover.
        """
        f_hover = self.hover_thrust / 4.0
        df = min(f_hover, self.motor_thrust_max - f_hover)
        return (4.0 if self.frame == "x" else 2.0) * df * self.moment_arm

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
    ("vehicle", "linear_drag_n_s_m"): "linear_drag",
    ("vehicle", "angular_drag_n_m_s_rad"): "angular_drag",
    ("vehicle", "frame"): "frame",
    ("vehicle", "hover_throttle"): "hover_throttle",
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
        if section == "gains":  # free names, checked by the controller; values must be finite numbers > 0
            gains = []
            for key, value in table.items():
                off = key == "wn_d" and value == 0  # the disturbance observer's pole: 0 switches it off
                if (
                    isinstance(value, bool)
                    or not isinstance(value, (int, float))
                    or not (math.isfinite(value) and (value > 0 or off))
                ):
                    raise VehicleFileError(f"{source}: gains.{key} must be a finite number > 0, got {value!r}")
                gains.append((str(key), float(value)))
            kwargs["gains"] = tuple(sorted(gains))
            continue
        for key, value in table.items():
            attr = _TOML_KEYS.get((section, key))
            if attr is None:
                known = ", ".join(f"{s}.{k}" for s, k in _TOML_KEYS)
                raise VehicleFileError(f"{source}: unknown key {section}.{key} (known: {known})")
            if attr in ("name", "frame"):
                if not isinstance(value, str):
                    raise VehicleFileError(f"{source}: vehicle.{key} must be a string")
                kwargs[attr] = value
            elif attr == "inertia":
                if not (isinstance(value, list) and len(value) == 3):
                    raise VehicleFileError(f"{source}: vehicle.inertia_kg_m2 must be a list of three numbers")
                try:
                    kwargs[attr] = tuple(float(v) for v in value)
                except (TypeError, ValueError):
                    raise VehicleFileError(f"{source}: vehicle.inertia_kg_m2 must be numbers, got {value!r}") from None
            else:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise VehicleFileError(f"{source}: {section}.{key} must be a number, got {value!r}")
                kwargs[attr] = float(value)
    try:
        return Vehicle(**kwargs)
    except VehicleFileError as exc:
        raise VehicleFileError(f"{source}: {exc}") from None


#: the vehicle files shipped with the package (``--vehicle NAME``), in ``estimators/model/vehicles/NAME.toml``
VEHICLES_DIR = Path(__file__).resolve().parent / "vehicles"


def named_vehicles() -> list[str]:
    """Names of the shipped vehicle files (``paper-table1``, ``px4-sih``, ``ardupilot-sitl-quad``, ...)."""
    return sorted(p.stem for p in VEHICLES_DIR.glob("*.toml"))


def load_vehicle(path: str | Path | None) -> Vehicle:
    """Read a vehicle description (TOML file, or the name of a shipped one, :func:`named_vehicles`); ``None``
    gives the paper's Table 1 vehicle. A file that exists wins over a shipped name."""
    if path is None:
        return Vehicle()
    p = Path(path)
    if not p.exists() and p.suffix == "" and (VEHICLES_DIR / f"{p.name}.toml").is_file() and str(p) == p.name:
        p = VEHICLES_DIR / f"{p.name}.toml"
    elif not p.exists() and p.suffix == "" and str(p) == p.name:
        raise VehicleFileError(
            f"no vehicle file {p} and no shipped vehicle of that name (shipped: {', '.join(named_vehicles())})"
        )
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise VehicleFileError(f"cannot read vehicle file {p}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise VehicleFileError(
            f"vehicle file {p} is not UTF-8 text (byte {exc.start}: {exc.object[exc.start : exc.start + 1]!r})"
        ) from None
    return vehicle_from_toml(text, source=str(p))


def vehicle_from_toml(text: str, source: str = "vehicle file") -> Vehicle:
    """A vehicle from the text of a vehicle file (:func:`vehicle_to_toml`'s, or a user's); VehicleFileError
    naming ``source`` when it is not valid TOML or not a valid vehicle."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise VehicleFileError(f"vehicle file {source} is not valid TOML: {exc}") from None
    return vehicle_from_mapping(data, source=source)


def vehicle_to_toml(v: Vehicle) -> str:
    """Serialize a vehicle to the TOML format :func:`load_vehicle` reads (round-trips exactly)."""
    sections: dict[str, list[str]] = {}
    for (section, key), attr in _TOML_KEYS.items():
        value = getattr(v, attr)
        if value is None:  # optional and unknown: left out
            continue
        if isinstance(value, str):
            text = f'"{value}"'
        elif isinstance(value, tuple):
            text = "[" + ", ".join(repr(float(x)) for x in value) + "]"
        else:
            text = repr(float(value))
        sections.setdefault(section, []).append(f"{key} = {text}")
    if v.gains:
        sections["gains"] = [f"{k} = {float(val)!r}" for k, val in v.gains]
    return "\n\n".join(f"[{s}]\n" + "\n".join(lines) for s, lines in sections.items()) + "\n"


__all__ = [
    "FRAMES",
    "VEHICLES_DIR",
    "Vehicle",
    "VehicleFileError",
    "load_vehicle",
    "named_vehicles",
    "vehicle_from_mapping",
    "vehicle_from_toml",
    "vehicle_to_toml",
]
