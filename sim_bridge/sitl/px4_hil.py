"""Real PX4 SITL flying a vehicle that carries a slung load: this process is PX4's simulator.

PX4's ``simulator_mavlink`` module (started for airframe 10016 ``none_iris``, ``Px4Sitl(model=HIL_MODEL)``)
connects to TCP port 4560 + instance, where :class:`Px4HilServer` listens. In lockstep with PX4:

1. the server sends HIL_SENSOR stamped with the simulation time (and HIL_GPS at ``gps_hz``, the ground truth
   HIL_STATE_QUATERNION at ``truth_hz``), made by ``sim_bridge.sitl.hil_sensors`` from the plant;
2. PX4 runs its estimators and controllers up to that time and answers HIL_ACTUATOR_CONTROLS;
3. the server holds those motor outputs over one sensor period of the plant (``sim_bridge.sitl.hil_vehicle``:
   the rotors, the rigid body, its cable and load, the ground) and goes back to 1.

The simulation runs at ``speed`` times the wall clock (1: real time, as a companion computer's loop beside PX4 needs;
None: as fast as PX4 answers). After PX4's first HIL_ACTUATOR_CONTROLS (before it, PX4 is booting) the server waits
for each answer, up to ``answer_timeout_s`` of wall time (then it goes on with the last outputs and counts the step
in ``missed_answers``: PX4 is stalled or gone). PX4 disarmed sends zero outputs: the vehicle rests.

Truth: every ``truth_every`` sensor periods one CSV row (flushed as written) with the simulation time (s), the
vehicle's position and velocity (world NWU, m, m/s, z up from the take-off point), its ZYX Euler angles (rad), the
load's position (NWU, m), the swing from the vertical (rad), the cable tension (N), the motor outputs and whether
the vehicle rests on the ground. PX4's own ULog has the same vehicle truth (``vehicle_local_position_groundtruth``)
on its clock; the load is only here.
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from estimators.model.frames import model_to_ned_vector
from estimators.model.vehicle import Vehicle
from sim_bridge.inner.px4_inner import quad_rotors
from sim_bridge.sitl.hil_sensors import HilNoise, HilSensors
from sim_bridge.sitl.hil_vehicle import HilVehicle

#: the airframe PX4 runs with an external simulator (10016: a quadrotor with no simulator of its own)
HIL_MODEL = "none_iris"
#: PX4 instance 0's simulator port; instance i adds i
HIL_PORT_BASE = 4560
#: PX4 instance 0's ground-station MAVLink port, where the cable-angle sensor's DEBUG_VECT goes; instance i adds i
PX4_MAVLINK_PORT_BASE = 18570
#: the truth CSV's columns (see the module docstring)
TRUTH_COLUMNS = (
    "t_s",
    "x_m",
    "y_m",
    "z_m",
    "vx_m_s",
    "vy_m_s",
    "vz_m_s",
    "phi_rad",
    "theta_rad",
    "psi_rad",
    "load_x_m",
    "load_y_m",
    "load_z_m",
    "swing_rad",
    "tension_n",
    "out0",
    "out1",
    "out2",
    "out3",
    "on_ground",
)


def hil_params(vehicle: Vehicle) -> dict[str, float]:
    """The PX4 parameters that give PX4's allocator the HIL physics' airframe (``Px4Sitl(params=...)``): the rotors
    where the physics has them (``quad_rotors`` of the vehicle's frame: for X airframe 10040's normalized layout,
    whose directions and spins are the physics'; PX4 normalizes the effectiveness, so the unit arms and KM 0.05
    stand for the vehicle's arm and moment coefficient as they do for SIH), thrust linear in the motor output, the
    hover thrust of the vehicle with its load, and the ULog's debug topics (the cable-angle sensor)."""
    params: dict[str, float] = {"CA_ROTOR_COUNT": 4, "THR_MDL_FAC": 0.0}
    # PX4's default log profile (1) plus its debug topics (32): the cable-angle sensor's DEBUG_VECT, which PX4
    # publishes as debug_vect, is then in the ULog and `slung replay` of it has the cable angle
    params["SDLOG_PROFILE"] = 1 | 32
    for i, r in enumerate(quad_rotors(vehicle.frame)):
        params[f"CA_ROTOR{i}_PX"], params[f"CA_ROTOR{i}_PY"], params[f"CA_ROTOR{i}_KM"] = r.px, r.py, r.km
    hover = vehicle.total_mass * vehicle.gravity / (4.0 * vehicle.motor_thrust_max)
    params["MPC_THR_HOVER"] = round(min(0.8, max(0.1, hover)), 3)
    return params


@dataclass
class HilStats:
    """What the server has done: sensor periods simulated, PX4's answers, steps it went on without one."""

    steps: int = 0
    answers: int = 0
    missed_answers: int = 0
    connected: bool = False
    armed: bool = False
    error: str | None = None
    sim_time_s: float = 0.0
    max_swing_rad: float = 0.0
    events: list[str] = field(default_factory=list)


class Px4HilServer:
    """PX4's simulator for one instance (see the module docstring).

    vehicle: the TRUE vehicle with its load; instance: PX4's instance (port 4560 + instance); seed: the sensor
    noise's; sensor_hz: HIL_SENSOR rate (PX4's IMU_INTEG_RATE for simulators is 250 Hz); plant_dt: the plant's
    step (s); speed: the simulation's pace against the wall clock (None: as fast as PX4 answers); truth_path: the
    truth CSV (None: none); initial_swing_rad: the load's swing at the start, toward north (rad; it stays so on
    the ground until the lift-off, and a landing hangs the load straight down again);
    load_sensor_hz: a cable-angle sensor's rate (0: none): DEBUG_VECT "LOADANG" (the emulator's convention) sent to
    PX4's ground-station MAVLink port 18570 + instance as a peripheral of the vehicle (system 1, component 158),
    which PX4 publishes as its ``debug_vect`` and streams on to the companion when asked (``slung fly`` asks).
    """

    def __init__(
        self,
        vehicle: Vehicle,
        *,
        instance: int = 0,
        seed: int = 0,
        sensor_hz: float = 250.0,
        gps_hz: float = 10.0,
        mag_baro_hz: float = 50.0,
        truth_hz: float = 50.0,
        plant_dt: float = 0.001,
        noise: HilNoise | None = None,
        truth_path: Path | None = None,
        answer_timeout_s: float = 2.0,
        initial_swing_rad: float = 0.0,
        speed: float | None = 1.0,
        load_sensor_hz: float = 0.0,
    ) -> None:
        if speed is not None and not speed > 0.0:
            raise ValueError(f"speed must be > 0 (or None: as fast as PX4 answers), got {speed}")
        self.speed = speed
        self.plant = HilVehicle(vehicle, plant_dt)
        if initial_swing_rad:
            s = initial_swing_rad
            x = self.plant.x
            x[12], x[13], x[14] = math.sin(s), 0.0, -math.cos(s)
        self.sensors = HilSensors(self.plant, np.random.default_rng(seed), noise)
        self.port = HIL_PORT_BASE + instance
        self.period_us = round(1e6 / sensor_hz)
        self.substeps = max(1, round(self.period_us * 1e-6 / plant_dt))
        if abs(self.substeps * plant_dt - self.period_us * 1e-6) > 1e-9:
            raise ValueError(f"plant_dt {plant_dt} s does not divide the sensor period {self.period_us} us")
        self.gps_every = max(1, round(sensor_hz / gps_hz))
        self.mag_baro_every = max(1, round(sensor_hz / mag_baro_hz))
        self.truth_every = max(1, round(sensor_hz / truth_hz))
        self.truth_path = truth_path
        self.answer_timeout_s = answer_timeout_s
        self.stats = HilStats()
        self.outputs = [0.0, 0.0, 0.0, 0.0]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: socket.socket | None = None
        self._mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=51)
        self._mav.robust_parsing = True
        #: the cable-angle sensor: DEBUG_VECT "LOADANG" to PX4's MAVLink port (a peripheral of the vehicle, which
        #: PX4 publishes as its debug_vect and streams on to the companion as DEBUG_VECT); every load_every periods
        self.load_every = max(1, round(sensor_hz / load_sensor_hz)) if load_sensor_hz > 0.0 else 0
        self._load_mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=mavlink2.MAV_COMP_ID_PERIPHERAL)
        self._load_addr = ("127.0.0.1", PX4_MAVLINK_PORT_BASE + instance)
        self._load_sock: socket.socket | None = None
        self._truth: IO[str] | None = None

    # --------------------------------------------------------------------------------------------- lifetime ---
    @property
    def running(self) -> bool:
        """Whether the service thread is alive (it ends on :meth:`stop`, when PX4 closes the link, or on a fault:
        ``stats.error``)."""
        return self._thread is not None and self._thread.is_alive()

    def open_truth(self) -> None:
        """Create the truth CSV now (OSError if it cannot be written), so that a bad path fails before PX4 starts."""
        if self.truth_path is not None and self._truth is None:
            self._truth = open(self.truth_path, "w", encoding="utf-8", buffering=1)  # noqa: SIM115 - closed in serve
            self._truth.write(",".join(TRUTH_COLUMNS) + "\n")

    def listen(self) -> None:
        """Open the TCP port PX4 connects to (before PX4 starts, so that its first attempt succeeds)."""
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", self.port))
        s.listen(1)
        s.settimeout(0.2)
        self._listener = s

    def start(self) -> Px4HilServer:
        """Listen and serve in a background thread (:meth:`stop` ends it)."""
        self.open_truth()
        if self._listener is None:
            self.listen()
        self._thread = threading.Thread(target=self.serve, name=f"px4-hil-{self.port}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the service and close the sockets (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self._listener is not None:
            self._listener.close()
            self._listener = None
        if self._load_sock is not None:
            self._load_sock.close()
            self._load_sock = None

    def __enter__(self) -> Px4HilServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -------------------------------------------------------------------------------------------- the loop ---
    def serve(self) -> None:
        """Accept PX4's connection and simulate until :meth:`stop` or PX4 closes the link."""
        if self._listener is None:
            self.listen()
        assert self._listener is not None
        conn: socket.socket | None = None
        while not self._stop.is_set() and conn is None:
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError as e:
                self.stats.error = f"listening on TCP {self.port}: {e}"
                return
        if conn is None:
            return
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.setblocking(True)  # sends block; reads wait in select (_read)
        self.stats.connected = True
        try:
            self.open_truth()
            self._loop(conn, self._truth)
        except ConnectionError:  # PX4 stopped: the end of the simulation, not a fault
            self.stats.events.append(f"{self.stats.sim_time_s:.3f} s: PX4 closed the link")
        except OSError as e:
            if not self._stop.is_set():
                self.stats.error = f"PX4's simulator link: {e}"
        except Exception as e:
            self.stats.error = f"the simulation stopped at {self.stats.sim_time_s:.3f} s: {type(e).__name__}: {e}"
        finally:
            conn.close()
            if self._truth is not None:
                self._truth.close()
                self._truth = None

    def _loop(self, conn: socket.socket, truth: IO[str] | None) -> None:
        mav, sensors, plant = self._mav, self.sensors, self.plant
        t_us = 0
        step = 0
        answered_once = False
        wall0 = time.monotonic()
        while not self._stop.is_set():
            t_us = step * self.period_us
            out = [sensors.sensor(mav, t_us, with_mag_baro=step % self.mag_baro_every == 0)]
            if step % self.gps_every == 0:
                out.append(sensors.gps(mav, t_us))
            if step % self.truth_every == 0:
                out.append(sensors.ground_truth(mav, t_us))
            conn.sendall(b"".join(m.pack(mav) for m in out))
            if self.load_every and step % self.load_every == 0:
                self._send_load_angle(t_us)
            if answered_once:
                if not self._await_answer(conn):
                    self.stats.missed_answers += 1
            else:  # PX4 is booting: read what it sent, then go on at the pace below
                self._read(conn, 0.0)
                answered_once = self.stats.answers > 0
            speed = self.speed if answered_once or self.speed is not None else 1.0
            if speed is not None:  # the wall clock paces the simulation
                ahead = (t_us + self.period_us) * 1e-6 / speed - (time.monotonic() - wall0)
                if ahead > 0.0:
                    time.sleep(ahead)
            plant.step(self.outputs, self.substeps)
            step += 1
            self.stats.steps = step
            self.stats.sim_time_s = step * self.period_us * 1e-6
            swing = plant.swing()
            self.stats.max_swing_rad = max(self.stats.max_swing_rad, swing if plant.x[2] > 0.05 else 0.0)
            if truth is not None and step % self.truth_every == 0:
                truth.write(self._truth_row(self.stats.sim_time_s, swing) + "\n")

    def _send_load_angle(self, t_us: int) -> None:
        """The cable's angles as the emulator's cable-angle sensor reports them (``docs/emulator.md``): x in the
        North-Down plane ``atan2(r_N, r_D)``, y in the East-Down plane ``atan2(r_E, r_D)``, z the total swing, rad."""
        if self._load_sock is None:
            self._load_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._load_sock.setblocking(False)
        x = self.plant.x
        r_n, r_e, r_d = model_to_ned_vector(x[12], x[13], x[14])
        msg = self._load_mav.debug_vect_encode(
            b"LOADANG", t_us, math.atan2(r_n, r_d), math.atan2(r_e, r_d), self.plant.swing()
        )
        with contextlib.suppress(OSError):  # PX4 not listening yet: the sample is lost, as on a real bus
            self._load_sock.sendto(msg.pack(self._load_mav), self._load_addr)

    def _await_answer(self, conn: socket.socket) -> bool:
        """Read until PX4's next HIL_ACTUATOR_CONTROLS (True) or the answer time-out (False)."""
        before = self.stats.answers
        deadline = time.monotonic() + self.answer_timeout_s
        while self.stats.answers == before and not self._stop.is_set():
            left = deadline - time.monotonic()
            if left <= 0.0:
                return False
            self._read(conn, min(left, 0.2))  # wake now and then to see stop()
        return self.stats.answers > before

    def _read(self, conn: socket.socket, timeout_s: float) -> None:
        """Parse what PX4 sent, waiting up to ``timeout_s`` for it (0: only what is there)."""
        ready, _, _ = select.select([conn], [], [], max(0.0, timeout_s))
        if not ready:
            return
        data = conn.recv(65536)
        if not data:
            raise ConnectionError("PX4 closed the simulator link")
        for msg in self._mav.parse_buffer(data) or []:
            if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
                c = msg.controls
                self.outputs = [c[i] if math.isfinite(c[i]) else 0.0 for i in range(4)]
                armed = bool(msg.mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
                if armed != self.stats.armed:
                    self.stats.events.append(f"{self.stats.sim_time_s:.3f} s: {'armed' if armed else 'disarmed'}")
                    self.stats.armed = armed
                self.stats.answers += 1

    def _truth_row(self, t: float, swing: float) -> str:
        x, p = self.plant.x, self.plant
        lx, ly, lz = p.load_position()
        vals = (t, *x[0:9], lx, ly, lz, swing, p.cable_tension(), *self.outputs, 1.0 if p.on_ground else 0.0)
        return ",".join(f"{v:.6g}" for v in vals)


__all__ = ["HIL_MODEL", "HIL_PORT_BASE", "TRUTH_COLUMNS", "HilStats", "Px4HilServer", "hil_params"]
