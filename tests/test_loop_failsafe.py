"""Failsafes of the live loop against the bundled emulator over real UDP on 127.0.0.1: telemetry cut, 30 % packet
loss, NaN injected at every stage of the pipeline, SIGTERM in flight."""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")
from emulator_helpers import UdpRelay, emulator_process, stop_emulator_process
from pymavlink import mavutil

from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, configure, free_udp_port, run_demo
from offboard.logs.timeseries_file import read_table

ROOT = Path(__file__).resolve().parents[1]


def demo_args(tmp_path: Path, *extra: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    configure(p)
    return p.parse_args(["--no-figures", "--out", str(tmp_path / "run"), *extra])


class Relay(UdpRelay):
    """UDP relay emulator <-> loop on 127.0.0.1 that stops forwarding the emulator's packets (telemetry) once the
    loop has sent ``cut_after`` SET_ATTITUDE_TARGET messages; the loop's packets keep flowing to the emulator."""

    def __init__(self, loop_port: int, cut_after: int) -> None:
        super().__init__(loop_port)
        self.cut_after = cut_after
        self.setpoints = 0
        self.cut_at: float | None = None

    def from_loop(self, data: bytes) -> bool:
        if len(data) > 10 and data[0] == 0xFD and data[7] | (data[8] << 8) | (data[9] << 16) == 82:
            self.setpoints += 1
            if self.setpoints >= self.cut_after and self.cut_at is None:
                self.cut_at = time.monotonic()
        return True

    def from_emulator(self, data: bytes) -> bool:
        return self.cut_at is None


def tlog_messages(path: Path) -> list:
    log = mavutil.mavlink_connection(str(path))
    out = []
    while (m := log.recv_match()) is not None:
        out.append(m)
    return out


def start_emulator(port: int, *extra: str, summary: Path) -> subprocess.Popen:
    """``slung emulate`` as its own process, writing its JSON summary to ``summary``."""
    return emulator_process(port, "--summary", str(summary), *extra, stdout=subprocess.DEVNULL)


def stop_emulator(proc: subprocess.Popen, summary: Path) -> dict:
    stop_emulator_process(proc)
    return json.loads(summary.read_text())


def test_telemetry_cut_leads_to_hold_within_limit(tmp_path: Path) -> None:
    """Real time (the limit is a wall-clock limit): the relay stops the emulator's packets 2 s into the controlled
    flight; the loop must ask for hold between the limit and the limit + 0.2 s after the last packet it received.

    The limit is set to 0.25 s here rather than the 0.1 s default: on a shared 2-core CI machine running the
    emulator, the loop and the test at once, a scheduling gap of 0.1 s before the cut sometimes tripped the
    watchdog early (correctly, but then the cut itself went untested). The check is the same, relative to the limit.
    """
    limit = 0.25
    loop_port = free_udp_port()
    relay = Relay(loop_port, cut_after=500)  # 2 s of control at 250 Hz
    relay.start()
    summary_path = tmp_path / "emu.json"
    emu = start_emulator(relay.port, "--realtime", summary=summary_path)
    # the relay shares this test's interpreter: under load it delays the telemetry by 0.1-0.2 s before the cut
    # (CI at load 12: the latency watchdog ended the flight first); the latency watchdog is tested on its own
    # (tests/test_delay_tolerance.py), here it must not pre-empt the staleness watchdog under test
    args = demo_args(
        tmp_path, "--scenario", "hover", "--duration", "10", "--stale-limit", str(limit), "--latency-limit", "0.5"
    )
    args.connect, args.trajectory = f"udpin:127.0.0.1:{loop_port}", None
    try:
        m, folder = fly(args, lockstep=False, quiet=True)
    finally:
        summary = stop_emulator(emu, summary_path)
        relay.stop = True
    assert relay.cut_at is not None
    assert m["flight"]["ended_by"] == "telemetry_stale"
    assert summary["mode"] == "AUTO.LOITER" and summary["armed"]
    msgs = tlog_messages(folder / "flight.tlog")
    last_rx = max(mm._timestamp for mm in msgs if mm.get_srcSystem() == 1)
    # the watchdog watches ATTITUDE and position: the first of the two to go stale sets the limit's start
    last_watched = min(
        max(mm._timestamp for mm in msgs if mm.get_srcSystem() == 1 and mm.get_type() == kind)
        for kind in ("ATTITUDE", "LOCAL_POSITION_NED")
    )
    holds = [
        mm._timestamp
        for mm in msgs
        if mm.get_type() == "COMMAND_LONG"
        and mm.command == 176
        and (mm.param2, mm.param3) == (4.0, 3.0)
        and mm._timestamp > last_rx
    ]
    assert holds, "no hold command after the telemetry stopped"
    delay = holds[0] - last_watched
    assert m["loop"]["stale_limit_s"] == limit
    # the hold request leaves between the limit and the limit + 0.2 s
    assert limit - 0.005 <= delay <= limit + 0.2, (delay, holds[0] - last_rx)


def test_a_large_host_process_does_not_stall_the_start_of_the_flight(tmp_path: Path) -> None:
    """Regression: the loop used to run a full garbage collection between its last telemetry read and its first
    tick. With `slung demo`'s emulator thread in the same process, the collection (which holds the interpreter
    lock) stalled the telemetry too, and in a process with a large heap (this test session, a host application)
    it lasted longer than the 0.1 s stale limit: the watchdog ended the real-time flight before its first tick.

    Here the process holds a heap whose full collection takes at least twice that limit, and every collection of
    the process is watched (``gc.callbacks``, the interpreter's own hook): none may run from the start of offboard
    control to the hand-over (the loop freezes and disables the collector there), and preflight's full collection
    must have run before it. That holds on any machine, loaded or not. The flight is flown in real time (where the
    stall did its harm) and must complete; its staleness and latency limits are 0.5 s, not 0.1 s, because on a
    shared 2-core machine at load 12 the scheduler alone starves a real-time flight for 0.1-0.2 s (the flight's
    end is not what this test is about; the watched collections are)."""
    heap: list[list[int]] = []
    took = 0.0
    while took < 0.2 and len(heap) < 12_000_000:  # grow until a full collection costs 2x the default stale limit
        heap.extend([] for _ in range(1_000_000))
        t = time.perf_counter()
        gc.collect()
        took = time.perf_counter() - t
    collections: list[tuple[float, int]] = []  # (local monotonic time at its start, generation)

    def watch(phase: str, info: dict) -> None:
        if phase == "start":
            collections.append((time.monotonic(), info["generation"]))

    gc.callbacks.append(watch)
    try:
        m, folder, _emu = run_demo(
            demo_args(
                tmp_path,
                *("--scenario", "hover", "--duration", "2", "--realtime", "--sensors", "ideal", "--disturbance"),
                *("none", "--stale-limit", "0.5", "--latency-limit", "0.5"),
            ),
            quiet=True,
        )
    finally:
        gc.callbacks.remove(watch)
        del heap
    assert took > 0.1  # a collection here costs more than the default stale limit: the stall was there to be had
    ev = json.loads((folder / "events.json").read_text())["loop"]
    start = next(e["t_local"] for e in ev if e["reason"] == "offboard control started")
    end = next(e["t_local"] for e in ev if e["kind"] == "exit")
    assert [c for c in collections if start <= c[0] <= end] == [], (start, end, collections[-5:])
    assert any(g == 2 for t, g in collections if t < start)  # preflight's full collection, before any setpoint
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    ticks = len(read_table(folder / "timeseries_live.slts"))
    # it flew under control: 500 ticks at 250 Hz on a quiet machine; a wall-clock figure, so a generous bound
    # (275-365 measured at load 3.5-12, 121 at load 16 on 2 cores)
    assert ticks > 50


def test_thirty_percent_packet_loss_flies_within_the_watchdogs_or_ends_in_hold(tmp_path: Path) -> None:
    """30 % of the datagrams lost each way (lockstep, 100 Hz: gaps of 20-40 ms between attitude samples). The
    filter carries the tilt across them with the commanded tilt acceleration and the IMU's gyro
    (``estimators.filters.measured_kf``); the telemetry ages taken only of fresh samples keep the loss from reading
    as link delay. What one run can promise is the safety property: every setpoint finite, and either the hover
    completes inside the supervision's limits (swing 0.8 rad, tracking 2 m) or a watchdog ends it with the vehicle
    holding. How well it flies is a rate, not a promise of each run (the loss pattern differs from run to run even
    in lockstep: the link's one generator also draws for the wall-clock-paced start): over 64 hovers (fault seeds
    100-115 x sensor seeds 0-3) with the paper's sign switching 59 stayed within 0.3 m and 0.3 rad, 4 swung up in
    world y (the roll axis) and were ended by the swing limit, 1 by telemetry_stale; with the flight's default law
    since 4 Dec 2026 (per-loop boundary layers, the motors' lag designed in) 64 of 64, swing at most 0.026 rad
    (docs/estimation.md 0.3); a run that completed with 0.68 rad of swing was seen once in CI (2026-12-02). About
    3 % of starts used to lose the OFFBOARD confirmation (three 1 Hz heartbeats in a row lost, 0.3^3); the
    supervisor now waits for two heartbeats without the mode, up to 9 s, so that a ``mode_not_entered`` hold takes
    nine lost in a row (0.3^9)."""
    m, folder, emu = run_demo(
        demo_args(tmp_path, "--scenario", "hover", "--duration", "4", "--rate", "100", "--loss", "0.3"), quiet=True
    )
    lost = emu["link"]["rx"]["dropped_in"]
    assert lost > 100  # the loss really happened
    sps = [mm for mm in tlog_messages(folder / "flight.tlog") if mm.get_type() == "SET_ATTITUDE_TARGET"]
    assert sps and all(math.isfinite(v) for s in sps for v in (*s.q, s.thrust))
    ended_by = m["flight"]["ended_by"]
    if ended_by == "completed":
        assert m["all_finite"]
        assert m["max"]["alpha"] < 0.8, m["max"]  # the true swing, against the swing watchdog's limit
        assert max(m["max"]["e_Fx"], m["max"]["e_Fy"], m["max"]["e_z"]) < 2.0, m["max"]  # the tracking limit
    else:
        assert ended_by in ("telemetry_stale", "estimator_divergence", "swing_limit", "mode_not_entered"), ended_by
        assert emu["mode"] == "AUTO.LOITER"


@pytest.mark.parametrize("output", ["attitude", "actuator"])
def test_nan_anywhere_never_reaches_the_wire(tmp_path: Path, output: str) -> None:
    inject = (("measurement", 1.0, 1.05), ("reference", 2.0, 2.02), ("command", 3.0, 3.02), ("estimate", 4.0, 4.02))
    m, folder, emu = run_demo(
        demo_args(tmp_path, "--scenario", "hover", "--duration", "6", "--output", output), inject=inject, quiet=True
    )
    # NaN measurements reached the filter and were refused there; NaN reference and command were replaced by the
    # mapper; a NaN estimate tripped the divergence watchdog, which left the vehicle holding
    assert m["estimation"]["stats"]["nan_rejected"] > 0
    ev = json.loads((folder / "events.json").read_text())
    fb_times = [e["t"] for e in ev["mapping"]]
    assert any(1.99 <= t <= 2.03 for t in fb_times) and any(2.99 <= t <= 3.03 for t in fb_times)
    assert m["flight"]["ended_by"] == "estimator_divergence" and emu["mode"] == "AUTO.LOITER"
    # the bytes on the wire (our own tlog) and what the autopilot saw
    kind = "SET_ATTITUDE_TARGET" if output == "attitude" else "SET_ACTUATOR_CONTROL_TARGET"
    sps = [mm for mm in tlog_messages(folder / "flight.tlog") if mm.get_type() == kind]
    assert len(sps) > 900
    for s in sps:
        vals = (
            [*s.q, s.body_roll_rate, s.body_pitch_rate, s.body_yaw_rate, s.thrust]
            if output == "attitude"
            else list(s.controls)
        )
        assert all(math.isfinite(v) for v in vals)
    assert emu["link"]["rx"]["malformed"] == 0 and emu["counters"]["setpoints_rejected"] == 0


@contextlib.contextmanager
def _fly_hover_in_a_process(
    tmp_path: Path, *extra: str
) -> Iterator[tuple[EmulatorThread, subprocess.Popen, Path, dict[str, Any]]]:
    """The PX4 emulator in lockstep in this process and ``slung fly`` (a 60 s hover, options ``extra``) in its own,
    so that a signal reaches the loop as it would from a terminal: (emulator, process, output folder, summary). On
    leaving, a process still running is killed and the emulator stopped; its summary then fills the dict."""
    port = free_udp_port()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004).start()
    out = tmp_path / "fly"
    cmd = [sys.executable, "-m", "offboard.cli", "fly", "--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover"]
    cmd += ["--duration", "60", "--lockstep", *extra, "--no-figures", "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    summary: dict[str, Any] = {}
    try:
        yield emu, proc, out, summary
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        summary.update(emu.stop())


@pytest.mark.parametrize("action", ["hold", "land"])
def test_sigterm_in_flight_ends_in_hold_or_land(tmp_path: Path, action: str) -> None:
    with _fly_hover_in_a_process(tmp_path, "--on-signal", action) as (emu, proc, out, summary):
        t_end = time.monotonic() + 40.0
        while emu.ap.mode.name != "OFFBOARD" and time.monotonic() < t_end and proc.poll() is None:
            time.sleep(0.05)
        if emu.ap.mode.name != "OFFBOARD":
            proc.kill()
            pytest.fail(f"never reached OFFBOARD (mode {emu.ap.mode.name}): {proc.communicate()[1][-1500:]}")
        time.sleep(1.0)  # well into the controlled flight
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=40.0)
    assert rc == 1
    ev = json.loads((out / "events.json").read_text())
    assert any(e["kind"] == "signal" for e in ev["loop"])
    if action == "hold":
        assert summary["mode"] == "AUTO.LOITER" and summary["armed"]
    else:
        assert summary["mode"] == "AUTO.LAND" and not summary["armed"] and summary["on_ground"]
    m = json.loads((out / "metrics.json").read_text())
    assert m["flight"]["ended_by"] == "signal"


def test_sigint_during_the_take_off_holds_at_once(tmp_path: Path) -> None:
    """Ctrl-C while the autopilot climbs (AUTO.TAKEOFF, before any offboard control) ends the run at once: Hold
    where the vehicle is, never OFFBOARD, not after the climb to the reference's start height has finished (what
    the loop used to do: its management phases did not look at the signal)."""
    with _fly_hover_in_a_process(tmp_path) as (emu, proc, out, summary):
        t_end = time.monotonic() + 40.0
        while emu.ap.mode.name != "AUTO.TAKEOFF" and time.monotonic() < t_end and proc.poll() is None:
            time.sleep(0.005)
        assert emu.ap.mode.name == "AUTO.TAKEOFF", proc.communicate()[1][-1500:]
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=30.0)
        height_at_exit = emu.ap.x[2]
    assert rc == 1
    modes = [name for _, name in summary["modes"]]
    assert "OFFBOARD" not in modes and modes[-1] == "AUTO.LOITER" and summary["armed"]
    assert height_at_exit < 0.5  # the take-off to the hover's start height (1 m) was cut short
    ev = json.loads((out / "events.json").read_text())
    assert [e["reason"] for e in ev["loop"] if e["kind"] == "signal"] == ["signal 2 before the flight"]


@pytest.mark.parametrize(("flavor", "end", "mode"), [("ardupilot", "hold", "BRAKE"), ("px4", "land", "AUTO.LAND")])
def test_watchdog_hand_over_is_brake_on_ardupilot_and_honours_end_land(
    tmp_path: Path, flavor: str, end: str, mode: str
) -> None:
    """A watchdog (a NaN estimate trips the divergence watchdog 1 s in) hands ArduPilot to BRAKE, which holds
    position and height by itself (LOITER follows the RC throttle stick: with it low the vehicle came down on its
    load), and under ``--end land`` the hand-over lands instead of holding."""
    m, folder, emu = run_demo(
        demo_args(tmp_path, "--scenario", "hover", "--duration", "3", "--flavor", flavor, "--end", end),
        inject=(("estimate", 1.0, 1.02),),
        quiet=True,
    )
    assert m["flight"]["ended_by"] == "estimator_divergence"
    assert emu["mode"] == mode, emu["mode"]
    exits = [e["reason"] for e in json.loads((folder / "events.json").read_text())["loop"] if e["kind"] == "exit"]
    assert exits and exits[0].startswith("hold:" if end == "hold" else "land:"), exits
