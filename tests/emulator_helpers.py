"""Helpers for the emulator tests and benchmark: start ``slung emulate`` as a subprocess on a free loopback port,
talk to it with pymavlink, and a minimal hold controller (test client only; the real controller is offboard/)."""

from __future__ import annotations

import json
import math
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from estimators.model.frames import euler_to_quaternion
from estimators.model.vehicle import Vehicle

ROOT = Path(__file__).resolve().parents[1]
PX4_OFFBOARD = (1, 6, 0)  # DO_SET_MODE params for PX4 OFFBOARD
MAV_CMD_ARM = 400
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_SET_MESSAGE_INTERVAL = 511


def free_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def emulator_process(
    port: int, *args: str, stdout: Any = subprocess.PIPE, stderr: Any = subprocess.PIPE
) -> subprocess.Popen:
    """``slung emulate`` (``python -m sim_bridge.emulator_cli``) as its own process, sending MAVLink to
    ``udpout:127.0.0.1:<port>``, with the further ``args``; text pipes by default. The one way the tests and the
    benchmarks start it as a process (real time needs its own core, not a thread of the caller)."""
    cmd = [sys.executable, "-m", "sim_bridge.emulator_cli", "--mavlink", f"udpout:127.0.0.1:{port}", *args]
    return subprocess.Popen(cmd, cwd=ROOT, stdout=stdout, stderr=stderr, text=True)


def stop_emulator_process(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """SIGTERM an :func:`emulator_process` (it writes its summary and ends) and wait for it; killed if it has not
    ended within ``timeout`` s."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


class Emu:
    """``python -m sim_bridge.emulator_cli`` sending to a pymavlink client listening on a free port."""

    def __init__(
        self,
        *args: str,
        client_sysid: int = 255,
        client_compid: int = 190,
        signing_key: bytes | None = None,
        sign_outgoing: bool = True,
    ) -> None:
        self.port = free_port()
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{self.port}",
            source_system=client_sysid,
            source_component=client_compid,
            dialect="ardupilotmega",
        )
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=sign_outgoing)
        self.proc = emulator_process(self.port, *args)
        self.summary: dict[str, Any] | None = None
        self.texts: list[str] = []  # every STATUSTEXT seen by recv()

    @property
    def emulator_address(self) -> tuple[str, int]:
        """The emulator's UDP address (known once it has sent us something)."""
        return next(iter(self.conn.clients))

    def send_raw(self, data: bytes) -> None:
        """One raw datagram to the emulator."""
        self.conn.port.sendto(data, self.emulator_address)

    @property
    def mav(self) -> Any:
        """The pymavlink MAVLink object of the client."""
        return self.conn.mav

    def wait_heartbeat(self, timeout: float = 10.0) -> Any:
        """First HEARTBEAT from the autopilot (sysid 1, compid 1)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if m is not None and m.get_srcSystem() == 1 and m.get_srcComponent() == 1:
                return m
        raise TimeoutError("no heartbeat from the emulator")

    def recv(self, types: str | list[str], timeout: float = 2.0, cond: Any = None, sysid: int = 1) -> Any:
        """Next message of the given type(s) from ``sysid`` (and satisfying ``cond``), or None on timeout."""
        wanted = (types,) if isinstance(types, str) else tuple(types)
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return None
            m = self.conn.recv_match(blocking=True, timeout=left)
            if m is None:
                return None
            t = m.get_type()
            if t == "STATUSTEXT":
                self.texts.append(m.text)
            if t in wanted and m.get_srcSystem() == sysid and (cond is None or cond(m)):
                return m

    def drain(self) -> None:
        """Read everything queued (STATUSTEXTs are kept in ``texts``)."""
        while True:
            m = self.conn.recv_match(blocking=False)
            if m is None:
                return
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)

    def latest(self, name: str, sysid: int = 1, timeout: float = 2.0) -> Any:
        """Drain what is queued and return the newest message of a type (waiting for one if none is queued)."""
        last = None
        while True:
            m = self.conn.recv_match(blocking=False)
            if m is None:
                break
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)
            if m.get_type() == name and m.get_srcSystem() == sysid:
                last = m
        return last if last is not None else self.recv(name, timeout, sysid=sysid)

    def command(self, cmd: int, *params: float, target: int = 1, timeout: float = 2.0) -> Any:
        """COMMAND_LONG and its COMMAND_ACK (or None)."""
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.drain()  # a full socket buffer would drop the answer
        self.mav.command_long_send(target, 1, cmd, 0, *p)
        return self.recv("COMMAND_ACK", timeout, cond=lambda m: m.command == cmd)

    def wait_ready(self, timeout: float = 10.0) -> None:
        """Until the estimator is ready (LOCAL_POSITION_NED flows)."""
        if self.recv("LOCAL_POSITION_NED", timeout) is None:
            raise TimeoutError("no LOCAL_POSITION_NED")

    def stop(self, timeout: float = 10.0) -> dict[str, Any]:
        """SIGTERM the emulator and return its JSON summary."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        out, err = self.proc.communicate(timeout=timeout)
        self.conn.close()
        lines = [ln for ln in out.splitlines() if ln.startswith("{")]
        if not lines:
            raise RuntimeError(f"no summary from the emulator; stderr: {err[-2000:]}")
        self.summary = json.loads(lines[-1])
        return self.summary

    def __enter__(self) -> Emu:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class InProcessEmu(Emu):
    """The emulator built by ``sim_bridge.emulator_cli.build`` and run in a thread of this process (so a test can
    read its plant inputs and state), with the same pymavlink client API as :class:`Emu` over real UDP."""

    def __init__(self, *args: str) -> None:
        import argparse
        import threading

        from sim_bridge import emulator_cli

        self.port = free_port()
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{self.port}", source_system=255, source_component=190, dialect="ardupilotmega"
        )
        parser = argparse.ArgumentParser()
        emulator_cli.configure(parser)
        self.args = parser.parse_args(["--mavlink", f"udpout:127.0.0.1:{self.port}", *args])
        self.emu, self.ap, self.link = emulator_cli.build(self.args)
        self.summary = None
        self.texts = []
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            self.emu.run(None)
        except BaseException as exc:  # re-raised by stop()
            self.error = exc

    def stop(self, timeout: float = 10.0) -> dict[str, Any]:
        """Stop the thread, close the sockets; the emulator's summary (as ``slung emulate`` prints it)."""
        self.emu.stop()
        self.thread.join(timeout)
        self.summary = {**self.ap.summary(), **self.emu.summary(), "link": self.link.summary()}
        self.link.close()
        self.conn.close()
        if self.error is not None:
            raise RuntimeError(f"the emulator failed: {self.error!r}")
        return self.summary

    def __exit__(self, *exc: object) -> None:
        if self.thread.is_alive():
            self.emu.stop()
            self.thread.join(10.0)
            self.link.close()


def attitude_target(
    mav: Any, roll: float, pitch: float, yaw: float, thrust: float, t_ms: int = 0, target: int = 1
) -> None:
    """SET_ATTITUDE_TARGET, type_mask 7 (attitude + thrust), Euler angles in rad (NED/FRD)."""
    q = euler_to_quaternion(roll, pitch, yaw)
    mav.set_attitude_target_send(t_ms, target, 1, 7, list(q), 0.0, 0.0, 0.0, thrust)


def offboard_then_silence(e: Emu, action: int, *params: tuple[bytes, float]) -> int:
    """Set PX4's offboard-loss action ``COM_OBL_RC_ACT`` = ``action`` and a 0.5 s loss timeout (``params``: more
    REAL32 parameters, set before the timeout), arm, switch to OFFBOARD and climb 1 s in lockstep (thrust 0.6), then
    send nothing more: the emulator free-runs into its failsafe. Returns the last step's end marker (SYSTEM_TIME
    ``time_boot_ms``, ms)."""
    e.wait_heartbeat()
    e.wait_ready()
    e.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", action))[0], 6)
    for name, value in params:
        e.mav.param_set_send(1, 1, name, value, 9)
    e.mav.param_set_send(1, 1, b"COM_OF_LOSS_T", 0.5, 9)
    assert e.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == "COM_OF_LOSS_T") is not None
    for _ in range(5):
        attitude_target(e.mav, 0, 0, 0, 0.0)
    assert e.command(MAV_CMD_ARM, 1, 0).result == 0
    attitude_target(e.mav, 0, 0, 0, 0.6)
    assert e.command(MAV_CMD_DO_SET_MODE, 1, 6, 0).result == 0
    t_stop = 0
    for _ in range(100):  # 1 s of lockstep climb
        attitude_target(e.mav, 0, 0, 0, 0.6)
        marker = e.recv("SYSTEM_TIME", 2.0)
        assert marker is not None
        t_stop = marker.time_boot_ms
    return t_stop


class HoldController:
    """PD hold of a NED position with attitude + normalized thrust output (small-angle, test client only)."""

    def __init__(
        self,
        vehicle: Vehicle,
        target_ned: tuple[float, float, float],
        kp_xy: float = 1.0,
        kd_xy: float = 1.8,
        kp_z: float = 4.0,
        kd_z: float = 4.0,
    ) -> None:
        self.hover = vehicle.hover_thrust_normalized
        self.g = vehicle.gravity
        self.target = target_ned
        self.k = (kp_xy, kd_xy, kp_z, kd_z)

    def update(self, pos: tuple[float, float, float], vel: tuple[float, float, float]) -> tuple[float, float, float]:
        """(roll rad, pitch rad, normalized thrust) for position and velocity in NED."""
        kp, kd, kpz, kdz = self.k
        ax = kp * (self.target[0] - pos[0]) - kd * vel[0]
        ay = kp * (self.target[1] - pos[1]) - kd * vel[1]
        az = kpz * (self.target[2] - pos[2]) - kdz * vel[2]
        g = self.g
        lim = 0.35
        pitch = max(-lim, min(lim, -ax / g))
        roll = max(-lim, min(lim, ay / g))
        thrust = self.hover * (g - az) / g / (math.cos(roll) * math.cos(pitch))
        return roll, pitch, max(0.0, min(1.0, thrust))


def fly_lockstep_hold(
    emu: Emu,
    seconds: float,
    vehicle: Vehicle,
    altitude: float = 2.0,
    period: float = 0.01,
    collect: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Arm, enter offboard and hold ``altitude`` for ``seconds`` of simulation time in lockstep.

    Returns wall time of the lockstep part, final position (NED) and the number of handshakes; with ``collect``
    (message names), also ``messages``: name -> [(time of the step marker that followed it ms, message)] for
    every such message of the autopilot from the offboard entry on, and those streams run at the control rate;
    ``start_ms``: the simulation time of the offboard entry (ms; it depends on how long the emulator free-ran
    before the first setpoint, a wall-clock matter).
    """
    emu.wait_heartbeat()
    emu.wait_ready()
    mav = emu.mav
    iv = int(period * 1e6)
    ids = {"HIGHRES_IMU": 105, "DEBUG_VECT": 250, "ATTITUDE_QUATERNION": 31, "ODOMETRY": 331}
    for msgid in (32, 30, *(ids[n] for n in collect if n in ids)):  # LOCAL_POSITION_NED, ATTITUDE, ...
        emu.command(MAV_CMD_SET_MESSAGE_INTERVAL, msgid, iv)
    messages: dict[str, list[tuple[int, Any]]] = {n: [] for n in collect}
    pending: list[Any] = []
    ctrl = HoldController(vehicle, (0.0, 0.0, -altitude))
    pos, vel = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    sim_ms = 0
    start_ms = None
    armed = offboard = False
    steps = 0
    t0 = time.monotonic()
    max_err = 0.0
    trace: list[tuple[float, float, float]] = []
    while True:
        roll, pitch, thrust = ctrl.update(pos, vel)
        if not armed:
            thrust = 0.0
        attitude_target(mav, roll, pitch, 0.0, thrust, sim_ms)
        steps += 1
        # read until the end-of-step marker
        while True:
            m = emu.conn.recv_match(blocking=True, timeout=5.0)
            if m is None:
                raise TimeoutError("lockstep: no end-of-step marker")
            t = m.get_type()
            if t in messages and start_ms is not None and m.get_srcSystem() == 1:
                pending.append(m)
            if t == "LOCAL_POSITION_NED":
                pos, vel = (m.x, m.y, m.z), (m.vx, m.vy, m.vz)
                if start_ms is not None:
                    trace.append((m.time_boot_ms - start_ms, m.x, m.z))
            elif t == "SYSTEM_TIME" and m.get_srcSystem() == 1:
                sim_ms = m.time_boot_ms
                for pm in pending:
                    messages[pm.get_type()].append((sim_ms, pm))
                pending.clear()
                break
        if not armed and steps == 20:
            mav.command_long_send(1, 1, MAV_CMD_ARM, 0, 1, 0, 0, 0, 0, 0, 0)
            armed = True
        if armed and not offboard and steps == 25:
            mav.command_long_send(1, 1, MAV_CMD_DO_SET_MODE, 0, *PX4_OFFBOARD, 0, 0, 0, 0)
            offboard = True
            start_ms = sim_ms
            t0 = time.monotonic()
        if start_ms is not None:
            if sim_ms - start_ms > 10000:
                max_err = max(max_err, abs(pos[2] + altitude))
            if sim_ms - start_ms >= seconds * 1000:
                break
    wall = time.monotonic() - t0
    return {
        "wall_s": wall,
        "sim_s": (sim_ms - (start_ms or 0)) / 1000.0,
        "pos": pos,
        "handshakes": steps,
        "max_alt_err_after_10s": max_err,
        "trace": trace,
        "messages": messages,
        "start_ms": start_ms,
    }


class UdpRelay(threading.Thread):
    """A UDP relay on 127.0.0.1 between the loop (listening on ``loop_port``) and the emulator (whoever else sends
    to :attr:`port`), forwarding each datagram unless the hooks say otherwise: :meth:`from_loop` and
    :meth:`from_emulator` return whether to forward (subclasses drop or count). Stops when :attr:`stop` is set."""

    def __init__(self, loop_port: int) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.loop_addr = ("127.0.0.1", loop_port)
        self.emu_addr: tuple[str, int] | None = None
        self.stop = False

    def from_loop(self, data: bytes) -> bool:
        return True

    def from_emulator(self, data: bytes) -> bool:
        return True

    def run(self) -> None:
        while not self.stop:
            r, _, _ = select.select([self.sock], [], [], 0.05)
            if not r:
                continue
            data, addr = self.sock.recvfrom(65535)
            if addr == self.loop_addr:
                if self.from_loop(data) and self.emu_addr is not None:
                    self.sock.sendto(data, self.emu_addr)
            else:
                self.emu_addr = addr
                if self.from_emulator(data):
                    self.sock.sendto(data, self.loop_addr)


def fly_against_emulator(
    argv: list[str], flavor: str = "px4", vehicle: str | None = None
) -> tuple[dict[str, Any], Path]:
    """``slung fly`` with the options ``argv`` (without ``--connect``) against the bundled emulator in a thread
    (``flavor``, lockstep at 250 Hz, ``vehicle`` or the paper's), its truth recorded: (metrics, run folder)."""
    import argparse

    from offboard.flight.fly_cli import configure as fly_configure
    from offboard.flight.fly_cli import fly
    from offboard.harness.demo_cli import EmulatorThread, free_udp_port

    port = free_udp_port()
    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(["--connect", f"udpin:127.0.0.1:{port}", *argv])
    emu = EmulatorThread(flavor, port, lockstep=True, period=0.004, vehicle=vehicle).start()
    try:
        return fly(args, lockstep=True, truth_probe=emu.truth, quiet=True, on_reference_start=emu.set_reference_start)
    finally:
        emu.stop()
