"""PX4's control allocator, as far as the setpoints need it: the physical torque of a unit normalized torque.

PX4's rate controller outputs roll / pitch / yaw torque in normalized units; its control allocator
(``control_allocator``, ``ControlAllocationPseudoInverse``) turns them into motor commands 0..1 with the
pseudo-inverse of the effectiveness matrix built from the ``CA_ROTOR*`` parameters, then **normalizes** that mix:
roll and pitch columns by ``sqrt(|column|^2 / (n_nonzero / 2))`` (the larger of the two), yaw by its largest
entry, thrust by the mean norm of the rotors' thrust rows. The unit torque therefore depends on the rotor layout
in the parameters, not on the vehicle's physical hover margin: for a symmetric X quad (positions +-1) a unit roll
torque moves each motor by 1/sqrt(2) of its range, i.e. ``4 / sqrt(2) T_max a`` newton-metres for motors of
``T_max`` N at a perpendicular arm ``a`` (PX4 SITL's SIH: 2.83 N m, where the hover-margin torque the vehicle file
gives is 1.96 N m), and a unit yaw torque moves each by its whole range.

Rotor i of the parameters: position ``(PX, PY)`` (any unit: only the layout matters, the physical lever arms come
from the vehicle file's ``moment_arm``), thrust coefficient ``CT``, moment ratio ``KM`` (sign = spin direction),
axis straight up. Effectiveness column: ``(-CT PY, CT PX, CT KM, 0, 0, -CT)`` (roll, pitch, yaw, thrust x, y, z;
FRD). No PX4 code is copied; the normalization rules are restated from its source (2026).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from estimators.model.vehicle import Vehicle


@dataclass(frozen=True)
class Rotor:
    """One ``CA_ROTORn_*`` entry: position (PX forward, PY right; normalized or m), CT, KM."""

    px: float
    py: float
    ct: float = 6.5
    km: float = 0.05


def normalized_mix(rotors: list[Rotor]) -> np.ndarray:
    """PX4's normalized allocation matrix (n x 6: roll, pitch, yaw, thrust x, y, z -> motor commands)."""
    if not rotors:
        raise ValueError("no rotors")
    b = np.zeros((6, len(rotors)))
    for i, r in enumerate(rotors):
        b[:, i] = (-r.ct * r.py, r.ct * r.px, r.ct * r.km, 0.0, 0.0, -r.ct)
    mix = np.linalg.pinv(b)
    nz_roll = int(np.sum(np.abs(mix[:, 0]) > 1e-3))
    nz_pitch = int(np.sum(np.abs(mix[:, 1]) > 1e-3))
    roll_s = math.sqrt(float(mix[:, 0] @ mix[:, 0]) / (nz_roll / 2.0)) if nz_roll else 1.0
    pitch_s = math.sqrt(float(mix[:, 1] @ mix[:, 1]) / (nz_pitch / 2.0)) if nz_pitch else 1.0
    rp = max(roll_s, pitch_s)
    yaw = float(np.max(mix[:, 2]))
    norms = np.linalg.norm(mix[:, 3:6], axis=1)
    nz_thrust = int(np.sum(norms > 1e-7))
    thrust = float(np.sum(norms)) / nz_thrust if nz_thrust else 1.0
    out = mix.copy()
    if rp > 1e-7:
        out[:, 0:2] /= rp
    if yaw > 1e-7:
        out[:, 2] /= yaw
    if thrust > 1e-7:
        out[:, 3:6] /= thrust
    out[np.abs(out) < 1e-3] = 0.0
    return out


def unit_torques(rotors: list[Rotor], vehicle: Vehicle) -> tuple[float, float, float]:
    """Physical torque (N m, roll, pitch, yaw) of a unit normalized torque through PX4's allocator, for motors of
    the vehicle file's ``motor_thrust_max`` (thrust linear in the command, THR_MDL_FAC 0) whose roll / pitch lever
    arms are the parameters' positions scaled so that the largest is the vehicle file's ``moment_arm``, and whose
    reaction torque is ``yaw_moment_coefficient`` newton-metres per newton."""
    mix = normalized_mix(rotors)
    lever = max(max(abs(r.px), abs(r.py)) for r in rotors)
    if lever <= 0.0:
        raise ValueError("rotor positions are all zero")
    s = vehicle.moment_arm / lever
    tmax = vehicle.motor_thrust_max
    roll = sum(mix[i, 0] * tmax * (-r.py * s) for i, r in enumerate(rotors))
    pitch = sum(mix[i, 1] * tmax * (r.px * s) for i, r in enumerate(rotors))
    yaw = sum(
        mix[i, 2] * tmax * vehicle.yaw_moment_coefficient * math.copysign(1.0, r.km) for i, r in enumerate(rotors)
    )
    return float(abs(roll)), float(abs(pitch)), float(abs(yaw))


def unit_torques_from_params(get: Callable[[str], float | None], vehicle: Vehicle) -> tuple[float, float, float] | None:
    """:func:`unit_torques` for the rotors that PX4's parameters describe: ``get(name)`` reads a parameter (None:
    no answer) for CA_ROTOR_COUNT and CA_ROTORn_PX / PY / CT / KM. None when they do not all answer or describe no
    allocation (PX4 <= v1.13's mixers have no such parameters)."""
    n = get("CA_ROTOR_COUNT")
    if n is None or not math.isfinite(n) or not (1 <= int(n) <= 12):
        return None
    rotors = []
    for i in range(int(n)):
        vals = [get(f"CA_ROTOR{i}_{k}") for k in ("PX", "PY", "CT", "KM")]
        if any(v is None or not math.isfinite(v) for v in vals):
            return None
        px, py, ct, km = (float(v) for v in vals)  # type: ignore[arg-type]
        rotors.append(Rotor(px, py, ct, km))
    try:
        return unit_torques(rotors, vehicle)
    except (ValueError, np.linalg.LinAlgError):
        return None


__all__ = ["Rotor", "normalized_mix", "unit_torques", "unit_torques_from_params"]
