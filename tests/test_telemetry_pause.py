"""A telemetry pause the vehicle survives does not end the flight (issue 39): ``slung fly`` against the bundled
emulator in lockstep over real UDP on 127.0.0.1, through a relay that drops every telemetry datagram of the
emulator (all but its HEARTBEAT and its lockstep step markers) for 250 ms of vehicle time, 2 s into the controlled
flight. The staleness limit is derived from the link's gaps in the hold before control (``offboard.flight.staleness``):
the pause is flown on the filter's prediction and reported; with a fixed 0.1 s limit the same pause ends the flight
on the watchdog (the pause is real, and the watchdog still works)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
from emulator_helpers import UdpRelay

from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, free_udp_port

SYSTEM_TIME, HEARTBEAT, SET_ATTITUDE_TARGET = 2, 0, 82
STEP_S = 0.004
PAUSE_S = 0.25


def msgid(data: bytes) -> int:
    """The message id of a MAVLink 2 datagram (one message per datagram on this link), -1 for anything else."""
    if len(data) > 10 and data[0] == 0xFD:
        return data[7] | (data[8] << 8) | (data[9] << 16)
    return -1


class PauseRelay(UdpRelay):
    """Forwards everything, except that once the loop has sent ``after`` attitude setpoints (the controlled
    flight's), the emulator's datagrams other than HEARTBEAT and the step markers are dropped for ``markers``
    step markers (vehicle time: the emulator advances one step per marker)."""

    def __init__(self, loop_port: int, after: int, markers: int) -> None:
        super().__init__(loop_port)
        self.after, self.markers = after, markers
        self.setpoints = 0
        self.left: int | None = None
        self.dropped = 0

    def from_loop(self, data: bytes) -> bool:
        if msgid(data) == SET_ATTITUDE_TARGET:
            self.setpoints += 1
        return True

    def from_emulator(self, data: bytes) -> bool:
        if self.left is None and self.setpoints >= self.after:
            self.left = self.markers
        if not self.left:
            return True
        mid = msgid(data)
        if mid == SYSTEM_TIME:
            self.left -= 1
            return True
        if mid == HEARTBEAT:
            return True
        self.dropped += 1
        return False


def fly_through_pause(tmp_path: Path, *extra: str) -> tuple[dict, list[dict], PauseRelay]:
    loop_port = free_udp_port()
    relay = PauseRelay(loop_port, after=500, markers=round(PAUSE_S / STEP_S))  # 2 s of control at 250 Hz
    relay.start()
    emu = EmulatorThread("px4", relay.port, lockstep=True, period=STEP_S).start()
    p = argparse.ArgumentParser()
    fly_configure(p)
    out = tmp_path / "f"
    args = p.parse_args(
        [
            *("--connect", f"udpin:127.0.0.1:{loop_port}", "--scenario", "hover", "--duration", "5", "--lockstep"),
            *("--no-figures", "--out", str(out), *extra),
        ]
    )
    try:
        m, folder = fly(args, lockstep=True, quiet=True)
    finally:
        emu.stop()
        relay.stop = True
    return m, json.loads((folder / "events.json").read_text())["loop"], relay


@pytest.mark.slow
def test_a_250_ms_telemetry_pause_is_bridged_on_the_prediction_and_reported(tmp_path: Path) -> None:
    m, events, relay = fly_through_pause(tmp_path)
    assert relay.left == 0 and relay.dropped > 100, (relay.left, relay.dropped)  # the pause happened, in flight
    assert m["flight"]["ended_by"] == "completed", [e for e in events if e["kind"] not in ("phase",)]
    st = m["loop"]["staleness"]
    assert st["limit_s"] > PAUSE_S and m["loop"]["stale_limit_s"] == st["limit_s"]
    assert st["hold_gaps"]["Attitude"]["n"] > 100  # measured in the hold
    assert st["bridged_gaps"] >= 1 and PAUSE_S - 0.01 <= st["bridged_gap_max_s"] <= PAUSE_S + 0.05, st
    gaps = [e for e in events if e["kind"] == "telemetry_gap"]
    assert gaps and "bridged on the filter's prediction" in gaps[0]["reason"], gaps
    assert any(e["kind"] == "phase" and e["reason"].startswith("telemetry gaps in the hold") for e in events)


@pytest.mark.slow
def test_the_same_pause_ends_the_flight_under_a_fixed_0_1_s_limit(tmp_path: Path) -> None:
    m, _, relay = fly_through_pause(tmp_path, "--stale-limit", "0.1")
    assert relay.dropped > 0
    assert m["flight"]["ended_by"] == "telemetry_stale"
    assert m["loop"]["staleness"]["limit_s"] == 0.1
