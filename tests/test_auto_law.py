"""``--law auto`` against the autopilot's own attitude loop: the attitude-level law is chosen on PX4's default loop
(MC_ROLL_P 4, the only one known before the connection) and kept only if the loop the autopilot reports, read
before the take-off, leaves it gains robust to that loop off by 2x (docs/model.md §12.5); otherwise the flight flies
the torque-level law through the same attitude output, says so, and records it so that ``slung replay`` rebuilds
the law that flew. Flown against the bundled emulator (PX4 flavour, lockstep) with its attitude gains set as a
ground station would (``--param``), on PX4 SITL's SIH quadrotor carrying a 0.3 kg load on 0.6 m (swing 4.6 rad/s),
whose attitude law has robust gains behind MC_ROLL_P 4 but none behind 2."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from estimators.model.vehicle import load_vehicle
from offboard.cli import main
from offboard.control import smc_attitude
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, free_udp_port

SLOW_LOOP = (("MC_ROLL_P", 2.0), ("MC_PITCH_P", 2.0))


def _vehicle_file(folder: Path) -> Path:
    """px4-sih with a 0.3 kg load on a 0.6 m cable (hover throttle 0.64: 1.3 kg on four 5 N motors)."""
    text = (Path(__file__).parent.parent / "estimators" / "model" / "vehicles" / "px4-sih.toml").read_text()
    for old, new in (
        ('name = "px4-sih"', 'name = "px4-sih-load"'),
        ("mass_kg = 0.0", "mass_kg = 0.3"),
        ("cable_length_m = 1.0", "cable_length_m = 0.6"),
        ("hover_throttle = 0.5 ", "hover_throttle = 0.64 "),
    ):
        assert old in text, old
        text = text.replace(old, new, 1)
    path = folder / "px4-sih-load.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _fly(tmp_path: Path, params: tuple[tuple[str, float], ...], *extra: str) -> tuple[dict, Path]:
    port = free_udp_port()
    vehicle = str(_vehicle_file(tmp_path))
    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(
        [
            "--connect",
            f"udpin:127.0.0.1:{port}",
            "--vehicle",
            vehicle,
            "--scenario",
            "hover",
            "--duration",
            "3",
            "--no-figures",
            "--out",
            str(tmp_path / "f"),
            *extra,
        ]
    )
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004, vehicle=vehicle, params=params).start()
    try:
        m, folder = fly(args, lockstep=True, truth_probe=emu.truth, quiet=True)
    finally:
        emu.stop()
    return m, folder


def _events(folder: Path) -> list[str]:
    return [e["reason"] for e in json.loads((folder / "events.json").read_text())["loop"] if e["kind"] == "phase"]


def test_the_premise_robust_gains_behind_the_default_loop_and_none_behind_the_slow_one(tmp_path: Path) -> None:
    v = load_vehicle(_vehicle_file(tmp_path))
    d = smc_attitude.InnerLoop()
    assert smc_attitude.robust_gains_exist(v, d)
    assert not smc_attitude.robust_gains_exist(v, smc_attitude.InnerLoop(2.0, d.yaw_bandwidth, d.rate_bandwidth))


def test_auto_keeps_the_attitude_law_behind_the_default_loop(tmp_path: Path) -> None:
    m, folder = _fly(tmp_path, ())
    assert m["flight"]["ended_by"] == "completed"
    assert json.loads((folder / "metrics.json").read_text())["config"]["law"] == "attitude"
    assert not any("--law auto" in e for e in _events(folder))


def test_auto_flies_the_torque_law_behind_a_slow_loop_and_replay_rebuilds_it(tmp_path: Path) -> None:
    m, folder = _fly(tmp_path, SLOW_LOOP)
    assert m["flight"]["ended_by"] == "completed"
    cfg = json.loads((folder / "metrics.json").read_text())["config"]
    assert cfg["law"] == "torque"
    assert cfg["layer_errors"] and cfg["actuation_lag_s"] is not None  # the torque law's flight parameters
    said = [e for e in _events(folder) if e.startswith("--law auto: the torque-level law")]
    assert len(said) == 1 and "(2 1/s)" in said[0], said
    ticks = m["loop"]["ticks"]
    assert ticks > 500
    assert m["rms"]["alpha"] < 0.05 and m["max"]["alpha"] < 0.1, (m["rms"], m["max"])  # it flew, and held the load
    # the replay rebuilds the law that flew (and the vehicle the run recorded), bit for bit
    code = main(["replay", str(folder / "flight.tlog"), "--out", str(tmp_path / "r")])
    agree = json.loads((tmp_path / "r" / "metrics.json").read_text())["live_agreement"]
    assert code == 0
    assert agree["setpoint_identical"] == agree["estimate_identical"] == ticks, agree


def test_an_explicit_attitude_law_is_kept_behind_a_slow_loop_with_a_warning(tmp_path: Path) -> None:
    m, folder = _fly(tmp_path, SLOW_LOOP, "--law", "attitude")
    assert json.loads((folder / "metrics.json").read_text())["config"]["law"] == "attitude"
    assert any("no gains stay stable" in w for w in m["flight"]["warnings"]), m["flight"]["warnings"]


@pytest.mark.parametrize("text", ["MC_ROLL_P", "MC_ROLL_P=x", "=1", "MC_ROLL_P=nan"])
def test_a_malformed_emulator_param_is_one_line_and_exit_2(text: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["emulate", "--param", text, "--duration", "0.1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--param" in err[0] and "Traceback" not in err[0], err


@pytest.mark.parametrize(("text", "why"), [("NO_SUCH_P=1", "no such parameter"), ("MC_ROLL_P=99", "out of range")])
def test_an_emulator_param_it_cannot_set_is_refused(text: str, why: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["emulate", "--param", text, "--duration", "0.1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and why in err[0], err
