"""The HIL server's lockstep exchange at its edges, over a real TCP socket on 127.0.0.1, with this test in PX4's
place (``tests/test_px4_hil.py`` flies real PX4; what PX4 never does on demand is tested here): answers split across
TCP segments, an answer that does not come, PX4 closing the link, and :meth:`Px4HilServer.stop` while the server
waits for an answer."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from estimators.model.vehicle import load_vehicle
from sim_bridge.sitl.px4_hil import Px4HilServer

VEHICLE = load_vehicle("px4-hil-load")
INSTANCE = 9  # TCP 4569: no test starts PX4 instance 9


def _connect(server: Px4HilServer) -> socket.socket:
    deadline = time.monotonic() + 5.0
    while True:
        try:
            return socket.create_connection(("127.0.0.1", server.port), timeout=5.0)
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def _sensors(conn: socket.socket, mav: mavlink2.MAVLink, n: int) -> list[int]:
    """The time_usec of the next ``n`` HIL_SENSOR messages the server sends."""
    stamps: list[int] = []
    while len(stamps) < n:
        data = conn.recv(65536)
        assert data, "the server closed the link"
        for m in mav.parse_buffer(data) or []:
            if m.get_type() == "HIL_SENSOR":
                stamps.append(m.time_usec)
    return stamps


def _answer(mav: mavlink2.MAVLink, outputs: float) -> bytes:
    controls = [outputs] * 4 + [0.0] * 12
    mode = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED | 1
    return mav.hil_actuator_controls_encode(0, controls, mode, 1).pack(mav)


@pytest.fixture
def server() -> Px4HilServer:
    s = Px4HilServer(VEHICLE, instance=INSTANCE, speed=None, answer_timeout_s=0.3)
    s.start()
    yield s
    s.stop()


def test_answers_split_across_segments_hold_the_outputs_and_step_in_lockstep(server: Px4HilServer) -> None:
    px4 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    with _connect(server) as conn:
        first = _sensors(conn, px4, 1)[0]
        hover = VEHICLE.total_mass * VEHICLE.gravity / (4 * VEHICLE.motor_thrust_max)
        for _ in range(50):
            frame = _answer(px4, 1.2 * hover)
            conn.sendall(frame[:7])  # a frame cut inside its header ...
            time.sleep(0.002)
            conn.sendall(frame[7:])  # ... and its rest in the next segment
            stamps = _sensors(conn, px4, 1)
        assert server.stats.answers == 50 and server.stats.missed_answers == 0
        assert server.stats.armed and any(e.endswith(": armed") for e in server.stats.events)
        # each answer advanced exactly one 4 ms sensor period (lockstep), and the vehicle lifted off
        assert stamps[-1] - first == pytest.approx(server.stats.steps * 4000 - 4000, abs=4000 * 3)
        assert server.outputs == pytest.approx([1.2 * hover] * 4)
        assert not server.plant.on_ground and server.plant.x[2] > 0.0


def test_a_missing_answer_is_counted_and_px4_closing_the_link_ends_the_service(server: Px4HilServer) -> None:
    px4 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    with _connect(server) as conn:
        _sensors(conn, px4, 1)
        conn.sendall(_answer(px4, 0.0))
        _sensors(conn, px4, 1)  # lockstep from now on: the server waits 0.3 s for each answer
        time.sleep(0.8)
        assert server.stats.missed_answers >= 1  # it went on without one, and said so
        assert server.running
    deadline = time.monotonic() + 3.0
    while server.running and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not server.running
    assert server.stats.error is None
    assert server.stats.events[-1].endswith("PX4 closed the link")


def test_stop_ends_the_service_promptly_while_it_waits_for_an_answer(server: Px4HilServer) -> None:
    px4 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    slow = Px4HilServer(VEHICLE, instance=INSTANCE - 1, speed=None, answer_timeout_s=30.0)
    slow.start()
    try:
        with _connect(slow) as conn:
            _sensors(conn, px4, 1)
            conn.sendall(_answer(px4, 0.0))
            _sensors(conn, px4, 1)  # now it waits up to 30 s for the next answer
            t0 = time.monotonic()
            slow.stop()
            assert time.monotonic() - t0 < 2.0
            assert not slow.running and slow.stats.error is None
    finally:
        slow.stop()
    assert server.running  # the fixture's server, untouched
