"""Every fault ends in the hand-over (issue 10, item 3) and bad input is one line (item 7): non-finite telemetry
refused before any conversion, a tlog that cannot be written (the kernel's ENOSPC, from /dev/full) stops the
logging and not the flight, an exception inside the flight ends in hold with a report, and implausible vehicle
files, trajectories and limits are refused with their limit before anything connects. Flights against the bundled
emulator in lockstep over real UDP on 127.0.0.1."""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink2

from estimators.model.frames import ned_euler_to_model, wrap_angle
from offboard.cli import main
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.flight.link.telemetry import TelemetryDecoder
from offboard.flight.supervisor import EXIT_ABORTED, exit_code
from offboard.harness.demo_cli import EmulatorThread, free_udp_port


def test_non_finite_attitude_is_refused_before_any_conversion() -> None:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    dec = TelemetryDecoder(system=1)
    for bad in (math.inf, -math.inf, math.nan):
        raw = mav.attitude_encode(1000, 0.1, 0.0, bad, 0.0, 0.0, 0.0).pack(mav)
        msg = mavlink2.MAVLink(None).decode(bytearray(raw))
        assert dec.decode(msg) is None
    assert dec.counts["refused_nonfinite"] == 3
    ok = mavlink2.MAVLink(None).decode(bytearray(mav.attitude_encode(1000, 0.1, 0.0, 3.0, 0, 0, 0).pack(mav)))
    assert dec.decode(ok) is not None
    # the wrap itself no longer raises on inf ("math domain error"): it gives NaN, which every check refuses
    assert math.isnan(wrap_angle(math.inf)) and math.isnan(ned_euler_to_model(0.0, 0.0, -math.inf)[2])


def _args(port: int, out: Path, *extra: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    fly_configure(p)
    return p.parse_args(
        [
            *("--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover", "--duration", "3", "--lockstep"),
            *("--no-figures", "--out", str(out), *extra),
        ]
    )


def _fly(out: Path, probe_hook: Any = None) -> tuple[dict, dict]:
    port = free_udp_port()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004).start()
    t0 = [math.inf]

    def probe(t: float) -> Any:
        if probe_hook is not None:
            probe_hook(t - t0[0])
        return emu.truth(t)

    def start(t: float) -> None:
        t0[0] = t

    try:
        m, _ = fly(_args(port, out), lockstep=True, truth_probe=probe, quiet=True, on_reference_start=start)
    finally:
        summary = emu.stop()
    return m, summary


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full on this machine")
def test_a_tlog_that_cannot_be_written_stops_logging_not_the_flight(tmp_path: Path) -> None:
    out = tmp_path / "f"
    out.mkdir()
    (out / "flight.tlog").symlink_to("/dev/full")  # every write fails with ENOSPC, as on a full disk
    m, summary = _fly(out)
    assert m["flight"]["ended_by"] == "completed" and m["completed"]
    failure = m["link"]["tlog_failure"]
    assert failure is not None and "writing stopped after 0 records" in failure
    assert any("writing stopped" in w for w in m["flight"]["warnings"])
    assert m["link"]["tlog_records"] == 0 and summary["mode"] == "AUTO.LOITER"


@pytest.mark.slow
def test_an_exception_inside_the_flight_ends_in_hold_with_a_report(tmp_path: Path) -> None:
    def hook(t_ref: float) -> None:
        if t_ref > 1.0:
            raise RuntimeError("probe failure injected by the test")

    m, summary = _fly(tmp_path / "f", hook)
    assert m["flight"]["ended_by"] == "internal_error" and exit_code("internal_error") == EXIT_ABORTED
    ev = json.loads((tmp_path / "f" / "events.json").read_text())["loop"]
    err = next(e for e in ev if e["kind"] == "internal_error")
    assert "RuntimeError: probe failure injected by the test" in err["reason"]
    assert any(e["kind"] == "exit_done" and e["reason"].startswith("hold") for e in ev)
    assert summary["mode"] == "AUTO.LOITER" and summary["armed"]


BAD_VEHICLES = [
    (b'[vehicle]\nname = "caf\xe9"\n', "not UTF-8"),
    (b"[vehicle]\nmass_kg = 1e-12\n", "mass_vehicle = 1e-12 kg is outside the plausible range 0.01..100 kg"),
    (b"[load]\ncable_length_m = 1e-9\n", "cable_length = 1e-09 m is outside the plausible range 0.05..30 m"),
    (b"[environment]\ngravity_m_s2 = 1e-300\n", "plausible range 1..30 m/s^2"),
    (b"[vehicle]\nmotor_time_constant_s = 1e300\n", "motor_time_constant = 1e+300 s is outside"),
    (b"[vehicle]\nmotor_thrust_max_n = 1e308\n", "motor_thrust_max = 1e+308 N is outside the plausible range"),
    (b"[vehicle]\ninertia_kg_m2 = [0.1, 0.1, 1e9]\n", "inertia"),
]


def _refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    # a listener where the flight would connect: every refusal must come before any packet is sent
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.05)
    try:
        code = main(
            ["fly", "--connect", f"udpout:127.0.0.1:{sock.getsockname()[1]}", "--out", str(tmp_path / "o"), *argv]
        )
        with pytest.raises(TimeoutError):
            sock.recvfrom(100)
    finally:
        sock.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


@pytest.mark.parametrize(("content", "words"), BAD_VEHICLES)
def test_implausible_or_unreadable_vehicle_files_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, words: str
) -> None:
    f = tmp_path / "v.toml"
    f.write_bytes(content)
    line = _refused(tmp_path, capsys, "--scenario", "hover", "--vehicle", str(f))
    assert words in line, line


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (("--scenario", "hover", "--duration", "1e9"), "duration 1e+09 s outside the plausible range 0.5..3600 s"),
        (("--scenario", "hover", "--swing-limit", "1e9"), "swing limit must be within 0.05..1.2 rad"),
        (("--scenario", "hover", "--divergence-limit", "1e6"), "divergence limit must be within 0.05..10 m"),
        (("--scenario", "hover", "--tracking-limit", "1e6"), "tracking-error limit must be within 0.05..100 m"),
        (("--scenario", "hover", "--settle", "1e4"), "settle time must be within 0..600 s"),
        (("--scenario", "hover", "--settle-swing", "0.9"), "settle swing must be within 0.005 rad..the swing limit"),
        (("--trajectory", "{low}"), "height -5 m above the take-off point at t = 0 s is outside the plausible"),
        (("--trajectory", "{high}"), "height 1e+06 m above the take-off point"),
    ],
)
def test_implausible_references_and_limits_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: tuple[str, ...], words: str
) -> None:
    wp = "[[waypoint]]\nt = 0.0\nx = 0.0\ny = 0.0\nz = {z}\n[[waypoint]]\nt = 5.0\nx = 0.0\ny = 0.0\nz = {z}\n"
    files = {}
    for name, z in (("low", "-5.0"), ("high", "1e6")):
        files[name] = tmp_path / f"{name}.toml"
        files[name].write_text(wp.format(z=z), encoding="utf-8")
    argv = tuple(a.format(low=files["low"], high=files["high"]) for a in argv)
    line = _refused(tmp_path, capsys, *argv, "--force")
    assert words in line, line


@pytest.mark.slow
def test_the_exit_stream_after_a_signal_is_paced_at_the_loop_rate(tmp_path: Path) -> None:
    """Real time, the emulator in its own process behind a relay that, once the controlled flight runs, drops the
    loop's commands (so the hold it asks for is never confirmed and the loop streams hover setpoints for its whole
    exit time-out). SIGTERM then: the exit stream must stay paced at the loop rate (it was resent unpaced, about
    21 000 setpoints in 1 s, because every wait returned at once while the signal was pending)."""
    import select
    import signal
    import threading
    import time

    from pymavlink import mavutil
    from test_loop_failsafe import demo_args, start_emulator, stop_emulator

    loop_port = free_udp_port()
    relay = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    relay.bind(("127.0.0.1", 0))
    state: dict[str, Any] = {"emu": None, "drop": False, "stop": False, "dropped": 0}

    def run_relay() -> None:
        while not state["stop"]:
            r, _, _ = select.select([relay], [], [], 0.05)
            if not r:
                continue
            data, addr = relay.recvfrom(65535)
            if addr == ("127.0.0.1", loop_port):
                is_cmd = len(data) > 10 and data[0] == 0xFD and data[7] | (data[8] << 8) | (data[9] << 16) == 76
                if is_cmd and state["drop"]:
                    state["dropped"] += 1
                elif state["emu"] is not None:
                    relay.sendto(data, state["emu"])
            else:
                state["emu"] = addr
                relay.sendto(data, ("127.0.0.1", loop_port))

    th = threading.Thread(target=run_relay, daemon=True)
    th.start()
    summary_path = tmp_path / "emu.json"
    emu = start_emulator(relay.getsockname()[1], "--realtime", summary=summary_path)
    # the relay runs in this test's interpreter, beside the loop: on a loaded machine it holds packets for 0.1 s
    # and more (CI at load 12: telemetry 103 ms old, the latency watchdog ended the flight before the signal);
    # the latency watchdog is not under test here (tests/test_delay_tolerance.py is its test)
    args = demo_args(tmp_path, "--scenario", "hover", "--duration", "20", "--rate", "100", "--latency-limit", "0.5")
    args.connect, args.trajectory = f"udpin:127.0.0.1:{loop_port}", None

    def on_start(t0: float) -> None:
        def later() -> None:
            time.sleep(1.0)
            state["drop"] = True
            time.sleep(0.5)
            state["signal_at"] = time.time()
            os.kill(os.getpid(), signal.SIGTERM)

        threading.Thread(target=later, daemon=True).start()

    try:
        m, folder = fly(args, lockstep=False, quiet=True, on_reference_start=on_start)
    finally:
        stop_emulator(emu, summary_path)
        state["stop"] = True
        th.join(5.0)
        relay.close()
    assert m["flight"]["ended_by"] == "signal" and "not confirmed" in m["flight"]["end_state"], m["flight"]
    assert state["dropped"] >= 1
    log = mavutil.mavlink_connection(str(folder / "flight.tlog"))
    stamps = []
    while (msg := log.recv_match(type="SET_ATTITUDE_TARGET")) is not None:
        if msg._timestamp >= state["signal_at"]:
            stamps.append(msg._timestamp)
    # the exit time-out is 2 s at 100 Hz: about 200 setpoints; generous bounds for a loaded machine
    span = stamps[-1] - stamps[0]
    print(f"{len(stamps)} setpoints in {span:.2f} s after the signal")
    assert 1.5 <= span <= 4.0 and 50 <= len(stamps) <= 1.5 * 100 * span + 10
