"""A take-off command lost on the link is sent again: a UDP relay between the loop and the emulator (real sockets on
127.0.0.1, the emulator as its own process) drops every NAV_TAKEOFF of the loop's first ``command()`` (its five
tries), so the autopilot never hears it and never acknowledges it. Before the fix the loop waited 60 s for a climb
that could not come (CI, 2026-12-06: ``test_thirty_percent_packet_loss...`` lost its take-off that way); now the
vehicle that has not climbed within 5 s gets the command again and the flight completes."""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

from emulator_helpers import UdpRelay, emulator_process, stop_emulator_process
from pymavlink.dialects.v20 import common as mavlink2

from offboard.flight.fly_cli import fly
from offboard.flight.link.management import TAKEOFF_RESENDS
from offboard.harness.demo_cli import configure, free_udp_port

NAV_TAKEOFF = 22


class TakeoffDropper(UdpRelay):
    """Relays datagrams between the loop and the emulator, dropping the loop's first ``drop`` NAV_TAKEOFF commands."""

    def __init__(self, loop_port: int, drop: int) -> None:
        super().__init__(loop_port)
        self.drop = drop
        self.dropped = 0
        self.passed = 0
        self._mav = mavlink2.MAVLink(None)
        self._mav.robust_parsing = True

    def from_loop(self, data: bytes) -> bool:
        msgs = self._mav.parse_buffer(data) or []
        if not any(m.get_type() == "COMMAND_LONG" and m.command == NAV_TAKEOFF for m in msgs):
            return True
        if self.dropped < self.drop:
            self.dropped += 1
            return False
        self.passed += 1
        return True


def test_a_lost_takeoff_command_is_sent_again_and_the_flight_completes(tmp_path: Path) -> None:
    assert TAKEOFF_RESENDS >= 1
    loop_port = free_udp_port()
    relay = TakeoffDropper(loop_port, drop=5)  # Manager.command's five tries of the first take-off command
    relay.start()
    emu: subprocess.Popen = emulator_process(relay.port, "--realtime", stdout=subprocess.DEVNULL)
    p = argparse.ArgumentParser()
    configure(p)
    args = p.parse_args(["--no-figures", "--out", str(tmp_path / "run"), "--scenario", "hover", "--duration", "2"])
    args.connect, args.trajectory = f"udpin:127.0.0.1:{loop_port}", None
    try:
        m, _ = fly(args, lockstep=False, quiet=True)
    finally:
        stop_emulator_process(emu)
        relay.stop = True
    assert relay.dropped == 5 and relay.passed >= 1  # the first command never arrived; a later one did
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    assert "take-off command not acknowledged; waiting for the climb" not in m["flight"]["warnings"]
