"""An autopilot that refuses: ``slung fly`` (its command line, in this process) against the bundled emulator in
lockstep over real UDP on 127.0.0.1, the emulator told to fail one check (``--refuse``: its pre-arm check, the
take-off, or the switch to PX4 OFFBOARD / ArduPilot GUIDED, answered with the autopilots' own result codes and
messages). Each run ends with exit code 2 and the autopilot's reason on one line, the same reason in the report
folder's ``events.json``, and the vehicle where a refusal must leave it: disarmed on the ground, or holding where it
was in the air."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from offboard.cli import main
from offboard.flight.supervisor import EXIT_USER_ERROR
from offboard.harness.demo_cli import EmulatorThread, free_udp_port


def fly_refused(tmp_path: Path, flavor: str, refuse: str) -> tuple[int, str, dict, dict]:
    """``slung fly`` against an emulator that refuses ``refuse``: (exit code, the error line, events.json, the
    emulator's summary)."""
    port = free_udp_port()
    emu = EmulatorThread(
        flavor,
        port,
        lockstep=True,
        period=0.004,
        vehicle=None,
        attitude_model="rigid",
        noise=0.0,
        loss=0.0,
        tlog=None,
        refuse=(refuse,),
    ).start()
    out = tmp_path / "f"
    argv = ["fly", "--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover", "--duration", "2", "--lockstep"]
    try:
        code = main([*argv, "--no-figures", "--out", str(out)])
    finally:
        summary = emu.stop()
    events = json.loads((out / "events.json").read_text())
    return code, events["error"], events, summary


@pytest.mark.slow
@pytest.mark.parametrize(
    ("flavor", "refuse", "words"),
    [
        ("px4", "arm", ("refused to arm (result 1)", "Preflight Fail: Accel Sensor 0 missing")),
        # a STATUSTEXT holds 50 characters: PX4's message arrives cut short
        ("px4", "takeoff", ("take-off refused (result 1)", "Switching to AUTO.TAKEOFF is currently not possib")),
        ("ardupilot", "takeoff", ("take-off refused (result 4)",)),
        ("ardupilot", "offboard", ("ArduPilot refused GUIDED mode",)),
    ],
)
def test_a_refusal_on_the_ground_is_a_one_line_error_and_leaves_the_vehicle_on_the_ground(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flavor: str, refuse: str, words: tuple[str, ...]
) -> None:
    code, error, events, summary = fly_refused(tmp_path, flavor, refuse)
    assert code == EXIT_USER_ERROR == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"slung fly: error: {error}", err[-3:]  # one line, the same as events.json's
    for w in words:
        assert w in error, error
    assert summary["on_ground"] and summary["altitude_m"] < 0.05
    assert "OFFBOARD" not in [name for _, name in summary["modes"]] and summary["mode"] != "GUIDED"
    c = summary["counters"]
    if refuse == "arm":
        assert not summary["armed"] and c["arm_refusals"] >= 2 and c["arms"] == 0  # retried, never armed
    elif refuse == "takeoff":
        # armed for the take-off, refused: handed to the hold mode and disarmed where it stands
        assert c["arms"] == 1 and not summary["armed"]
        assert summary["mode"] == ("AUTO.LOITER" if flavor == "px4" else "BRAKE"), summary["mode"]
        loop = [(e["kind"], e["reason"]) for e in events["loop"]]
        assert any(k == "exit" and r.startswith("hold: take-off refused") for k, r in loop), loop[-5:]
        assert ("exit_done", "disarmed on the ground") in loop, loop[-5:]
    else:  # GUIDED refused before arming: nothing else happened
        assert c["arms"] == 0 and c["mode_refusals"] >= 1 and not summary["armed"]


@pytest.mark.slow
def test_px4_refusing_offboard_after_the_take_off_is_left_holding_in_the_air(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, error, events, summary = fly_refused(tmp_path, "px4", "offboard")
    assert code == EXIT_USER_ERROR
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"slung fly: error: {error}"
    assert "refused offboard control (result 1)" in error and "Switching to OFFBOARD is currently not possible" in error
    assert summary["counters"]["mode_refusals"] >= 1
    # it flew its take-off to the hover's 1 m, then holds there, armed, never in OFFBOARD
    assert summary["armed"] and summary["mode"] == "AUTO.LOITER" and not summary["on_ground"]
    assert 0.7 < summary["altitude_m"] < 1.3, summary["altitude_m"]
    assert "OFFBOARD" not in [name for _, name in summary["modes"]]
    assert any(e["kind"] == "takeoff_done" for e in events["management"])
