"""In-process closed loop: plant (``sim_bridge``) + sensors + estimator + the sliding-mode controller.

The loop is the same as the live one minus the wire: at each controller tick the estimate (true state, or a
Kalman filter fed by the sensor models) and the reference go into :func:`offboard.smc.step`, whose command is
held (zero-order hold) while the plant is integrated with fixed-step RK4 at its own, finer or equal, step.

Everything is logged at the controller rate into preallocated arrays (:class:`SimLog`), from which
``offboard.metrics`` computes the figures and ``offboard.report`` draws them.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from estimators.cable import planar_swing
from estimators.control_state import ControlState
from estimators.flatness import FlatConstants, flat_chain, flat_constants, world_tilt
from estimators.vehicle import Vehicle
from offboard import smc
from offboard.runlog import COL, LOG_COLUMNS, Disturbance, PlantSetup, ReferenceLike, Scenario, SimConfig, SimLog
from sim_bridge import dynamics

# The run records live in the plant-free ``offboard.runlog`` (the live flight path reads them without loading the
# simulator); they are re-exported here for the simulation's users.
__all__ = ["COL", "LOG_COLUMNS", "Disturbance", "PlantSetup", "ReferenceLike", "Scenario", "SimConfig", "SimLog",
           "plant_scenario", "run", "truth_control_state"]

_LOG = logging.getLogger(__name__)
_DEFAULT_CONFIG = SimConfig()  # frozen: safe as a default argument


def plant_scenario(scenario: Scenario) -> Scenario:
    """``scenario`` with its simulation part built: the initial plant state and the disturbance from the plain
    numbers of ``scenario.setup`` (``offboard.runlog.PlantSetup``), unless the scenario already carries an
    ``initial_state``. The named scenarios (``offboard.scenarios``) are plant-free; this is where the plant's
    side of them is made. ValueError for a scenario with neither."""
    if scenario.initial_state is not None:
        return scenario
    s = scenario.setup
    if s is None:
        raise ValueError(f"scenario {scenario.name!r} has no initial plant state and no plant setup")
    disturbance = scenario.disturbance
    if s.disturbance == "paper":
        from sim_bridge.disturbances import DisturbanceSpec, RandomDisturbance

        start = scenario.disturbance_start
        spec = DisturbanceSpec() if start is None else DisturbanceSpec(start=start)
        disturbance = RandomDisturbance(spec, s.seed)
    elif s.disturbance is not None:
        raise ValueError(f"scenario {scenario.name!r}: unknown disturbance {s.disturbance!r} (known: paper)")
    state = dynamics.make_state(position=s.position, euler=(0.0, 0.0, s.heading), cable=s.cable,
                                cable_rate=s.cable_rate)
    return replace(scenario, initial_state=state, disturbance=disturbance)


def truth_control_state(x: list[float], k: FlatConstants) -> ControlState:
    """The controller's input computed from the true plant state (the paper's all-states-measured case)."""
    ay, ax, ayd, axd = planar_swing(x[12], x[13], x[14], x[15], x[16], x[17])
    nx, ny, nxd, nyd = world_tilt(x[6], x[7], x[8], x[9], x[10], x[11])
    return ControlState(
        flat_chain(k, x[0], x[3], ay, ayd, nx, nxd),
        flat_chain(k, x[1], x[4], ax, axd, ny, nyd),
        x[2], x[5], x[6], x[7], x[8], x[9], x[10], x[11], ax, ay, axd, ayd,
    )


def run(
    scenario: Scenario,
    vehicle: Vehicle,
    params: smc.ControllerParams,
    config: SimConfig = _DEFAULT_CONFIG,
    progress: Callable[[float], None] | None = None,
) -> SimLog:
    """Simulate ``scenario`` with the true plant ``vehicle`` and controller ``params`` (whose nominal
    vehicle may differ, for robustness studies). Returns the full log; never raises on divergence (the
    log then shows it), but stops early if the state becomes non-finite. A named scenario's simulation part
    (initial plant state, disturbances) is built here (:func:`plant_scenario`)."""
    scenario = plant_scenario(scenario)
    if not (config.plant_dt > 0 and config.control_rate > 0):
        raise ValueError("plant_dt and control_rate must be > 0")
    substeps = round(1.0 / (config.control_rate * config.plant_dt))
    if substeps < 1 or abs(substeps * config.plant_dt * config.control_rate - 1.0) > 1e-9:
        raise ValueError("the control period must be a whole number of plant steps")
    control_dt = substeps * config.plant_dt
    n_ticks = math.floor(scenario.duration / control_dt + 1e-9) + 1

    if config.actuators not in ("ideal", "mixer"):
        raise ValueError(f"unknown actuators {config.actuators!r} (ideal or mixer)")
    p = dynamics.plant_params(vehicle, config.attitude_model)
    k_nominal = flat_constants(params.vehicle)
    k_true = flat_constants(vehicle)
    rng = np.random.default_rng(config.seed)

    sensors = None
    estimator = None
    if config.estimator != "truth" or config.sensors is not None:
        from sim_bridge.sensors import SensorSuite  # the sensor models: only when asked for

        sensors = SensorSuite(config.sensors or "ideal", vehicle, rng, load_sensor=config.load_sensor)
    if config.estimator != "truth":
        from estimators.factory import make_estimator

        estimator = make_estimator(
            config.estimator, params.vehicle, load_sensor=config.load_sensor, rate_hz=config.control_rate
        )

    data = np.full((n_ticks, len(LOG_COLUMNS)), np.nan)
    assert scenario.initial_state is not None  # plant_scenario built it
    x = list(scenario.initial_state)
    memory = smc.ControllerMemory()
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
    step = smc.step
    rk4 = dynamics.rk4_step
    tension = dynamics.tension
    u = dynamics.hover_input(p)
    mixer = None
    if config.actuators == "mixer":
        from sim_bridge.airframe import Mixer

        mixer = Mixer(vehicle, config.plant_dt)
        mixer.reset(0.25 * u[0])  # the motors start at hover
    last_progress = 0
    for tick in range(n_ticks):
        t = tick * control_dt
        truth = truth_control_state(x, k_nominal)
        est = truth if estimator is None else estimator.estimate(t)
        ref = scenario.reference.sample(t)
        cmd, memory = step(t, est, ref.fx, ref.fy, ref.z, ref.psi, memory, params)
        if dist_table is not None:
            d: Any = dist_table[tick]
        elif dist is not None:
            d = dist(t)
        else:
            d = zero9
        u = [cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi, *d]
        if estimator is not None:
            estimator.push_command(t, cmd.thrust, (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi))
        _log_tick(data[tick], t, x, truth, est, ref, cmd, u, p, k_true, estimator)
        if mixer is not None:  # the plant feels the motors' wrench, not the command
            mixer.allocate(cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)
            u[0:4] = mixer.wrench()
        tens = tension(x, u, p)
        data[tick, COL["tension"]] = tens
        if tick == n_ticks - 1:
            break
        for i in range(substeps):
            if mixer is not None:  # the motors' thrusts at the end of this plant step act over it (zero-order)
                u[0:4] = mixer.step()
            x = rk4(x, u, p, config.plant_dt, t + i * config.plant_dt)
            tens = tension(x, u, p)
            if tens <= 0.0:
                if slack_steps == 0:
                    _LOG.warning("cable went slack at t = %.3f s (tension %.3f N): the rigid-cable model is not "
                                 "valid while it is slack; the run continues and counts slack steps", t, tens)
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
