"""Benchmark of ``slung emulate``: lockstep speed of a 60 s hold flight, and real-time stream rates.

Run: ``python bench/bench_emulator.py [--seconds 60] [--rates-window 5]``. Prints a JSON report:

- ``lockstep``: wall time of a ``--seconds`` offboard hold flight (PX4 flavour, 100 Hz setpoints, default
  streams plus LOCAL_POSITION_NED and ATTITUDE at 100 Hz) flown by a simple PD hold controller over UDP, and
  the real-time factor (simulation seconds per wall second);
- ``rates``: in ``--realtime`` mode, the measured rate of each stream over ``--rates-window`` seconds against
  the configured one (defaults, ATTITUDE raised to 500 Hz with SET_MESSAGE_INTERVAL, ODOMETRY to 100 Hz).

The client reads datagrams with a plain socket and pymavlink's parser (no mavutil polling), as a tight
controller loop would. Benchmarks never fail; they report.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from emulator_helpers import HoldController, emulator_process  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402

from estimators.model.frames import euler_to_quaternion  # noqa: E402
from estimators.model.vehicle import Vehicle  # noqa: E402


class RawClient:
    """UDP socket + pymavlink parser, listening on a free 127.0.0.1 port."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.sock.settimeout(5.0)
        self.mav = mavlink2.MAVLink(self, srcSystem=255, srcComponent=190)
        self.peer: tuple[str, int] | None = None

    def write(self, buf: bytes) -> None:
        """pymavlink file interface: send to the emulator."""
        if self.peer is not None:
            self.sock.sendto(buf, self.peer)

    def recv(self) -> list[Any]:
        """Messages of the next datagram."""
        data, addr = self.sock.recvfrom(65535)
        self.peer = addr
        return self.mav.parse_buffer(data) or []

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


def start(args: list[str], port: int) -> subprocess.Popen:
    """The emulator as a subprocess sending to ``port`` (its JSON summary on stdout)."""
    return emulator_process(port, *args, stderr=subprocess.DEVNULL)


def stop(proc: subprocess.Popen) -> dict[str, Any]:
    """Terminate the emulator and parse its JSON summary."""
    proc.terminate()
    out, _ = proc.communicate(timeout=10)
    lines = [ln for ln in out.splitlines() if ln.startswith("{")]
    return json.loads(lines[-1]) if lines else {}


def wait_for(c: RawClient, name: str, timeout: float = 10.0) -> Any:
    """First message of a type."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for m in c.recv():
            if m.get_type() == name:
                return m
    raise TimeoutError(name)


def lockstep_flight(seconds: float, period: float = 0.01, altitude: float = 2.0) -> dict[str, Any]:
    """Arm, offboard, hold ``altitude`` for ``seconds`` of simulation time in lockstep; wall time measured."""
    v = Vehicle()
    c = RawClient()
    proc = start(["--lockstep", "--lockstep-period", str(period)], c.port)
    try:
        wait_for(c, "HEARTBEAT")
        wait_for(c, "LOCAL_POSITION_NED")
        mav = c.mav
        for msgid in (32, 30):
            mav.command_long_send(1, 1, 511, 0, msgid, period * 1e6, 0, 0, 0, 0, 0)
        hold = HoldController(v, (0.0, 0.0, -altitude))
        pos = vel = (0.0, 0.0, 0.0)
        sim_ms, steps, start_ms, t0 = 0, 0, None, time.monotonic()
        swing_max = 0.0
        err_max = 0.0
        while True:
            roll, pitch, thrust = hold.update(pos, vel)
            mav.set_attitude_target_send(
                sim_ms, 1, 1, 7, list(euler_to_quaternion(roll, pitch, 0.0)), 0, 0, 0, thrust if steps >= 20 else 0.0
            )
            steps += 1
            done = False
            while not done:
                for m in c.recv():
                    t = m.get_type()
                    if t == "LOCAL_POSITION_NED":
                        pos, vel = (m.x, m.y, m.z), (m.vx, m.vy, m.vz)
                    elif t == "DEBUG_VECT":
                        swing_max = max(swing_max, abs(m.z))
                    elif t == "SYSTEM_TIME" and m.get_srcSystem() == 1:
                        sim_ms = m.time_boot_ms
                        done = True
            if steps == 20:
                mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            elif steps == 25:
                mav.command_long_send(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)
                start_ms, t0 = sim_ms, time.monotonic()
            if start_ms is not None:
                if sim_ms - start_ms > 10000:
                    err_max = max(err_max, abs(pos[2] + altitude))
                if sim_ms - start_ms >= seconds * 1000:
                    break
        wall = time.monotonic() - t0
        sim = (sim_ms - start_ms) / 1000.0
    finally:
        summary = stop(proc)
        c.close()
    return {
        "sim_s": sim,
        "wall_s": round(wall, 3),
        "realtime_factor": round(sim / wall, 2),
        "handshakes": steps,
        "final_altitude_m": round(-pos[2], 4),
        "max_altitude_error_after_10s_m": round(err_max, 4),
        "mode": summary.get("mode"),
        "emulator_setpoints": summary.get("counters", {}).get("setpoints_accepted"),
    }


def stream_rates(window: float, attitude_hz: float = 500.0) -> dict[str, Any]:
    """Real-time stream rates (by the messages' own time stamps and by wall clock) vs configured."""
    c = RawClient()
    proc = start(["--realtime"], c.port)
    configured = {
        "ATTITUDE": attitude_hz,
        "ATTITUDE_QUATERNION": 50.0,
        "HIGHRES_IMU": 50.0,
        "LOCAL_POSITION_NED": 30.0,
        "ODOMETRY": 100.0,
        "GLOBAL_POSITION_INT": 50.0,
        "DEBUG_VECT": 50.0,
        "SYS_STATUS": 5.0,
        "ATTITUDE_TARGET": 10.0,
        "HEARTBEAT": 1.0,
    }
    try:
        wait_for(c, "LOCAL_POSITION_NED")
        c.mav.command_long_send(1, 1, 511, 0, 30, 1e6 / attitude_hz, 0, 0, 0, 0, 0)
        c.mav.command_long_send(1, 1, 511, 0, 331, 1e4, 0, 0, 0, 0, 0)
        t_settle = time.monotonic() + 0.5
        while time.monotonic() < t_settle:
            c.recv()
        arrivals: dict[str, list[float]] = {}
        t0 = time.monotonic()
        while time.monotonic() - t0 < window:
            msgs = c.recv()
            now = time.monotonic()
            for m in msgs:
                if m.get_srcSystem() == 1:
                    arrivals.setdefault(m.get_type(), []).append(now)
    finally:
        stop(proc)
        c.close()
    out = {}
    for name, hz in configured.items():
        ts = arrivals.get(name, [])
        # wall-clock rate between the first and the last arrival (no window-edge quantization)
        got = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 2 else 0.0
        out[name] = {
            "configured_hz": hz,
            "measured_hz": round(got, 2),
            "messages": len(ts),
            "error_pct": round(100 * (got - hz) / hz, 2),
        }
    return out


def step_cost(steps: int = 20000) -> dict[str, Any]:
    """In process: cost of one 1 kHz plant step with the inner loops, mixer, motors and default telemetry
    (PX4 flavour, offboard attitude hover; packets go to a closed loopback port), and of the bare RK4 step."""
    from sim_bridge.autopilot import Autopilot
    from sim_bridge.emulator import Emulator
    from sim_bridge.plant.dynamics import hover_input, make_state, plant_params, rk4_step
    from sim_bridge.protocol.link import Link, LinkFaults

    v = Vehicle()
    port = RawClient()  # a bound socket nobody reads: sendto never blocks, nothing is refused
    link = Link([f"udpout:127.0.0.1:{port.port}"], LinkFaults())
    ap = Autopilot("px4", v, link, est_ready_s=0.1)
    emu = Emulator(ap, link, v, clock="lockstep")
    emu.step(500)
    ap.sp_kind, ap.sp_q, ap.sp_thrust, ap.sp_time_us = "att", (1.0, 0.0, 0.0, 0.0), 0.5, 10**15
    ap._arm(0.0)
    ap.request_mode(ap.fl.by_name["OFFBOARD"])
    samples = []
    for _ in range(5):
        t0 = time.perf_counter()
        emu.step(steps // 5)
        samples.append((time.perf_counter() - t0) / (steps // 5) * 1e6)
    p = plant_params(v, "rigid")
    x, u = make_state((0, 0, 5)), hover_input(p)
    t0 = time.perf_counter()
    for _ in range(steps):
        x = rk4_step(x, u, p, 0.001)
    rk4 = (time.perf_counter() - t0) / steps * 1e6
    link.close()
    port.close()
    samples.sort()
    return {
        "emulator_step_us_median": round(samples[2], 1),
        "emulator_step_us_max_of_5": round(samples[-1], 1),
        "rk4_rigid_step_us": round(rk4, 1),
        "telemetry_packets": link.tx_packets,
    }


def main() -> int:
    """Run both benchmarks and print the JSON report."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rates-window", type=float, default=5.0)
    a = ap.parse_args()
    report = {"step_cost": step_cost(), "lockstep": lockstep_flight(a.seconds), "rates": stream_rates(a.rates_window)}
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
