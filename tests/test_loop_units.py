"""Loop pieces without a vehicle: configuration limits, statistics, the staleness / divergence / swing watchdogs on
a loop fed by hand, and the rate-integrator model of the command mapping against the emulator's PI rate loop."""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest

from estimators.model import frames
from estimators.model.control_state import ControlState
from estimators.model.measurements import Attitude, PositionVelocity
from estimators.model.rotations import body_rates
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.scenarios import make_scenario
from offboard.flight.command_mapping import CommandMapper, MappingConfig
from offboard.flight.link.autopilot_model import AutopilotModel
from offboard.flight.link.connection import MavConnection, VehicleInfo
from offboard.flight.loop import FlightAbortError, FlightLoop, LoopConfig, LoopStats
from sim_bridge.inner.airframe import AttitudeController, default_rate_gains


def test_config_limits() -> None:
    LoopConfig().validate()
    for bad in (
        LoopConfig(rate_hz=10.0),
        LoopConfig(rate_hz=2000.0),
        LoopConfig(stale_s=0.0),
        LoopConfig(end_action="crash"),
        LoopConfig(prime_s=0.5),
    ):
        with pytest.raises(ValueError):
            bad.validate()


def test_stats_summary_percentiles_and_missed_fraction() -> None:
    s = LoopStats(ticks=4, elapsed_s=2.0, compute=[1e-4, 2e-4, 3e-4, 4e-4], latency=[5e-4, 5e-4], missed=1)
    d = s.summary(250.0)
    assert d["rate_hz_achieved"] == 2.0 and d["missed_fraction"] == 0.25
    assert d["compute_us_p50"] == pytest.approx(250.0) and d["compute_us_max"] == pytest.approx(400.0)
    assert d["latency_us_p99"] == pytest.approx(500.0) and d["latency_samples"] == 2


@pytest.fixture
def loop() -> FlightLoop:
    """A loop on a real (idle) UDP socket, never started: its watchdogs are called by hand."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    conn = MavConnection(f"udpin:127.0.0.1:{port}")
    conn.vehicle = VehicleInfo(1, 1, "px4", 2)
    v = Vehicle()
    sc = make_scenario("hover")
    lp = FlightLoop(
        conn,
        v,
        sc.reference,
        5.0,
        smc.ControllerParams.for_vehicle(v),
        CommandMapper(v),
        None,
        LoopConfig(stale_s=0.1, divergence_m=1.0, swing_limit_rad=0.5),
    )
    yield lp
    conn.close()


def _est(x: float = 0.0, z: float = 1.0, ax: float = 0.0, ay: float = 0.0) -> ControlState:
    return ControlState(
        (x, 0.0, 0.0, 0.0, 0.0, 0.0), (0.0,) * 6, z, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ax, ay, 0.0, 0.0
    )


def test_staleness_watchdog_real_time_and_lockstep(loop: FlightLoop) -> None:
    loop.last_rx_local = {"Attitude": 10.0, "PositionVelocity": 10.0}
    loop._watchdogs(0.0, 10.09)  # 90 ms: fine
    with pytest.raises(FlightAbortError) as e:
        loop._watchdogs(0.0, 10.11)
    assert e.value.kind == "telemetry_stale" and e.value.action == "hold"
    loop.cfg = LoopConfig(lockstep=True, stale_s=0.1)
    loop.last_att = Attitude(5.0, 0, 0, 0, 0, 0, 0)
    loop.last_pos = PositionVelocity(4.95, 0, 0, 1, 0, 0, 0)
    loop._watchdogs(5.04, 1e9)  # vehicle-time ages in lockstep: the wall clock does not matter
    with pytest.raises(FlightAbortError):
        loop._watchdogs(5.06, 0.0)  # the position is 0.11 s old


def test_a_tick_past_its_deadline_reads_the_waiting_telemetry_first(loop: FlightLoop) -> None:
    """After a stall of the loop itself its tick's deadline is long past: the telemetry that came meanwhile is read
    before the tick, so the staleness watchdog sees it (the slot pacing ticked without reading, and a 333 ms stall
    of the loop read as 333 ms without telemetry, 7 Dec 2026). A real datagram on the loop's real UDP socket."""
    import time

    from pymavlink.dialects.v20 import common as mavlink2

    from offboard.flight.tick_pacing import TickPacer

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    port = loop.conn.conn.port.getsockname()[1]
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.sendto(mav.attitude_encode(1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).pack(mav), ("127.0.0.1", port))
        time.sleep(0.05)  # on the socket, unread
        pacer = TickPacer(0.004)
        pacer.window(time.monotonic() - 1.0)  # the slot of a tick one second ago: its deadline long past
        before = time.monotonic()
        assert loop._await_slot(pacer) is True
        assert loop.last_rx_local["Attitude"] >= before  # read now: its age at the watchdog is ~0, not the stall
    finally:
        s.close()


def test_divergence_and_swing_watchdogs(loop: FlightLoop) -> None:
    loop.last_pos = PositionVelocity(1.0, 0.3, 0.0, 1.0, 0.0, 0.0, 0.0)
    loop._check_swing(_est(x=0.3 + 0.9))  # 0.9 m off: fine
    with pytest.raises(FlightAbortError) as e:
        loop._check_swing(_est(x=0.3 + 1.1))
    assert e.value.kind == "estimator_divergence"
    with pytest.raises(FlightAbortError) as e:
        loop._check_swing(_est(x=math.nan))
    assert e.value.kind == "estimator_divergence"
    # swing: the flat output moves with the load, so keep the vehicle position consistent
    ell = Vehicle().cable_length
    loop._check_swing(_est(x=0.3 + ell * 0.4, ay=0.4))
    with pytest.raises(FlightAbortError) as e:
        loop._check_swing(_est(x=0.3 + ell * 0.4, ay=0.4, ax=0.35))
    assert e.value.kind == "swing_limit"


def test_rate_integrator_model_keeps_the_realized_torque_on_command() -> None:
    """Constant command at a frozen state for 0.5 s: with the integrator model the emulator's PI rate loop delivers
    the commanded torque at every tick; without it (rate_integral 0) the integrator adds up to its limit."""
    v = Vehicle()
    g = default_rate_gains(v)
    ratio = tuple(i / p for i, p in zip(g.i, g.p))
    tau = (0.05, -0.04, 0.02)
    est = ControlState((0.0,) * 6, (0.0,) * 6, 1.0, 0.0, 0.05, -0.03, 0.4, 0.1, 0.0, 0.2, 0.0, 0.0, 0.0, 0.0)
    w = body_rates(est.phi, est.theta, est.phi_rate, est.theta_rate, est.psi_rate)
    q = frames.euler_to_quaternion(est.phi, est.theta, est.psi)
    errors = {}
    for name, model in (
        ("with", AutopilotModel(rate_integral=ratio)),
        ("without", AutopilotModel(rate_integral=(0.0, 0.0, 0.0))),
    ):
        m = CommandMapper(v, MappingConfig(max_rate=10.0), model)
        ac = AttitudeController(v, 0.001)
        worst = 0.0
        for k in range(125):  # 0.5 s at 250 Hz, the emulator's loops at 1 kHz in between
            sp = m.map(k * 0.004, smc.Command(v.hover_thrust, *tau, 0, 0, 0, 0, False, True), est)
            rate_sp = ac.attitude_to_rates(q, frames.ned_quaternion_to_model(*sp.q))
            for _ in range(4):
                out = ac.rates_to_torque(rate_sp, w, integrate=True)
            worst = max(worst, float(np.max(np.abs(np.subtract(out, tau)))))
        errors[name] = worst
    assert errors["with"] < 0.01 * v.roll_pitch_torque_max
    assert errors["without"] > 0.1 * v.roll_pitch_torque_max


def test_flight_code_does_not_load_the_emulator() -> None:
    """The loop, the link and the mapping meet the emulator only on the wire: importing them (in a fresh
    interpreter) loads no sim_bridge module, directly or indirectly."""
    import subprocess
    import sys

    code = (
        "import sys, offboard.flight.loop, offboard.flight.command_mapping, offboard.flight.link.connection, "
        "offboard.flight.link.telemetry, offboard.flight.link.setpoints, offboard.flight.link.management, "
        "offboard.flight.link.mavsdk_backend; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'sim_bridge'))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_actuator_lag_is_the_motors_first_order_response() -> None:
    """The command the filter is given: the first one as is, then a first-order lag with the motor time constant
    (exact per step, whatever the step), and a time constant of 0 passes commands through."""
    from offboard.flight.loop import ActuatorLag

    lag = ActuatorLag(0.02)
    assert lag(1.0, 6.0, (0.1, -0.2, 0.0)) == (6.0, (0.1, -0.2, 0.0))
    t, out = 1.0, None
    for _ in range(5):  # 5 steps of 4 ms = one time constant after a step to 8 N / 0.5 N m
        t += 0.004
        out = lag(t, 8.0, (0.5, -0.2, 0.0))
    assert out is not None
    k = 1.0 - math.exp(-1.0)
    assert out[0] == pytest.approx(6.0 + 2.0 * k, rel=1e-12)
    assert out[1][0] == pytest.approx(0.1 + 0.4 * k, rel=1e-12) and out[1][1] == pytest.approx(-0.2)
    one = ActuatorLag(0.02)
    one(1.0, 6.0, (0.1, -0.2, 0.0))
    assert one(1.02, 8.0, (0.5, -0.2, 0.0))[0] == pytest.approx(out[0], rel=1e-12)  # one 20 ms step, same
    assert ActuatorLag(0.0)(2.0, 3.0, (1.0, 2.0, 3.0)) == (3.0, (1.0, 2.0, 3.0))
    with pytest.raises(ValueError):
        ActuatorLag(math.nan)


def test_start_criterion_is_sized_to_the_telemetry_s_scatter() -> None:
    """The hold at the reference's start ends when the window mean is within two standard errors of the goal
    (floors 1 cm / 3 cm/s): white noise averages down (the 1 cm floor decides), an estimate that wanders over
    seconds does not, and its tolerance grows with its scatter; a vehicle really off the goal still fails."""
    import random

    from offboard.flight.start_checks import settled as _settled
    from offboard.flight.start_checks import standard_error

    rng = random.Random(1)
    white = [rng.gauss(0.0, 0.02) for _ in range(300)]
    assert standard_error(white) == pytest.approx(0.02 / math.sqrt(300), rel=0.3)
    walk = [0.0]
    for _ in range(299):
        walk.append(0.995 * walk[-1] + rng.gauss(0.0, 0.02))
    assert standard_error(walk) > 5.0 * standard_error(white)  # correlated samples count as few

    def settled(xs: list[float], off: float) -> bool:
        """Whether samples ``xs``, shifted so that the mean of the last 50 (the 0.5 s window) is ``off`` m from
        the goal, pass; the 300 (3 s) give the standard error."""
        shift = off - sum(xs[-50:]) / 50
        w = [(0.01 * i, shift + x, 0.0, 2.0, 0.0, 0.0, 0.0) for i, x in enumerate(xs)]
        return _settled(w[-50:], [], 0.0, 0.0, 2.0, True, False, w)

    # white 2 cm noise: 5 mm off is settled, 3 cm off is not (the floor is 1 cm; the standard error ~1 mm)
    assert settled(white, 0.005) and not settled(white, 0.03)
    # a wandering estimate: its mean is known only to decimetres, so 5 cm off counts as there; far off does not
    assert 2.0 * standard_error(walk) > 0.05
    assert settled(walk, 0.05) and not settled(walk, 4.0 * standard_error(walk))
