"""What a compiled run is given, built on the Python side: the reference sampled at every tick (shared by the runs
of a sweep), a run's sensor schedule as flat arrays, and the law's and the actuators' constants and state for the
kernels of :mod:`.engine` (``fly_run``).

Reference rows are ``layout.REF_SIZE`` floats per tick (orders 0..6 of ``F_x``, ``F_y``, ``z``, ``psi``; m, rad and
their derivatives, world NWU), the law's rows shaped beforehand for ``zv`` / ``zvd``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from offboard.control.compiled import attitude_law as cal
from offboard.control.compiled import laws as claws
from offboard.control.compiled.reference_row import REF_SIZE
from offboard.control.smc_attitude import AttitudeParams
from sim_bridge.inner.compiled import px4_loops as cpx
from sim_bridge.plant.compiled import plant as cp

#: the actuator kinds of ``fly_run``: the command itself, the four-motor mixer, PX4's attitude path
ACT_IDEAL, ACT_MIXER, ACT_PX4_ATTITUDE = 0, 1, 2
ACTUATORS = {"ideal": ACT_IDEAL, "mixer": ACT_MIXER, "px4-attitude": ACT_PX4_ATTITUDE}
#: the rows the compiled engine flies: the torque-level laws and the attitude-level law (through PX4's attitude loops)
COMPILED_LAWS = (*claws.TORQUE_LAWS, "smc-attitude")


def check_law(law: str, actuators: str) -> None:
    """ValueError unless the compiled path flies ``law`` with ``actuators``: the attitude-level law only through
    PX4's attitude loops (``px4-attitude``, as the sweep flies it), every other row only with ``ideal`` or
    ``mixer`` (they command torques)."""
    if law not in COMPILED_LAWS:
        raise ValueError(f"the compiled path flies the laws {', '.join(COMPILED_LAWS)}, not {law!r}")
    wanted = ("px4-attitude",) if law == "smc-attitude" else ("ideal", "mixer")
    if actuators not in wanted:
        raise ValueError(f"the compiled path flies {law!r} with actuators {' or '.join(wanted)}, not {actuators!r}")


#: the rows that fly a shaped reference (the input-shaping cascades); every other row flies the reference itself
SHAPED_LAWS = ("zv", "zvd")


def law_shaper(law: str, nominal: Any) -> Any:
    """The reference shaper in front of ``law`` on the ``nominal`` vehicle (``zv`` / ``zvd``), else None."""
    from offboard.control.controllers import registry

    if law not in SHAPED_LAWS:
        return None
    return registry.make(law, nominal).shaper


def law_arrays(
    law: str, params: Any, estimator: str = "truth", tuning: Any = None
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(code, constants, LQR gain, a run's fresh memory) of ``law`` for ``params.vehicle``, the nominal vehicle
    (``params``: ``smc``'s law; the attitude-level law is built as the sweep builds it,
    :func:`sweep_attitude_params`, with the vehicle's drag in its model unless the run's filter, built with
    ``tuning``, feeds its external acceleration forward: ``registry.drag_in_law``)."""
    if law == "smc-attitude":
        from offboard.control.controllers import registry

        drag_ff = estimator != "kf" or registry.drag_in_law(tuning)
        c = cal.attitude_constants(sweep_attitude_params(params.vehicle, drag_ff))
        return cal.LAW_SMC_ATTITUDE, c, np.zeros((0, 0)), cal.attitude_memory()
    code, c, K = claws.law_constants(law, params.vehicle, params)
    return code, c, K, claws.law_memory(code, c)


def sweep_attitude_params(nominal: Any, drag_feedforward: bool = True) -> AttitudeParams:
    """The law as ``slung sweep`` flies it on the ``nominal`` vehicle (``compare.controller_as_flown``: designed for
    the inner loops ``emulated_inner_loop(nominal, "px4")`` reports, within ``MappingConfig().max_tilt``), with the
    vehicle's drag in its model or not (``registry.drag_in_law`` of the run's filter tuning)."""
    from offboard.harness.compare import controller_as_flown
    from offboard.logs.runlog import SimConfig

    _, law = controller_as_flown("smc-attitude", nominal, SimConfig(actuators="mixer"))
    params = law.params  # type: ignore[attr-defined]  # (a PureStepController: the protocol has no params)
    assert isinstance(params, AttitudeParams)
    return replace(params, drag_feedforward=drag_feedforward)


def actuator_arrays(kind: int, vehicle: Any, plant_dt: float, hover: float) -> tuple[np.ndarray, ...]:
    """(the mixer's constants, the PX4 path's constants, its state) for the TRUE ``vehicle`` with the motors at
    ``hover / 4`` N each; the arrays a kind does not use are placeholders."""
    mix_c = cp.mixer_constants(vehicle, plant_dt)
    if kind != ACT_PX4_ATTITUDE:
        return mix_c, np.zeros(1), np.zeros(1)
    from offboard.flight.command_mapping import MappingConfig

    return mix_c, cpx.px4_constants(vehicle, plant_dt, MappingConfig().max_tilt), cpx.px4_state(0.25 * hover)


def reference_rows(reference: Any, shaper: Any, n_ticks: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The reference sampled at every tick (ticks, 28), and the law's (shaped by ``shaper`` when given, once per
    tick in order, as the scalar ``ShapedCascade`` shapes it; else the same array)."""
    rows = np.empty((n_ticks, REF_SIZE))
    law = np.empty((n_ticks, REF_SIZE)) if shaper is not None else rows
    for tick in range(n_ticks):
        t = tick * dt
        s = reference.sample(t)
        rows[tick] = (*s.fx, *s.fy, *s.z, *s.psi)
        if shaper is not None:
            law[tick] = np.concatenate([np.asarray(v, dtype=float) for v in shaper(t, s.fx, s.fy, s.z, s.psi)])
    return rows, law


_REFERENCES: dict[tuple[Any, ...], tuple[np.ndarray, np.ndarray]] = {}


def sweep_reference(config: Any, controller: str, scenario: Any, params: Any) -> tuple[np.ndarray, np.ndarray]:
    """The sweep's one reference as rows (and the law's, shaped for ``zv`` / ``zvd``), sampled once per process for
    a file's move and nominal vehicle: every run of every chunk flies the same reference (``sweep.scenario``), and
    sampling its 13 001 ticks costs as much as flying 40 runs; the rows that fly it unshaped share one sampling."""
    shaped = controller if controller in SHAPED_LAWS else ""
    key = (config.move_time_s, config.distance_m, config.hold_s, config.vehicle_file, shaped)
    if key not in _REFERENCES:
        n_ticks = math.floor(scenario.duration / 0.001 + 1e-9) + 1
        if len(_REFERENCES) > 16:
            _REFERENCES.clear()
        shaper = law_shaper(controller, params.vehicle)
        _REFERENCES[key] = reference_rows(scenario.reference, shaper, n_ticks, 0.001)
    return _REFERENCES[key]


def records(sched: Any) -> tuple[np.ndarray, ...]:
    """A run's schedule (``offboard.harness.compiled.schedule.RunSchedule``) as flat arrays: the first record of each
    kind (5,), sampling steps, times, noise (n, 6) and values to fill (n, 6), the events and their payloads."""
    counts = [len(s) for s in sched.steps]
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    n = int(start[-1])
    steps = np.concatenate(sched.steps).astype(np.int64) if n else np.zeros(0, dtype=np.int64)
    times = np.concatenate(sched.times).astype(float) if n else np.zeros(0)
    noise = np.zeros((n, 6))
    for kind, e in enumerate(sched.noise):
        if len(e):
            noise[start[kind] : start[kind + 1], : e.shape[1]] = e
    ev = np.ascontiguousarray(sched.events, dtype=np.int64).reshape(-1, 3)
    return start, steps, times, noise, np.full((n, 6), np.nan), ev, np.asarray(sched.payload, dtype=float)
