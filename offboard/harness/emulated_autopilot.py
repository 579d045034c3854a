"""What ``slung fly`` reads from the bundled emulator's autopilot for a vehicle, without the wire.

``slung fly`` derives the attitude-level law's gains from the inner loops it reads from the autopilot's parameters
(``Manager.read_autopilot_model``, then ``attitude_mapping.inner_loop_of``). ``slung compare`` flies that law in
process through the emulator's PX4 loops (``sim_bridge.inner.px4_attitude_path``), whose parameters are the
emulator's PX4 flavour for the vehicle (``sim_bridge.modes.flavors.px4_params``: MC_ROLL_P 4, the stock rate gains
scaled to the vehicle's inertia and unit torque). The law it flies there must be the one ``slung fly`` would fly
against the same loops: the same parameters, read by the same function
(``autopilot_model.autopilot_model_from_params``), give the same model. Without it the row was designed for
:class:`~offboard.control.smc_attitude.InnerLoop`'s generic defaults (rate bandwidth 10 1/s where the loops it met
have 17 on the paper's vehicle), took the design's slow fallback gains, and tracked 0.95 m RMS in process against
0.025-0.048 m over MAVLink (docs/compare.md).
"""

from __future__ import annotations

from estimators.model.vehicle import Vehicle
from offboard.control.smc_attitude import InnerLoop
from offboard.flight.attitude_mapping import inner_loop_of
from offboard.flight.link.autopilot_model import AutopilotModel, autopilot_model_from_params
from offboard.flight.px4_allocation import unit_torques_from_params


def emulated_autopilot_model(vehicle: Vehicle, flavour: str = "px4") -> AutopilotModel:
    """The :class:`AutopilotModel` that ``slung fly`` reads from the emulator's ``flavour`` (px4 / ardupilot) for
    ``vehicle``: its parameter table's defaults, no parameter changed."""
    from sim_bridge.modes.flavors import ap_params, px4_params

    table = px4_params(vehicle) if flavour == "px4" else ap_params(vehicle)
    values = {name: float(p.value) for name, p in table.items()}
    get = values.get
    unit = unit_torques_from_params(get, vehicle) if flavour == "px4" else None
    return autopilot_model_from_params(flavour, get, vehicle, unit)


def emulated_inner_loop(vehicle: Vehicle, flavour: str = "px4") -> InnerLoop:
    """The attitude-level law's inner-loop model for the emulator's ``flavour`` loops on ``vehicle`` (as ``slung
    fly`` derives it from what it reads)."""
    return inner_loop_of(emulated_autopilot_model(vehicle, flavour))


__all__ = ["emulated_autopilot_model", "emulated_inner_loop"]
