"""The load identified in flight (issue 34 Build 2, ``slung fly --identify-load``;
``offboard.flight.load_identification`` and ``offboard.flight.loop_identify``): the vehicle file's load is the
prior, an identification hover of at most 10 s with a gentle excitation runs before control, and the identified mass
and cable length fly when confident.

The flight: the emulator's ArduPilot flavour (lockstep, px4-typical sensors) carrying ArduPilot SITL's 1.2 kg on
1 m, flown with a vehicle file that says 0.6 kg on 1.5 m. Measured 2026-12-07: 1.142 +- 0.081 kg on 1.030 +- 0.048 m
after 10 s of hover (1.061-1.144 kg and 0.996-1.030 m over eight runs on a loaded machine), used; the flight
completes on the identified vehicle."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pytest

from estimators.identification.load_id import LoadIdentification
from estimators.model.measurements import Imu
from estimators.model.vehicle import load_vehicle
from offboard.cli import main
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.flight.load_identification import InFlightLoadId, decide
from offboard.harness.demo_cli import EmulatorThread, free_udp_port

BUNDLED = Path(__file__).resolve().parents[1] / "estimators" / "model" / "vehicles" / "ardupilot-sitl-quad.toml"
FILE = load_vehicle(str(BUNDLED)).with_changes(mass_load=0.6, cable_length=1.5)


def _ident(attached: bool, mass: float, cable: float, s_mass: float, s_cable: float) -> LoadIdentification:
    return LoadIdentification(
        attached=attached,
        mass_kg=mass if attached else None,
        cable_m=cable if attached else None,
        uncertainty={"mass_kg": s_mass if attached else None, "cable_m": s_cable if attached else None},
        mass_ratio=mass / FILE.mass_vehicle,
        mass_ratio_sigma=s_mass / FILE.mass_vehicle,
        damping_ratio=0.0,
        coupled_mode_rad_s=3.6,
        log_likelihood_ratio=100.0 if attached else 1.0,
        bic_margin=90.0 if attached else -5.0,
        explained_fraction=0.5,
        swing_amplitude_rad=0.01,
        samples=250,
        effective_samples=100.0,
        windows=1,
        grid_rate_hz=25.0,
        used_velocity=True,
        reason="the load model wins" if attached else "the bare vehicle's model explains it as well",
    )


def test_the_identified_load_flies_only_when_confident_else_the_priors_and_why() -> None:
    flown, block = decide(_ident(True, 1.15, 1.03, 0.08, 0.05), FILE)
    assert flown is not None and flown.mass_load == 1.15 and flown.cable_length == 1.03
    assert flown.mass_vehicle == FILE.mass_vehicle  # the vehicle's own values are the file's
    assert block["used"] and block["prior"] == {"mass_kg": 0.6, "cable_m": 1.5}
    assert block["identified"] == {"mass_kg": 1.15, "cable_m": 1.03}
    assert block["uncertainty"] == {"mass_kg": 0.08, "cable_m": 0.05}
    # too uncertain (1 sigma 20 % of the length): the priors, said so
    flown, block = decide(_ident(True, 1.15, 1.0, 0.08, 0.2), FILE)
    assert flown is None and not block["used"] and "not confident" in block["why"]
    assert block["identified"] == {"mass_kg": 1.15, "cable_m": 1.0}  # reported all the same
    # no load seen: the file's load stays (a load the file declares is not dropped on a quiet hover)
    flown, block = decide(_ident(False, 0.0, 1.0, 0.0, 0.0), FILE)
    assert flown is None and block["attached"] is False and "no load identified" in block["why"]
    # nothing to identify from
    flown, block = decide(None, FILE, "too few records")
    assert flown is None and "too few records" in block["why"]


def test_too_few_records_are_said_and_the_priors_fly() -> None:
    """The identification's own process (``python -m offboard.flight.load_identification``) answers, and nothing to
    identify from is said, not raised."""
    import time

    lid = InFlightLoadId(FILE, 5.0)
    lid.start()
    lid.push(Imu(0.0, 0.0, 0.0, 9.8, 0.0, 0.0, 0.0))
    assert not lid.ready() and lid.span_s() == 0.0
    lid.run_in_background()
    lid.push(Imu(1.0, 0.0, 0.0, 9.8, 0.0, 0.0, 0.0))  # no longer buffering
    assert len(lid.imu) == 1
    t_end = time.monotonic() + 60.0
    while not lid.done() and time.monotonic() < t_end:
        time.sleep(0.05)
    assert lid.result is None and lid.error is not None and "too few records" in lid.error, lid.error
    flown, block = decide(lid.result, FILE, lid.error)
    assert flown is None and "too few records" in block["why"]


def test_the_identification_hover_is_at_most_ten_seconds() -> None:
    with pytest.raises(ValueError, match=r"0\.\.10 s"):
        InFlightLoadId(FILE, 12.0)
    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(["--connect", "x", "--scenario", "hover", "--out", "o", "--identify-load"])
    assert args.identify_load == 10.0


def test_a_wrong_vehicle_file_is_corrected_in_flight(tmp_path: Path) -> None:
    """The file says 0.6 kg on 1.5 m; the plant carries 1.2 kg on 1 m."""
    text = BUNDLED.read_text(encoding="utf-8")
    text = re.sub(r"(\[load\]\nmass_kg = )[0-9.]+", r"\g<1>0.6", text)
    text = text.replace("cable_length_m = 1.0", "cable_length_m = 1.5")
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(text, encoding="utf-8")
    assert load_vehicle(str(wrong)).mass_load == 0.6 and load_vehicle(str(wrong)).cable_length == 1.5
    traj = tmp_path / "hover.toml"
    traj.write_text('kind = "hover"\nx = 0.0\ny = 0.0\nz = 2.5\n', encoding="utf-8")
    port = free_udp_port()
    emu = EmulatorThread(
        "ardupilot", port, lockstep=True, period=0.004, vehicle="ardupilot-sitl-quad", sensors="px4-typical"
    ).start()
    p = argparse.ArgumentParser()
    fly_configure(p)
    link = ["--connect", f"udpin:127.0.0.1:{port}", "--vehicle", str(wrong), "--trajectory", str(traj)]
    args = p.parse_args([*link, "--duration", "3", "--identify-load", "--no-figures", "--out", str(tmp_path / "f")])
    try:
        m, _ = fly(args, lockstep=True, truth_probe=emu.truth, quiet=True, on_reference_start=emu.set_reference_start)
    finally:
        emu.stop()
    assert m["flight"]["ended_by"] == "completed"
    block = m["config"]["load_identification"]
    assert block["used"] and block["attached"] and block["hover_s"] <= 10.5
    assert block["prior"] == {"mass_kg": 0.6, "cable_m": 1.5}
    got, sigma = block["identified"], block["uncertainty"]
    # the truth within 3 of the stated sigmas (the identification's calibration), the sigmas within the 10 % that
    # makes it flown: the emulator's flights are not identical from run to run on a loaded machine (1.061-1.144 kg
    # measured, sigma 0.08 kg). Issue 34's 10 % / 5 % are judged on ArduPilot SITL by
    # bench/ardupilot_load_identification.py (1.225 kg, 0.999 m)
    print(f"identified {got} +- {sigma}")
    assert abs(got["mass_kg"] - 1.2) < 3.0 * sigma["mass_kg"] and 0.0 < sigma["mass_kg"] < 0.12, (got, sigma)
    assert abs(got["cable_m"] - 1.0) < 3.0 * sigma["cable_m"] and 0.0 < sigma["cable_m"] < 0.1, (got, sigma)
    assert block["flown"] == block["identified"]  # the loop's vehicle is the identified one
    # the replay of this run rebuilds the law and the filter on the identified load the flight flew, not on the
    # vehicle file's (it would otherwise compare two different pendulums with the live ticks): bit for bit
    code = main(["replay", str(tmp_path / "f" / "flight.tlog"), "--out", str(tmp_path / "r")])
    r = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert code == 0
    ticks = m["loop"]["ticks"]
    agree = r["live_agreement"]
    assert agree["setpoint_identical"] == agree["estimate_identical"] == ticks > 100, agree
    load = r["load"]  # metrics.json's load: what flew, the in-flight identification's uncertainty and prior
    assert load["attached"] and load["source"].startswith("identified in flight"), load
    assert load["mass_kg"] == pytest.approx(got["mass_kg"]) and load["cable_m"] == pytest.approx(got["cable_m"])
    assert load["uncertainty"] == sigma and load["prior"] == {"mass_kg": 0.6, "cable_m": 1.5}
