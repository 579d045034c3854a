"""In-process closed loop: plant (``sim_bridge``) + sensors + estimator + the sliding-mode controller.

The loop is the same as the live one minus the wire: at each controller tick the one tick of every driver
(:class:`offboard.control.tick.ControlTick`) takes the estimate (true state, or a Kalman filter fed by the sensor
models) and the reference to the controller (the sliding-mode law :func:`offboard.control.smc.step` unless another
``offboard.control.controllers`` law is given), whose command is held (zero-order hold) while the plant is integrated
with fixed-step RK4 at its own, finer or equal, step.

Everything is logged at the controller rate into preallocated arrays (:class:`SimLog`), from which
``offboard.report.metrics`` computes the figures and ``offboard.report.report`` draws them.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from estimators.model.control_state import ControlState
from estimators.model.flatness import FlatConstants, flat_constants, truth_control_state
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.controllers.protocol import Controller
from offboard.control.controllers.sliding_mode import SlidingModeController
from offboard.control.tick import ActuatorLag, ControlTick
from offboard.logs.estimate_columns import SIGMA_COLUMNS
from offboard.logs.runlog import COL, LOG_COLUMNS, Disturbance, PlantSetup, ReferenceLike, Scenario, SimConfig, SimLog
from sim_bridge.plant import dynamics
from sim_bridge.plant.dynamics import apply_drag

# The run records live in the plant-free ``offboard.logs.runlog`` (the live flight path reads them without loading the
# simulator); they are re-exported here for the simulation's users.
__all__ = [
    "COL",
    "LOG_COLUMNS",
    "Disturbance",
    "PlantSetup",
    "ReferenceLike",
    "Scenario",
    "SimConfig",
    "SimLog",
    "plant_scenario",
    "run",
    "truth_control_state",
]

_LOG = logging.getLogger(__name__)
_DEFAULT_CONFIG = SimConfig()  # frozen: safe as a default argument
_SD0 = COL[SIGMA_COLUMNS[0]]  # the filter's standard deviations in a log row


def plant_scenario(scenario: Scenario) -> Scenario:
    """``scenario`` with its simulation part built: the initial plant state and the disturbance from the plain
    numbers of ``scenario.setup`` (``offboard.logs.runlog.PlantSetup``), unless the scenario already carries an
    ``initial_state``. The named scenarios (``offboard.control.scenarios``) are plant-free; this is where the plant's
    side of them is made. ValueError for a scenario with neither."""
    if scenario.initial_state is not None:
        return scenario
    s = scenario.setup
    if s is None:
        raise ValueError(f"scenario {scenario.name!r} has no initial plant state and no plant setup")
    disturbance = scenario.disturbance
    if s.disturbance == "paper":
        from sim_bridge.plant.disturbances import DisturbanceSpec, RandomDisturbance

        start = scenario.disturbance_start
        spec = DisturbanceSpec() if start is None else DisturbanceSpec(start=start)
        disturbance = RandomDisturbance(spec, s.seed)
    elif s.disturbance is not None:
        raise ValueError(f"scenario {scenario.name!r}: unknown disturbance {s.disturbance!r} (known: paper)")
    state = dynamics.make_state(
        position=s.position, euler=(0.0, 0.0, s.heading), cable=s.cable, cable_rate=s.cable_rate
    )
    return replace(scenario, initial_state=state, disturbance=disturbance)


def run(
    scenario: Scenario,
    vehicle: Vehicle,
    params: smc.ControllerParams,
    config: SimConfig = _DEFAULT_CONFIG,
    progress: Callable[[float], None] | None = None,
    controller: Controller | None = None,
    sensor_preset: Any = None,
    command_lag: bool = False,
    tuning: Any = None,
) -> SimLog:
    """Simulate ``scenario`` with the true plant ``vehicle`` and controller ``params`` (whose nominal
    vehicle may differ, for robustness studies). ``controller``: the control law (default: the sliding-mode law
    with ``params``; ``params`` still gives the nominal vehicle the estimator and the truth state use). Returns
    the full log; never raises on divergence (the log then shows it), but stops early if the state becomes
    non-finite. A named scenario's simulation part (initial plant state, disturbances) is built here
    (:func:`plant_scenario`). ``sensor_preset``: a ``sim_bridge.plant.sensors.Preset`` used instead of the named
    ``config.sensors`` (a sweep scales the noise and latency). ``command_lag``: with motors, the filter is given
    the command through the nominal motor lag (``offboard.control.tick.ActuatorLag``), as in the live loop.
    ``tuning``: the filter's tuning (``estimators.filters.factory.make_estimator``; None: its defaults)."""
    scenario = plant_scenario(scenario)
    if not (config.plant_dt > 0 and config.control_rate > 0):
        raise ValueError("plant_dt and control_rate must be > 0")
    substeps = round(1.0 / (config.control_rate * config.plant_dt))
    if substeps < 1 or abs(substeps * config.plant_dt * config.control_rate - 1.0) > 1e-9:
        raise ValueError("the control period must be a whole number of plant steps")
    control_dt = substeps * config.plant_dt
    n_ticks = math.floor(scenario.duration / control_dt + 1e-9) + 1

    if config.actuators not in ("ideal", "mixer", "px4", "px4-attitude"):
        raise ValueError(f"unknown actuators {config.actuators!r} (ideal, mixer, px4 or px4-attitude)")
    p = dynamics.plant_params(vehicle, config.attitude_model)
    k_nominal = flat_constants(params.vehicle)
    k_true = flat_constants(vehicle)
    rng = np.random.default_rng(config.seed)

    sensors = None
    estimator = None
    if config.estimator != "truth" or config.sensors is not None:
        from sim_bridge.plant.sensors import SensorSuite  # the sensor models: only when asked for

        preset = sensor_preset if sensor_preset is not None else (config.sensors or "ideal")
        sensors = SensorSuite(preset, vehicle, rng, load_sensor=config.load_sensor)
    if config.estimator != "truth":
        from estimators.filters.factory import make_estimator

        estimator = make_estimator(
            config.estimator, params.vehicle, load_sensor=config.load_sensor, rate_hz=config.control_rate, tuning=tuning
        )

    data = np.full((n_ticks, len(LOG_COLUMNS)), np.nan)
    assert scenario.initial_state is not None  # plant_scenario built it
    x = list(scenario.initial_state)
    if controller is None:
        controller = SlidingModeController(params)
    controller.reset()
    # command_lag (the sweep's runs): with motors (mixer, px4) the filter is given what they deliver, the command
    # through the nominal motor lag, as the live loop gives it (offboard.control.tick.ActuatorLag): the measured-input
    # filter carries the tilt on the commanded acceleration, and the command itself ran it ahead of the vehicle by
    # the motors' lag, which with the telemetry's latency destabilized the sliding-mode law (docs/compare.md).
    # Otherwise the filter is given the command itself.
    lag = ActuatorLag(params.vehicle.motor_time_constant) if command_lag and config.actuators != "ideal" else None
    control_tick = ControlTick(controller, scenario.reference, estimator=estimator, lag=lag)
    dist = scenario.disturbance
    zero9 = (0.0,) * 9
    # Disturbances depend on time only: evaluate them for every tick at once (vectorized) when they can.
    dist_table = dist.sample_grid(np.arange(n_ticks) * control_dt).tolist() if hasattr(dist, "sample_grid") else None
    slack_steps = 0
    min_tension = math.inf
    if estimator is not None:
        estimator.initialize(0.0, truth_control_state(x, k_nominal))

    wall0 = time.perf_counter()
    t = 0.0
    rk4 = dynamics.rk4_step
    tension = dynamics.tension
    u = dynamics.hover_input(p)
    mixer = None
    if config.actuators == "mixer":
        from sim_bridge.inner.airframe import Mixer

        mixer = Mixer(vehicle, config.plant_dt)
        mixer.reset(0.25 * u[0])  # the motors start at hover
    elif config.actuators == "px4":  # PX4's allocator (airmode off) and motors, as behind --output actuator
        from sim_bridge.inner.px4_inner import Px4ActuatorPath

        mixer = Px4ActuatorPath(vehicle, config.plant_dt)
        mixer.reset(0.25 * u[0])
    att_path = None
    if config.actuators == "px4-attitude":  # the attitude setpoint through PX4's attitude P, rate PID, allocator
        from offboard.control.smc_attitude import AttitudeCommand
        from offboard.flight.command_mapping import MappingConfig
        from sim_bridge.inner.px4_attitude_path import Px4AttitudePath

        att_path = Px4AttitudePath(vehicle, config.plant_dt)
        att_path.reset(0.25 * u[0])
        max_tilt = MappingConfig().max_tilt
    drag = vehicle.linear_drag > 0.0 or vehicle.angular_drag > 0.0
    last_progress = 0
    for tick in range(n_ticks):
        t = tick * control_dt
        truth = truth_control_state(x, k_nominal)
        est, ref, _, _, _, cmd, _, _ = control_tick(t, t, None if estimator is not None else truth)
        if dist_table is not None:
            d: Any = dist_table[tick]
        elif dist is not None:
            d = dist(t)
        else:
            d = zero9
        u = [cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi, *d]
        _log_tick(data[tick], t, x, truth, est, ref, cmd, u, p, k_true, estimator)
        if mixer is not None:  # the plant feels the motors' wrench, not the command
            mixer.allocate(cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)
            u[0:4] = mixer.wrench()
        elif att_path is not None:  # the law's attitude setpoint, its tilt clipped as slung fly's mapping clips it
            if not isinstance(cmd, AttitudeCommand):
                raise ValueError("actuators 'px4-attitude' need the attitude-level law (an attitude setpoint)")
            phi_sp = min(max(cmd.phi_sp, -max_tilt), max_tilt)
            theta_sp = min(max(cmd.theta_sp, -max_tilt), max_tilt)
            att_path.set_setpoint(phi_sp, theta_sp, cmd.psi_sp, cmd.thrust)
            u[0:4] = att_path.wrench()
        tens = tension(x, u, p)
        data[tick, COL["tension"]] = tens
        if tick == n_ticks - 1:
            break
        if drag:  # the tick's disturbance on the vehicle alone, which the drag is added to at each plant step
            d_force, d_torque = d[0:3], d[6:9]
        for i in range(substeps):
            if mixer is not None:  # the motors' thrusts at the end of this plant step act over it (zero-order)
                u[0:4] = mixer.step()
            elif att_path is not None:
                u[0:4] = att_path.step(x)
            if drag:  # the vehicle file's still-air drag (SIH_KDV / SIH_KDW), as the emulator's plant feels it
                apply_drag(u, x, d_force, d_torque, vehicle.linear_drag, vehicle.angular_drag)
            x = rk4(x, u, p, config.plant_dt, t + i * config.plant_dt)
            tens = tension(x, u, p)
            if tens <= 0.0 and p.m > 0.0:  # no load (m = 0): no cable to go slack, the tension is 0 by definition
                if slack_steps == 0:
                    _LOG.warning(
                        "cable went slack at t = %.3f s (tension %.3f N): the rigid-cable model is not "
                        "valid while it is slack; the run continues and counts slack steps",
                        t,
                        tens,
                    )
                slack_steps += 1
            min_tension = min(min_tension, tens)
            if sensors is not None:
                delivered = sensors.sample(t + (i + 1) * config.plant_dt, x, u)
                if estimator is not None:
                    for m in delivered:
                        estimator.push(m)
        if not math.isfinite(sum(x)):
            data = data[: tick + 1]
            break
        if progress is not None and tick - last_progress >= 1000:
            last_progress = tick
            progress(t / scenario.duration)
    wall = time.perf_counter() - wall0
    stats = estimator.stats() if estimator is not None else {}
    return SimLog(data, scenario, config, vehicle, wall, slack_steps, min_tension, stats)


def _log_tick(
    row: np.ndarray,
    t: float,
    x: list[float],
    truth: ControlState,
    est: ControlState,
    ref: Any,
    cmd: smc.Command,
    u: list[float],
    p: dynamics.PlantParams,
    k_true: FlatConstants,
    estimator: Any,
) -> None:
    """Fill one log row (the order of LOG_COLUMNS)."""
    r1, r2, r3 = x[12], x[13], x[14]
    h = math.sqrt(r1 * r1 + r2 * r2)
    alpha = math.atan2(h, -r3)
    beta = math.atan2(r2, r1) if h > 1e-12 else 0.0
    ay, ax = math.atan2(r1, -r3), math.atan2(r2, -r3)
    Fx = x[0] + k_true.l * ay
    Fy = x[1] + k_true.l * ax
    e_psi = math.remainder(x[8] - ref.psi[0], 2.0 * math.pi)
    row[0] = t
    row[1:19] = x
    row[19:25] = (alpha, beta, ax, ay, Fx, Fy)
    row[25:33] = (ref.fx[0], ref.fy[0], ref.z[0], ref.psi[0], ref.fx[1], ref.fy[1], ref.z[1], ref.psi[1])
    row[33:37] = (Fx - ref.fx[0], Fy - ref.fy[0], x[2] - ref.z[0], e_psi)
    row[37:46] = (*cmd[:8], float(cmd.saturated))
    row[47:51] = (u[4], u[5], u[6], u[12])
    row[51:54] = (x[0] + p.l * r1, x[1] + p.l * r2, x[2] + p.l * r3)
    if est is truth:
        row[54:72] = 0.0
        row[72] = math.nan
    else:
        row[54:58] = (
            est.alpha_x - truth.alpha_x,
            est.alpha_y - truth.alpha_y,
            est.alpha_x_rate - truth.alpha_x_rate,
            est.alpha_y_rate - truth.alpha_y_rate,
        )
        row[58:64] = [a - b for a, b in zip(est.fx, truth.fx)]
        row[64:70] = [a - b for a, b in zip(est.fy, truth.fy)]
        row[70] = est.z - truth.z
        row[71] = math.remainder(est.psi - truth.psi, 2.0 * math.pi)
        row[72] = estimator.nees(t, truth)
        row[_SD0 : _SD0 + len(SIGMA_COLUMNS)] = estimator.sigmas()
