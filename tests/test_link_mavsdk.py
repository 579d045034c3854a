"""The MAVSDK backend (``--backend mavsdk``) flies the bundled emulator over real UDP on 127.0.0.1: MAVSDK's
Action plugin arms, takes off and holds; the loop's setpoints and telemetry use the same socket."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from offboard.flight.fly_cli import fly
from offboard.flight.link.mavsdk_backend import MAVSDK_SYSTEM_ID
from offboard.harness.demo_cli import EmulatorThread, configure, free_udp_port


def test_mavsdk_backend_flies_the_emulator(tmp_path: Path) -> None:
    port = free_udp_port()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004).start()
    p = argparse.ArgumentParser()
    configure(p)
    args = p.parse_args(["--scenario", "hover", "--duration", "4", "--no-figures", "--out", str(tmp_path / "f")])
    args.connect, args.trajectory = f"udpin:127.0.0.1:{port}", None
    try:
        m, folder = fly(args, lockstep=True, backend="mavsdk", truth_probe=emu.truth, quiet=True)
    finally:
        summary = emu.stop()
    assert m["flight"]["ended_by"] == "completed" and m["link"]["backend"] == "mavsdk"
    assert m["max"]["e_z"] < 0.05 and m["max"]["alpha"] < 0.05
    ev = json.loads((folder / "events.json").read_text())
    kinds = [e["kind"] for e in ev["management"]]
    assert "mavsdk_arm" in kinds and "mavsdk_takeoff" in kinds and "mavsdk_hold" in kinds
    assert summary["mode"] == "AUTO.LOITER" and summary["armed"]
    assert [mm[1] for mm in summary["modes"]][-3:] == ["AUTO.LOITER", "OFFBOARD", "AUTO.LOITER"]
    # the arm and take-off commands on the wire came from MAVSDK's own system id, the setpoints from ours
    log = mavutil.mavlink_connection(str(folder / "flight.tlog"))
    cmd_src, sp_src = set(), set()
    while (msg := log.recv_match(type=["COMMAND_LONG", "SET_ATTITUDE_TARGET"])) is not None:
        if msg.get_type() == "COMMAND_LONG" and msg.command in (400, 22):
            cmd_src.add(msg.get_srcSystem())
        elif msg.get_type() == "SET_ATTITUDE_TARGET":
            sp_src.add(msg.get_srcSystem())
    assert cmd_src == {MAVSDK_SYSTEM_ID} and sp_src == {255}
    # ... and the autopilot's answers to MAVSDK's commands are ours, not a foreign system's
    sup = m["flight"]["supervision"]
    assert sup["foreign_command_acks"] == 0, sup
    # MAVSDK set the take-off altitude (a parameter set it runs blocking: the backend must keep feeding it the
    # link meanwhile), so the autopilot's take-off climbed to the reference's 1 m, not to its 2.5 m default
    assert m["flight"]["warnings"] == []
    tko = [e for e in ev["management"] if e["kind"] == "mavsdk_set_takeoff_altitude"]
    assert len(tko) == 1 and tko[0]["detail"] in ("1", "SUCCESS", "ActionResult.SUCCESS")
    log = mavutil.mavlink_connection(str(folder / "flight.tlog"))
    climb = []
    while (msg := log.recv_match(type=["LOCAL_POSITION_NED", "HEARTBEAT"])) is not None:
        if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == 1 and msg.custom_mode == 6 << 16:
            break  # OFFBOARD: the autopilot's take-off and hold are over
        if msg.get_type() == "LOCAL_POSITION_NED":
            climb.append(-msg.z)
    assert climb and 0.8 < max(climb) < 1.3
