"""Delay tolerance (issue 10, item 2) through an independent hostile UDP proxy (``tests/hostile_proxy.py``, its own
process, real sockets on 127.0.0.1) between the bundled emulator and ``slung fly``, in lockstep: the proxy counts
its delays in vehicle periods, so the results do not depend on the machine's load. The loop measures the
telemetry age and the setpoint's way (TIMESYNC), sizes its filter for them and acts on the state predicted to when
its setpoint acts (``offboard/flight/latency.py``), and scales the torque-level law's poles so that its loops keep
their delay margin (``offboard/control/delay_margin.py``); the latency watchdog ends a flight whose link is slower
than its limit. The flights fly the default demo path: PX4 flavour, ``--law auto`` (the torque-level law for the
paper's vehicle behind PX4's attitude loop, sign switching), attitude output."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, free_udp_port

PROXY = Path(__file__).with_name("hostile_proxy.py")
STEP = 0.004  # the emulator's lockstep period (250 Hz)
#: the staleness and latency watchdogs' limits for the long flights below (defaults 0.1 s each), which are not what
#: these flights test. In lockstep the loop ticks on its own clock when a step marker is more than 20 ms (wall) late
#: (offboard.flight.loop, lockstep_wait_s), so on a loaded machine a burst of such ticks reads as old telemetry: at
#: load 15-19 the paper flights had 13-44 of them, and one clean flight ended on telemetry_stale (0.101 s, position
#: telemetry already up to 50 ms old behind 25 ms), another on the latency watchdog (telemetry 103 ms old, median,
#: at 38.9 s). The raised limits are those of the other tests whose watchdog under test is another one.
WATCHDOG_LIMITS = ("--stale-limit", "0.25", "--latency-limit", "0.3")


def fly_through_proxy(
    tmp_path: Path, name: str, delay: float, jitter: float, scenario: str, duration: float, *extra: str
) -> dict[str, Any]:
    client, listen = free_udp_port(), free_udp_port()
    proxy = subprocess.Popen(
        [
            *(sys.executable, str(PROXY), "--listen", str(listen), "--client", str(client)),
            *("--delay", repr(delay), "--jitter", repr(jitter), "--lockstep-step", repr(STEP), "--seed", "3"),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proxy.stdout is not None and proxy.stdout.readline().strip() == "ready"
    emu = EmulatorThread(
        "px4",
        listen,
        lockstep=True,
        period=STEP,
        sensors="px4-typical",
        disturbance="paper" if scenario == "paper" else "none",
    ).start()
    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(
        [
            *("--connect", f"udpin:127.0.0.1:{client}", "--scenario", scenario, "--duration", repr(duration)),
            *("--lockstep", "--no-figures", "--out", str(tmp_path / name), *extra),
        ]
    )
    try:
        m, _ = fly(args, lockstep=True, truth_probe=emu.truth, quiet=True, on_reference_start=emu.set_reference_start)
    finally:
        emu.stop()
        proxy.terminate()
        proxy.communicate(timeout=10)
    return m


@pytest.mark.slow
def test_through_25_ms_and_5_ms_jitter_the_delays_are_measured_and_the_filter_sized(tmp_path: Path) -> None:
    """25 ms each way plus 0..5 ms of jitter on the vehicle's packets (hover, the torque-level law): the loop
    measures both delays, sizes the filter's fusion horizon for them (so the slow link's measurements are fused),
    acts 24 ms ahead and scales the law's poles for the loop delay; the flight completes (before the gain schedule
    it completed or ended on a watchdog depending on the filter of the day)."""
    m = fly_through_proxy(tmp_path, "slow", 0.025, 0.005, "hover", 5.0, "--law", "torque")
    fl = m["flight"]
    assert fl["ended_by"] == "completed" and fl["end_state"] == "hold", fl
    assert 0.3 < m["config"]["gain_scale"] < 0.6
    lat = fl["latency"]
    assert lat["timesync_answers"] >= 3
    # 6 vehicle periods (24 ms) each way, up to one more on the vehicle's packets
    assert 20.0 <= lat["setpoint_way_ms"] <= 30.0 and 20.0 <= lat["telemetry_age_ms"] <= 36.0, lat
    assert 20.0 <= lat["horizon_ms"] <= 30.0 and lat["max_horizon_ms"] > 50.0
    assert m["config"]["delay_s"] > 0.06  # the filter was built to fuse a round trip behind
    # so the slow link's measurements are fused (with the base 12 ms horizon about one in eight was dropped late)
    st = m["estimation"]["stats"]
    assert st["late_dropped"] <= 0.01 * st["accepted"], st


@pytest.mark.slow
def test_the_paper_scenario_through_25_ms_and_5_ms_jitter_keeps_the_swing_within_1_5x_of_the_clean_run(
    tmp_path: Path,
) -> None:
    """Issue 10's aim: the paper scenario (50 s, disturbances from 25 s) through the proxy twice, delay 0 (the
    clean run) and 25 ms each way + 0..5 ms jitter on the vehicle's packets; both complete and the true swing RMS
    of the slow link stays within 1.5x of the clean run's. The slow link's gains were scaled for its measured loop
    delay (measured on this branch, six runs: scale 0.432-0.438, swing RMS 0.0482-0.0492 rad against 0.0382-0.0393,
    1.23-1.27x; with the paper's gains it ended on the swing watchdog after 3.6 s); the clean run kept the paper's."""
    clean = fly_through_proxy(tmp_path, "clean", 0.0, 0.0, "paper", 50.0, *WATCHDOG_LIMITS)
    slow = fly_through_proxy(tmp_path, "slow", 0.025, 0.005, "paper", 50.0, *WATCHDOG_LIMITS)
    for m in (clean, slow):
        assert m["flight"]["ended_by"] == "completed" and m["completed"], m["flight"]
        assert m["config"]["law"] == "torque" and m["duration_s"] > 49.9
    assert clean["config"]["gain_scale"] == 1.0
    assert 0.3 < slow["config"]["gain_scale"] < 0.6, slow["config"]["gain_scale"]
    ratio = slow["rms"]["alpha"] / clean["rms"]["alpha"]
    assert ratio <= 1.5, (slow["rms"], clean["rms"])
    ev = json.loads((tmp_path / "slow" / "events.json").read_text())["loop"]
    assert any("poles scaled by" in e["reason"] for e in ev if e["kind"] == "phase")


@pytest.mark.slow
def test_a_hover_through_50_ms_completes(tmp_path: Path) -> None:
    """50 ms each way (hover, default path): completed with the swing held small (measured on this branch, five
    runs: scale 0.27, swing RMS 0.017-0.033 rad, largest 0.034-0.066 rad over the 5 s; with the paper's gains the
    swing watchdog ended it after about 3 s)."""
    m = fly_through_proxy(tmp_path, "hover50", 0.05, 0.0, "hover", 5.0, *WATCHDOG_LIMITS)
    fl = m["flight"]
    assert fl["ended_by"] == "completed" and m["completed"], fl
    assert m["config"]["law"] == "torque" and m["duration_s"] > 4.9
    assert 0.15 < m["config"]["gain_scale"] < 0.4, m["config"]["gain_scale"]
    assert 40.0 <= fl["latency"]["setpoint_way_ms"] <= 56.0, fl["latency"]
    assert m["max"]["alpha"] < 0.15 and m["rms"]["alpha"] < 0.06, (m["max"], m["rms"])
    # slung replay rebuilds the scheduled law from config.gain_scale: every setpoint recomputed bit for bit
    from offboard.cli import main

    tlog = tmp_path / "hover50" / "flight.tlog"
    assert main(["replay", str(tlog), "--out", str(tmp_path / "r"), "--no-figures"]) == 0
    agree = json.loads((tmp_path / "r" / "metrics.json").read_text())["live_agreement"]
    assert agree["ticks"] > 1000 and agree["setpoint_identical"] == agree["ticks"], agree


@pytest.mark.slow
def test_the_latency_watchdog_ends_a_link_slower_than_its_limit(tmp_path: Path) -> None:
    m = fly_through_proxy(tmp_path, "limit", 0.05, 0.0, "hover", 5.0, "--latency-limit", "0.03")
    assert m["flight"]["ended_by"] == "latency" and m["flight"]["exit_code"] == 1
    ev = json.loads((tmp_path / "limit" / "events.json").read_text())["loop"]
    why = next(e["reason"] for e in ev if e["kind"] == "latency")
    assert "above the limit 30 ms" in why, why
    assert any(e["kind"] == "exit_done" and e["reason"].startswith("hold") for e in ev)


def test_link_latency_figures_and_limits() -> None:
    """The measurement on its own: medians over the window, the horizon by pacing mode, the watchdog."""
    from offboard.flight.latency import LinkLatency

    class Mav:
        def timesync_encode(self, tc1: int, ts1: int) -> tuple[int, int]:
            return tc1, ts1

    lat = LinkLatency(lockstep=True, limit_s=0.05, max_horizon_s=0.1)
    for k in range(9):
        t = 1.0 + 0.5 * k
        _, ts1 = lat.request(Mav(), t)
        lat.on_timesync(round((t + 0.024) * 1e9), ts1, t + 0.048)  # 24 ms up, 24 ms back (vehicle time)
        lat.on_telemetry_age(0.024 + (0.004 if k % 3 == 0 else 0.0))
    assert abs(lat.way_s - 0.024) < 1e-6 and abs(lat.age_s - 0.024) < 1e-6
    assert abs(lat.horizon() - 0.024) < 1e-6 and lat.check(5.0) is None
    lat.on_timesync(123, 456, 2.0)  # an answer to nothing we asked: ignored
    assert lat.answers == 9
    rt = LinkLatency(lockstep=False, limit_s=0.05, max_horizon_s=0.04)
    for k in range(5):
        _, ts1 = rt.request(Mav(), float(k))
        rt.on_timesync(1, ts1, k + 0.06)  # 60 ms round trip: 30 ms each way assumed
        rt.on_telemetry_age(0.03)
    assert abs(rt.way_s - 0.03) < 1e-9 and rt.horizon() == 0.04  # age + way = 60 ms, capped at the filter's room
    for _ in range(9):
        rt.on_telemetry_age(0.07)
    # above the limit: the watchdog fires once it has stayed there for hold_s (1 s), not at the first tick
    assert rt.check(10.0) is None and rt.check(10.9) is None
    why = rt.check(11.0)
    assert why is not None and "70 ms old" in why and "50 ms" in why
    for _ in range(5):  # back below: the timer starts again
        rt.on_telemetry_age(0.03)
    assert rt.check(11.1) is None
    for _ in range(9):
        rt.on_telemetry_age(0.07)
    assert rt.check(11.2) is None and rt.check(12.1) is None and rt.check(12.2) is not None
