"""The records of a closed-loop run, shared by every driver: the scenario, the run's configuration and its log.

Plant-free on purpose: ``slung sim`` (``offboard.harness.sim``), ``slung fly`` / ``slung demo``
(``offboard.flight.fly_cli``), ``offboard.report.metrics`` and ``offboard.report.report`` all read and write these
records, and the live flight path must not load the simulator (``sim_bridge``): the controller and the emulator meet
only on the MAVLink wire. Nothing here imports ``sim_bridge``; the simulation harness (``offboard.harness.sim``) builds
the plant-side parts of a scenario (initial plant state, disturbances) from the plain numbers in :class:`PlantSetup`.

Units: SI, radians, model frame (world NWU z up, body FLU, ZYX Euler angles).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from estimators.model.control_state import RIGID_BODY_NAMES
from estimators.model.vehicle import Vehicle
from offboard.logs.estimate_columns import SIGMA_COLUMNS


class ReferenceLike(Protocol):
    """What the loops need of a reference (``offboard.control.reference``)."""

    def sample(self, t: float) -> Any: ...


#: disturbance(t) -> (force on vehicle xyz N world, force on load xyz N world, torque xyz N m body)
Disturbance = Callable[[float], tuple[float, ...]]


@dataclass(frozen=True)
class PlantSetup:
    """The simulation part of a named scenario as plain numbers, for the simulation harness only (a live flight
    starts wherever the vehicle is and meets whatever wind there is).

    position: vehicle position at t = 0 (m, world NWU); cable: direction vehicle -> load at t = 0 (any non-zero
    length, world); cable_rate: its rate (1/s; made tangent to the sphere by the plant); heading: initial yaw
    (rad); velocity, roll, pitch and body rates start at 0. disturbance: ``None`` or ``"paper"``
    (``sim_bridge.plant.disturbances``' bounded random forces and yaw torque, default bounds, onset at the scenario's
    ``disturbance_start``); seed: its seed.
    """

    position: tuple[float, float, float]
    cable: tuple[float, float, float] = (0.0, 0.0, -1.0)
    cable_rate: tuple[float, float, float] = (0.0, 0.0, 0.0)
    disturbance: str | None = None
    seed: int = 0
    heading: float = 0.0


@dataclass
class Scenario:
    """A named closed-loop experiment: reference, duration and, for simulation, the plant's start (SI units).

    The reference part (name, description, duration, reference, disturbance_start, arrival_time) is all that a
    live flight, a replay, the metrics and the report use. The simulation part: ``initial_state``, the 18-float
    plant state (``sim_bridge.plant.dynamics``), and ``disturbance``, a callable; a named scenario gives them as plain
    numbers in ``setup`` instead, and the simulation harness (``offboard.harness.sim.plant_scenario``) builds them.
    arrival_time: for point-to-point scenarios, the time at which the reference comes to rest (residual swing
    and settling are measured after it). disturbance_start: time at which disturbances begin (metrics report
    errors after it).
    """

    name: str
    description: str
    duration: float
    reference: ReferenceLike
    initial_state: list[float] | None = None
    disturbance: Disturbance | None = None
    disturbance_start: float | None = None
    arrival_time: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    setup: PlantSetup | None = None


@dataclass(frozen=True)
class SimConfig:
    """How to run a scenario.

    plant_dt: RK4 step (s); control_rate: controller rate (Hz), plant_dt must divide its period;
    attitude_model: ``"paper"`` (eq. (13), reproduces the paper) or ``"rigid"``;
    sensors: ``None`` for the true state, else a preset of ``sim_bridge.plant.sensors``; estimator: ``"truth"``
    or ``"kf"``; load_sensor: whether a cable-angle sensor is fitted; seed: seeds sensors and disturbances;
    actuators: ``"ideal"`` (the commanded thrust and torques act on the plant, as in the paper) or ``"mixer"``
    (they go through the emulator's X mixer: four motors limited to [0, motor_thrust_max] with roll / pitch
    priority and first-order lag) or ``"px4"`` (PX4's control allocator with its sequential desaturation, airmode
    off, and SIH-like motors: what a torque command sent with ``--output actuator`` meets on PX4 and on the
    emulator's PX4 flavour, ``sim_bridge.inner.px4_inner.Px4ActuatorPath``) or ``"px4-attitude"`` (the
    attitude-level law's attitude and thrust setpoint through PX4's attitude P, rate PID, allocator and motors,
    ``sim_bridge.inner.px4_attitude_path.Px4AttitudePath``: how ``slung compare`` flies ``smc-attitude``).
    """

    plant_dt: float = 0.001
    control_rate: float = 1000.0
    attitude_model: str = "paper"
    sensors: str | None = None
    estimator: str = "truth"
    load_sensor: bool = True
    seed: int = 0
    actuators: str = "ideal"


# Columns of the log, in order. Units: SI, radians, model frame (world NWU z up).
LOG_COLUMNS: tuple[str, ...] = (
    "t",
    *RIGID_BODY_NAMES,
    "r1",
    "r2",
    "r3",
    "r1_rate",
    "r2_rate",
    "r3_rate",
    "alpha",
    "beta",
    "alpha_x",
    "alpha_y",
    "Fx",
    "Fy",
    "Fx_ref",
    "Fy_ref",
    "z_ref",
    "psi_ref",
    "Fx_ref_rate",
    "Fy_ref_rate",
    "z_ref_rate",
    "psi_ref_rate",
    "e_Fx",
    "e_Fy",
    "e_z",
    "e_psi",
    "u",
    "tau_phi",
    "tau_theta",
    "tau_psi",
    "s_z",
    "s_psi",
    "sigma_x",
    "sigma_y",
    "saturated",
    "tension",
    "dist_fx",
    "dist_fy",
    "dist_fz",
    "dist_tpsi",
    "load_x",
    "load_y",
    "load_z",
    # estimate minus truth (zero when the controller runs on the true state)
    "est_alpha_x",
    "est_alpha_y",
    "est_alpha_x_rate",
    "est_alpha_y_rate",
    "est_Fx0",
    "est_Fx1",
    "est_Fx2",
    "est_Fx3",
    "est_Fx4",
    "est_Fx5",
    "est_Fy0",
    "est_Fy1",
    "est_Fy2",
    "est_Fy3",
    "est_Fy4",
    "est_Fy5",
    "est_z",
    "est_psi",
    "nees",
    # the filter's standard deviations of the estimate (``offboard.logs.estimate_columns``; NaN without a filter)
    *SIGMA_COLUMNS,
)
COL = {name: i for i, name in enumerate(LOG_COLUMNS)}


@dataclass
class SimLog:
    """The logged run: ``data[k, COL[name]]`` at controller tick k, plus run facts."""

    data: np.ndarray
    scenario: Scenario
    config: SimConfig
    vehicle: Vehicle
    wall_time: float
    slack_steps: int
    min_tension: float
    estimator_stats: dict[str, int] = field(default_factory=dict)

    def column(self, name: str) -> np.ndarray:
        """One logged signal over time."""
        return self.data[:, COL[name]]
