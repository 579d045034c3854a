"""Refused data is told, not only counted (issue 39): ``slung fly`` against the bundled emulator in lockstep over
real UDP on 127.0.0.1, through a relay that, once the controlled flight runs, sends a non-finite ATTITUDE of the
autopilot's own system after each real one (1000 of them) and, now and then, a HEARTBEAT of another system (42).
Each kind becomes an event and a warning line at once, then at most one per kind every 5 s, and the last event
counts them all; the flight itself flies on (the real telemetry is still there). The rate limit on its own."""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
from pathlib import Path

import pytest
from emulator_helpers import UdpRelay

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink2

from offboard.flight.dropped_data import DroppedData
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, free_udp_port

ATTITUDE, SET_ATTITUDE_TARGET = 30, 82
NAN_RECORDS = 1000


def msgid(data: bytes) -> int:
    if len(data) > 10 and data[0] == 0xFD:
        return data[7] | (data[8] << 8) | (data[9] << 16)
    return -1


class NanRelay(UdpRelay):
    """Forwards everything; from the loop's 100th attitude setpoint on, after each of the emulator's ATTITUDE also
    a NaN one of system 1 (``NAN_RECORDS`` in all), and after every 50th a HEARTBEAT of system 42."""

    def __init__(self, loop_port: int) -> None:
        super().__init__(loop_port)
        self.setpoints = 0
        self.nan_sent = 0
        self.foreign_sent = 0
        self.autopilot = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.other = mavlink2.MAVLink(None, srcSystem=42, srcComponent=1)

    def from_loop(self, data: bytes) -> bool:
        if msgid(data) == SET_ATTITUDE_TARGET:
            self.setpoints += 1
        return True

    def from_emulator(self, data: bytes) -> bool:
        if msgid(data) == ATTITUDE and self.setpoints >= 100 and self.nan_sent < NAN_RECORDS:
            self.sock.sendto(data, self.loop_addr)  # the real one first, then its NaN twin
            bad = self.autopilot.attitude_encode(0, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0).pack(self.autopilot)
            self.sock.sendto(bad, self.loop_addr)
            self.nan_sent += 1
            if self.nan_sent % 50 == 0:
                hb = self.other.heartbeat_encode(6, 8, 0, 0, 0).pack(self.other)
                self.sock.sendto(hb, self.loop_addr)
                self.foreign_sent += 1
            return False
        return True


@pytest.mark.slow
def test_nan_telemetry_and_a_foreign_system_become_events_and_warning_lines(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    loop_port = free_udp_port()
    relay = NanRelay(loop_port)
    relay.start()
    emu = EmulatorThread("px4", relay.port, lockstep=True, period=0.004).start()
    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(
        [
            *("--connect", f"udpin:127.0.0.1:{loop_port}", "--scenario", "hover", "--duration", "6", "--lockstep"),
            *("--no-figures", "--out", str(tmp_path / "f")),
        ]
    )
    caplog.set_level(logging.WARNING, logger="offboard.flight.loop")
    try:
        m, folder = fly(args, lockstep=True, quiet=True)
    finally:
        emu.stop()
        relay.stop = True
    assert relay.nan_sent == NAN_RECORDS and relay.foreign_sent >= 10
    assert m["flight"]["ended_by"] == "completed"
    assert m["flight"]["telemetry"]["refused_nonfinite"] == NAN_RECORDS
    events = json.loads((folder / "events.json").read_text())["loop"]
    nan = [e for e in events if e["kind"] == "nonfinite_telemetry"]
    # told at once (within the first ticks of it), rate-limited (4 s of NaN: at most one more before the end), all
    # counted
    assert 2 <= len(nan) <= 3, nan
    assert int(nan[0]["reason"].split()[0]) <= 5 and "non-finite field refused" in nan[0]["reason"], nan[0]
    assert nan[-1]["reason"].endswith(f"({NAN_RECORDS} in all)")
    # another system on the link: told once (the emulator's load, system 2, is one too)
    foreign = [e["reason"] for e in events if e["kind"] == "foreign_system"]
    assert sum("system 42 " in r for r in foreign) == 1, foreign
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert sum(w.startswith("nonfinite_telemetry: ") for w in warned) == len(nan), warned
    assert any(w.startswith("foreign_system: MAVLink system 42 ") for w in warned), warned


def test_the_rate_limit_reports_the_first_at_once_then_one_per_interval_and_the_rest_at_the_end() -> None:
    d = DroppedData(interval_s=5.0)
    assert d.check(0.0, {"nonfinite_telemetry": 0}) == []
    assert d.check(1.0, {"nonfinite_telemetry": 1}) == [
        ("nonfinite_telemetry", "1 telemetry records with a non-finite field refused (1 in all)")
    ]
    assert d.check(2.0, {"nonfinite_telemetry": 500}) == []  # within 5 s of the last
    assert d.check(6.5, {"nonfinite_telemetry": 900})[0][1].startswith("899 ")
    assert d.check(7.0, {"nonfinite_telemetry": 1000}) == []
    assert d.flush(7.5, {"nonfinite_telemetry": 1000, "foreign_sender": 0}) == [
        ("nonfinite_telemetry", "100 telemetry records with a non-finite field refused (1000 in all)")
    ]
    assert d.flush(8.0, {"nonfinite_telemetry": 1000}) == []
