"""``slung demo`` end to end over real UDP on 127.0.0.1, lockstep, both flavours and both output modes, flying the
whole paper scenario (50 s: climb, heading change, figure-eight, the random disturbances from 25 s) with the
demo's defaults: px4-typical sensors in the emulator (noise, bias, latency of ``slung sim``'s models), the
paper's disturbances with their clock started at the reference start, seed 0, the Kalman filter in the loop.

Compared with ``slung sim --scenario paper --sensors px4-fast --estimator kf --control-rate 250
--attitude-model rigid --actuators mixer --seed 0``: the same sensor models at the rates the loop requests
(ATTITUDE and HIGHRES_IMU at 250 Hz, LOCAL_POSITION_NED at 100 Hz, LOADANG at 250 Hz = px4-fast's schedule), the
same filter, controller, rate, plant model, actuators (the emulator's X mixer with motor limits and lag),
disturbance signal, seed and law (the torque-level law with its per-loop boundary layers, docs/model.md C-12, and
its model of the motors' lag, C-13).
Criterion per signal (e_Fx, e_Fy, e_z, e_psi, alpha RMS): demo <= 1.3 x sim, no additive floor (ArduPilot: see
``_ratio``). Measured figures: docs/usage-fly-demo.md.

Why the mixer: on the paper's vehicle the yaw torque of the 0 -> 0.5 rad heading manoeuvre needs the whole hover
margin of every motor while the sign-switching roll / pitch torques switched by +-0.3-0.5 N m, and a mixer that
serves roll and pitch first (PX4's allocator without airmode, the emulator's) leaves yaw about half its command.
With ``--actuators ideal`` (the paper's assumption) ``slung sim`` gave e_psi 0.0007 rad RMS, with the mixer
0.05, the demo 0.03-0.04. With the layers the roll / pitch torques no longer switch and the mixer leaves yaw its
command: sim 0.0009, demo (PX4) about 0.001. The other signals hardly change (docs/usage-fly-demo.md).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.boundary_layers import FLIGHT_LAYER_ERRORS
from offboard.control.reference_stop import StoppingReference
from offboard.control.scenarios import PAPER_DISTURBANCE_START_S, make_scenario
from offboard.harness import sim as sim_mod
from offboard.harness.demo_cli import configure, run_demo
from offboard.logs.timeseries_file import read_table
from offboard.report import metrics as metrics_mod

DURATION = 50.0
SEED = 0
SIGNALS = ("e_Fx", "e_Fy", "e_z", "e_psi", "alpha")
RATIO = 1.3


def _ratio(flavor: str, signal: str) -> float:
    """demo / sim bound per signal: 1.3, and 1.7 for every ArduPilot signal. The emulator's ArduPilot flavour now
    shapes the attitude request as ArduPilot does (ATC_INPUT_TC, square-root controller) and takes the rates as
    feed-forward, which ``slung sim``'s mixer does not model: measured 1.05-1.48x over runs (e_Fx 0.024-0.026 m,
    e_psi 0.069-0.083 rad, all but e_psi within the paper's Table 2); 1.52-1.57x for e_Fx and e_Fy since the law
    leads over the motors' lag (docs/model.md C-13; e_Fx 0.035 m, three runs of 4 Dec 2026). The 1.3x held before
    only because the emulator's inner loops were the ones the mapping inverts. An ArduPilot inner-loop model in
    ``slung sim`` would restore the like-with-like comparison (open)."""
    return 1.7 if flavor == "ardupilot" else RATIO


def demo_args(tmp_path, *extra: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    configure(p)
    return p.parse_args(["--no-figures", "--out", str(tmp_path / "demo"), *extra])


def _sim(actuators: str) -> tuple[dict, sim_mod.SimLog]:
    """slung sim with the demo's law, sensors (px4-fast = px4-typical at the loop's request rates), filter, rate,
    plant model, actuators (the emulator's mixer), disturbances and seed. (With the paper's sign(.) the ``px4``
    run diverged, e_Fx 35 m, and bounded nothing.)"""
    v = Vehicle()
    sc = make_scenario("paper", duration=DURATION, seed=SEED)
    # the law the demo flies by default: smooth switching with each loop's own boundary layer (docs/model.md C-12)
    params = smc.ControllerParams.for_vehicle(
        v, switching="smooth", layer_errors=FLIGHT_LAYER_ERRORS, actuation_lag_s=v.motor_time_constant
    )
    cfg = sim_mod.SimConfig(
        control_rate=250.0, attitude_model="rigid", sensors="px4-fast", estimator="kf", seed=SEED, actuators=actuators
    )
    log = sim_mod.run(sc, v, params, cfg)
    return metrics_mod.compute(log), log


@pytest.fixture(scope="module")
def sim_runs() -> dict[str, tuple[dict, sim_mod.SimLog]]:
    """slung sim per actuator model, run once: ``mixer`` (roll / pitch priority) beside the attitude outputs, and
    ``px4`` (PX4's allocator and its desaturation) beside ``--output actuator``, which meets that allocator on the
    emulator's PX4 flavour: like is compared with like."""
    return {"mixer": _sim("mixer"), "px4": _sim("px4")}


def wire_setpoints(tlog_path) -> list:
    """Every setpoint message we sent, parsed back from the bytes in flight.tlog."""
    log = mavutil.mavlink_connection(str(tlog_path))
    out = []
    while (m := log.recv_match(type=["SET_ATTITUDE_TARGET", "SET_ACTUATOR_CONTROL_TARGET"])) is not None:
        out.append(m)
    return out


@pytest.mark.parametrize(("flavor", "output"), [("px4", "attitude"), ("px4", "actuator"), ("ardupilot", "attitude")])
def test_demo_flies_the_paper_scenario_like_sim(tmp_path, sim_runs, flavor: str, output: str) -> None:
    sim_m, sim_log = sim_runs["px4" if output == "actuator" else "mixer"]
    args = demo_args(tmp_path, "--flavor", flavor, "--output", output, "--law", "torque")  # sim runs the torque law
    assert (args.sensors, args.seed, args.disturbance, args.rate) == ("px4-typical", SEED, "paper", 250.0)
    m, folder, emu = run_demo(args, quiet=True)
    assert m["flight"]["ended_by"] == "completed" and m["completed"] and m["all_finite"]
    assert m["flight"]["truth_source"] == "emulator truth"
    # the figure-eight still moves at its end: the loop brought it to rest before the hand-over (the reference's
    # smooth stop, offboard.control.reference_stop), so the autopilot's hold was given a vehicle at rest
    stop_s = StoppingReference(make_scenario("paper", duration=DURATION).reference, DURATION).stop_s
    assert stop_s > 2.0 and m["config"]["stop_after_s"] == pytest.approx(DURATION)
    assert m["settle"]["flown_s"] >= stop_s - 0.01
    live = read_table(folder / "timeseries_live.slts")
    assert live.complete
    last = dict(zip(live.columns, live.data[-1].tolist(), strict=True))
    assert all(last[f"ref_f{a}{k}"] == 0.0 for a in "xy" for k in range(1, 7)), last
    assert m["duration_s"] == pytest.approx(DURATION, abs=0.05)
    ratios = {k: m["rms"][k] / sim_m["rms"][k] for k in SIGNALS}
    for k in SIGNALS:
        if flavor == "ardupilot" and k == "e_psi":
            # ArduPilot shapes the yaw request (ATC_INPUT_TC) and slung sim has no such loop, so there is no
            # like-for-like simulation of the heading: since the layers stopped the roll / pitch chatter that
            # starved the mixer's yaw (sim e_psi 0.05 -> 0.0009 rad) the bound is the paper's Table 2 (measured
            # 0.0008 rad with the motor lag designed in, 0.017 without, 0.039 with sign switching; 4 Dec 2026)
            assert m["rms"][k] <= metrics_mod.PAPER_TABLE2[k][0], (k, m["rms"][k], ratios)
            continue
        assert m["rms"][k] <= _ratio(flavor, k) * sim_m["rms"][k], (k, m["rms"][k], sim_m["rms"][k], ratios)
    # the emulator really was the paper scenario: noisy sensors, disturbance clock at the reference start
    assert emu["sensors"] == "px4-typical"
    dist = emu["disturbance"]
    assert dist["origin_s"] == pytest.approx(m["loop"]["reference_start_s"], abs=1e-9)
    ts = read_table(folder / "timeseries.slts")
    t = ts["t"]
    # the disturbance the plant received, logged, is slung sim's at the same reference time
    sim_t = sim_log.column("t")
    idx = np.searchsorted(sim_t, t - 1e-9)
    ok = idx < len(sim_t)
    assert np.all(np.abs(sim_t[idx[ok]] - t[ok]) < 1e-9)
    for c in ("dist_fx", "dist_fy", "dist_fz", "dist_tpsi"):
        np.testing.assert_allclose(ts[c][ok], sim_log.column(c)[idx[ok]], atol=1e-12, err_msg=c)
        assert np.all(ts[c][t < PAPER_DISTURBANCE_START_S - 1e-9] == 0.0) and np.max(np.abs(ts[c])) > 0.0
    # columns agree with each other: the heading error is the logged heading minus its reference, the filter's
    # heading error is small, the logged heading rate is the plant's (bounded), the tension near the load weight
    np.testing.assert_allclose(
        ts["e_psi"], np.remainder(ts["psi"] - ts["psi_ref"] + np.pi, 2 * np.pi) - np.pi, atol=1e-7
    )
    assert np.max(np.abs(ts["est_psi"])) < 0.05 and np.max(np.abs(ts["psi_rate"])) < 1.5
    print(f"{flavor}/{output}: demo / sim RMS ratios", {k: round(v, 3) for k, v in ratios.items()})
    # the vehicle was left holding (PX4 AUTO.LOITER, ArduPilot LOITER), armed and airborne
    assert emu["mode"] == ("AUTO.LOITER" if flavor == "px4" else "BRAKE") and emu["armed"]
    assert emu["counters"]["setpoints_rejected"] == 0
    # the filter was built as recorded
    assert m["config"]["load_sensor"] is True and m["config"]["delay_s"] == pytest.approx(0.012)
    assert m["config"]["load_telemetry_seen"] is True
    # the loop block and the tlog: every setpoint on the wire is finite and of the requested kind
    assert m["loop"]["ticks"] >= DURATION * 250 * 0.99 and m["loop"]["compute_us_p50"] > 0
    sps = wire_setpoints(folder / "flight.tlog")
    kinds = {s.get_type() for s in sps}
    assert kinds == {"SET_ATTITUDE_TARGET" if output == "attitude" else "SET_ACTUATOR_CONTROL_TARGET"}
    assert len(sps) >= m["loop"]["ticks"]
    for s in sps:
        vals = [*list(s.q), s.thrust] if output == "attitude" else list(s.controls)
        assert all(math.isfinite(v) for v in vals)
    raw = (folder / "flight.tlog").read_bytes()
    assert struct.unpack(">Q", raw[:8])[0] > 1_600_000_000 * 10**6  # QGC header: us since the epoch


def test_demo_seed_9_flies_with_the_motor_lag_designed_in(tmp_path) -> None:
    """Seed 9 of the paper's disturbances (most of its power near 1.9 Hz) swung the load up to the swing watchdog
    (0.8 rad, at 36-47 s) behind the emulator's PX4 attitude loops with the layers alone; the flight's law now
    leads over the motors' lag, the lag through which its filter is given the torque (docs/model.md C-13), and
    completes it within the paper's Table 2 (measured alpha 0.032 rad RMS, e_Fy 0.022 m, 4 Dec 2026)."""
    m, _folder, emu = run_demo(demo_args(tmp_path, "--seed", "9"), quiet=True)
    assert m["config"]["law"] == "torque" and m["config"]["actuation_lag_s"] == Vehicle().motor_time_constant
    assert m["flight"]["ended_by"] == "completed" and m["completed"] and m["all_finite"], m["flight"]
    for k in SIGNALS:
        assert m["rms"][k] <= metrics_mod.PAPER_TABLE2[k][0], (k, m["rms"])
    assert emu["mode"] == "AUTO.LOITER" and emu["armed"]


@pytest.mark.parametrize("pacing", ["lockstep", "realtime"])
def test_demo_approach_settles_quickly_with_noisy_telemetry(tmp_path, pacing: str) -> None:
    """The hold at the reference's start ends on 0.5 s window means, not on single noisy samples (which never
    meet 1 cm / 3 cm/s with px4-typical noise and used to wait for the 30 s timeout); the window runs on the
    loop's clock in both pacings (vehicle time in lockstep, local time in real time)."""
    extra = ("--realtime",) if pacing == "realtime" else ()
    m, folder, _ = run_demo(demo_args(tmp_path, "--duration", "0.5", *extra), quiet=True)
    assert m["flight"]["ended_by"] == "completed"
    phases = [e["reason"] for e in json.loads((folder / "events.json").read_text())["loop"] if e["kind"] == "phase"]
    at = [p for p in phases if p.startswith("at the start of the reference after")]
    assert at and float(at[0].split("after ")[1].split(" s")[0]) < 5.0, phases


def test_demo_refuses_noise_with_sensor_models(tmp_path) -> None:
    with pytest.raises(UserError, match="--noise"):
        run_demo(demo_args(tmp_path, "--noise", "1"), quiet=True)


def test_ardupilot_actuator_output_is_refused(tmp_path) -> None:
    with pytest.raises(UserError, match="ArduPilot has no actuator"):
        run_demo(demo_args(tmp_path, "--flavor", "ardupilot", "--output", "actuator"), quiet=True)


def test_demo_rate_out_of_range_is_refused_in_the_rate_s_words(tmp_path) -> None:
    with pytest.raises(UserError, match=r"--rate must be within 20\.\.1000 Hz"):
        run_demo(demo_args(tmp_path, "--rate", "5000"), quiet=True)
