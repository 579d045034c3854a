"""slung replay: exact reproduction of live runs (slung demo and a generated offboard flight), the log inventory and
its "what is missing" reports, robustness to damaged logs, exit codes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from tlog_fixtures import LogSpec, flight_log, offboard_log, write_live_table

from offboard.cli import main
from offboard.control.boundary_layers import FLIGHT_LAYER_ERRORS
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, free_udp_port
from offboard.logs import replay as rp
from offboard.logs.estimate_columns import INNOVATION_COLUMNS, SIGMA_COLUMNS
from offboard.logs.timeseries_file import read_table
from offboard.logs.tlog import TlogReader


def _replay_cli(tlog: Path, out: Path, *extra: str) -> tuple[int, dict]:
    code = main(["replay", str(tlog), "--out", str(out), *extra])
    return code, json.loads((out / "metrics.json").read_text())


def _columns(path: Path) -> dict[str, np.ndarray]:
    """The columns of a run folder's time series (``offboard.logs.timeseries_file``)."""
    table = read_table(path)
    return {name: table.data[:, i] for i, name in enumerate(table.columns)}


def _assert_as_kept(replayed: np.ndarray, live_log: Path, name: str) -> None:
    """The replay's column (float64) is the live tick log's column ``name`` exactly at the precision the tick log
    kept it (``offboard.logs.live_storage``: float64 times, float32 estimates and setpoints, float16 for the
    filter's standard deviations and innovations): rounded the same way, every bit equal."""
    table = read_table(live_log)
    kept = table.stored_as(name)
    np.testing.assert_array_equal(replayed.astype(kept), table[name].astype(kept), err_msg=f"{name} ({kept})")


# ------------------------------------------------------------------------------------------ slung demo, exact ---


@pytest.fixture(scope="module")
def demo_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Four short `slung demo` flights recorded for the replay: PX4 with attitude and with actuator output,
    ArduPilot (GUIDED, throttle with angle boost) with attitude output, all lockstep, and PX4 in real time (the
    loop's tick times then come from its clock, not from the emulator's markers)."""
    out = {}
    for flavor, output, mode in (
        ("px4", "attitude", "lockstep"),
        ("px4", "actuator", "lockstep"),
        ("ardupilot", "attitude", "lockstep"),
        ("px4", "attitude", "realtime"),
        ("px4", "attitude", "sih"),  # PX4 SITL's SIH vehicle, no load: --law auto flies the attitude-level law
        ("px4", "attitude", "feedforward"),  # the filter's external acceleration fed forward (the smc row's)
    ):
        name = f"{flavor}-{output}-{mode}"
        d = tmp_path_factory.mktemp(f"demo-{name}")
        # the exit code is not asserted: a flight a watchdog ended early (a loaded test machine) must replay
        # exactly too; the replay tests check that there was a flight at all
        main(
            [
                "demo",
                "--flavor",
                flavor,
                "--duration",
                "1.5",
                "--output",
                output,
                "--no-figures",
                "--out",
                str(d),
                "--sensors",
                "ideal",
                "--disturbance",
                "none",
            ]  # exact telemetry (the demo's default is px4-typical)
            + (["--realtime"] if mode == "realtime" else [])
            + (["--vehicle", "px4-sih", "--scenario", "hover"] if mode == "sih" else [])
            + (["--external-feedforward"] if mode == "feedforward" else [])
            + (["--emulator-tlog"] if flavor == "ardupilot" else [])  # the emulator's side of the link too
        )
        assert (d / "flight.tlog").is_file() and (d / "timeseries_live.slts").is_file()
        out[name] = d
    return out


def test_the_emulators_tlog_is_written_only_when_asked(demo_runs: dict[str, Path]) -> None:
    """``slung demo`` keeps the link's record in flight.tlog; ``--emulator-tlog`` adds the emulator's view of the
    same link (every message type the loop logged, seen from the other end), which doubled the folder."""
    from offboard.logs.tlog import read_messages

    assert not (demo_runs["px4-attitude-lockstep"] / "emulator.tlog").exists()
    run = demo_runs["ardupilot-attitude-lockstep"]
    types = {}
    for name in ("flight.tlog", "emulator.tlog"):
        msgs, _ = read_messages(run / name)
        types[name] = {m.get_type() for _, m in msgs}
    assert {"SET_ATTITUDE_TARGET", "ATTITUDE", "HEARTBEAT"} <= types["flight.tlog"] <= types["emulator.tlog"], types


@pytest.mark.parametrize(
    "run_name",
    [
        "px4-attitude-lockstep",
        "px4-actuator-lockstep",
        "ardupilot-attitude-lockstep",
        "px4-attitude-realtime",
        "px4-attitude-feedforward",
    ],
)
def test_replay_of_slung_demo_reproduces_its_estimates_and_setpoints_exactly(
    demo_runs: dict[str, Path], run_name: str, tmp_path: Path
) -> None:
    run = demo_runs[run_name]
    flavor, output, _ = run_name.split("-")
    code, m = _replay_cli(run / "flight.tlog", tmp_path / "r")
    assert code == 0
    live = _columns(run / "timeseries_live.slts")
    rep = _columns(tmp_path / "r" / "timeseries.slts")
    n = len(live["t_vehicle"])
    # normally ~375 ticks; on a heavily loaded machine the lockstep emulator's grace timeout can advance the
    # vehicle without the loop, and the 1.5 s flight has far fewer ticks: still every one must replay exactly
    assert n >= 5 and len(rep["t"]) == n
    # the replay's own time series against the live loop's, column by column, bit for bit at the precision the
    # tick log keeps (its times whole, its estimates and setpoints as float32: the wire's)
    np.testing.assert_array_equal(rep["t"], live["t_vehicle"])
    pairs = [
        ("Fx", "est_fx0"),
        ("Fx_d5", "est_fx5"),
        ("Fy_d3", "est_fy3"),
        ("z", "est_z"),
        ("psi", "est_psi"),
        ("alpha_x", "est_alpha_x"),
        ("alpha_y_rate", "est_alpha_y_rate"),
        ("cmd_thrust", "cmd_thrust"),
        ("cmd_tau_theta", "cmd_tau_theta"),
    ]
    sp_names = (
        ("q_w", "q_x", "q_y", "q_z", "roll_rate", "pitch_rate", "yaw_rate", "thrust")
        if output == "attitude"
        else ("roll", "pitch", "yaw", "thrust")
    )
    pairs += [("sp_" + name, f"sp{i}") for i, name in enumerate(sp_names)]
    # the loop read the filter's standard deviations and innovations after every tick, the replay reads them too:
    # the reads changed nothing (the estimates above are bit-identical) and they are themselves reproduced exactly
    pairs += [(name, name) for name in (*SIGMA_COLUMNS, *INNOVATION_COLUMNS)]
    for a, b in pairs:
        _assert_as_kept(rep[a], run / "timeseries_live.slts", b)
    assert np.all(live["sd_fx0"] > 0.0) and np.all(np.isfinite(live["sd_alpha_x"]))
    for stream in ("nu_pos", "nu_tilt"):  # from the stream's first fused record on, every tick has its innovation
        nu = live[stream]
        assert np.isfinite(nu).any() and np.isfinite(nu[int(np.argmax(np.isfinite(nu))) :]).all(), stream
    assert m["live_agreement"]["estimate_identical"] == n
    assert m["live_agreement"]["setpoint_identical"] == n
    assert m["live_agreement"]["compared_at"] == {"estimate": "float32", "setpoint": "float32"}
    # the run flew the torque-level law with its per-loop boundary layers (docs/model.md C-12), and the replay
    # rebuilt the law with them: one epsilon for all loops would be another law, and other setpoints
    cfg = json.loads((run / "metrics.json").read_text())["config"]
    assert cfg["layer_errors"] == list(FLIGHT_LAYER_ERRORS)
    assert m["config"]["layer_errors"] == list(FLIGHT_LAYER_ERRORS)
    # and with its model of the motors' lag (docs/model.md C-13): the replay led over the same 20 ms
    assert cfg["actuation_lag_s"] == m["config"]["actuation_lag_s"] == pytest.approx(0.02)
    # the paper scenario still climbs at 1.5 s: the loop flew the reference's smooth stop after it (at least 2 s,
    # offboard.control.reference_stop), and those ticks, replayed with the stop, are among the identical ones above
    assert cfg["stop_after_s"] == pytest.approx(1.5) and live["t_ref"][-1] > 1.5 + 2.0 - 0.01
    # what went over the wire (float32) is what the replay recomputes, rounded to float32
    assert m["setpoint_agreement"]["float32_identical"] == m["setpoint_agreement"]["ticks_compared"] == n
    assert m["log"]["has_offboard_segment"] and m["log"]["autopilot"] == flavor
    # the filter was rebuilt with the live run's tuning: --external-feedforward, recorded in metrics.json
    live_ff = json.loads((run / "metrics.json").read_text())["config"]["external_feedforward"]
    assert live_ff is (run_name.endswith("feedforward")) and m["config"]["external_feedforward"] is live_ff


def test_replay_reproduces_an_attitude_level_law_flight(demo_runs: dict[str, Path], tmp_path: Path) -> None:
    """A flight of the attitude-level law (offboard.control.smc_attitude) replays with that law, bit for bit: its gains
    re-derived from the autopilot model the run logged, as the live loop derived them."""
    run = demo_runs["px4-attitude-sih"]
    live_m = json.loads((run / "metrics.json").read_text())
    assert live_m["config"]["law"] == "attitude"
    code, m = _replay_cli(run / "flight.tlog", tmp_path / "r", "--vehicle", "px4-sih")
    assert code == 0
    live = _columns(run / "timeseries_live.slts")
    rep = _columns(tmp_path / "r" / "timeseries.slts")
    n = len(live["t_vehicle"])
    assert n >= 5 and len(rep["t"]) == n
    for a, b in (("cmd_thrust", "cmd_thrust"), ("sp_q_x", "sp1"), ("sp_q_y", "sp2"), ("sp_thrust", "sp7")):
        _assert_as_kept(rep[a], run / "timeseries_live.slts", b)
    assert m["live_agreement"]["setpoint_identical"] == n
    assert m["setpoint_agreement"]["float32_identical"] == n
    # without --vehicle: the vehicle the run recorded in its metrics.json (not the paper's), the same law
    code, m = _replay_cli(run / "flight.tlog", tmp_path / "r-recorded")
    assert code == 0 and m["live_agreement"]["setpoint_identical"] == n


def test_a_recorded_vehicle_that_does_not_read_is_one_line_and_exit_2(
    demo_runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "flight.tlog").write_bytes((demo_runs["px4-attitude-sih"] / "flight.tlog").read_bytes())
    meta = json.loads((demo_runs["px4-attitude-sih"] / "metrics.json").read_text())
    meta["config"]["vehicle_toml"] = meta["config"]["vehicle_toml"].replace("mass_kg = 1.0", "mass_kg = -1.0", 1)
    (run / "metrics.json").write_text(json.dumps(meta))
    capsys.readouterr()
    assert main(["replay", str(run / "flight.tlog"), "--out", str(tmp_path / "r"), "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--vehicle" in err[0] and "metrics.json" in err[0] and "Traceback" not in err[0], err


def test_replay_of_slung_demo_from_the_tlog_alone(demo_runs: dict[str, Path], tmp_path: Path) -> None:
    """Without the live tick log the ticks of a lockstep run are rebuilt from the emulator's markers and the
    setpoints in the tlog, exactly."""
    run = demo_runs["px4-attitude-lockstep"]
    code, m = _replay_cli(run / "flight.tlog", tmp_path / "r", "--no-live-log")
    assert code == 0
    live = _columns(run / "timeseries_live.slts")
    rep = _columns(tmp_path / "r" / "timeseries.slts")
    assert m["live_agreement"] is None
    assert m["setpoint_agreement"]["float32_identical"] == len(live["t_vehicle"])
    np.testing.assert_array_equal(rep["t_ref"], live["t_ref"])
    _assert_as_kept(rep["Fx_d4"], run / "timeseries_live.slts", "est_fx4")


def test_estimate_only_over_a_whole_demo_log(demo_runs: dict[str, Path], tmp_path: Path) -> None:
    """The estimator alone over the whole log (take-off and approach included, commands unknown): it runs while
    the emulator reports the vehicle in the air and agrees with the autopilot's position."""
    code, m = _replay_cli(
        demo_runs["px4-attitude-lockstep"] / "flight.tlog", tmp_path / "r", "--estimate-only", "--no-figures"
    )
    assert code == 0 and m["estimation"]["airborne_only"]
    assert m["estimation"]["height_vs_autopilot_m"]["rms"] < 0.01
    assert m["estimation"]["position_vs_autopilot_m"]["rms"] < 0.01
    assert m["estimation"]["alpha_x_vs_sensor"]["rms"] < 0.01
    # the payload reports as its own system (as ArduPilot's slung-payload SITL does): the swing against that truth,
    # which is only as good as the vehicle's own GLOBAL_POSITION_INT (the emulator's EKF error / cable length)
    truth = m["estimation"]["swing_vs_truth"]
    assert m["log"]["load_sysid"] == 2 and truth["ticks"] > 100 and truth["truth_swing_max_rad"] is not None
    assert truth["alpha_x"]["rms"] < 0.2 and truth["alpha_y"]["rms"] < 0.2


# --------------------------------------------------------------------------------- generated offboard flights ---


@pytest.mark.parametrize("output", ["attitude", "actuator"])
def test_generated_offboard_flight_is_reproduced_with_and_without_its_tick_log(output: str, tmp_path: Path) -> None:
    data, live_rows = offboard_log(seconds=1.5, output=output)
    sc = rp.scan(TlogReader(data))
    inv = rp.inventory(sc)
    write_live_table(tmp_path / "live.csv", live_rows)
    live = rp.load_live_table(tmp_path / "live.csv")
    assert live is not None
    ref = rp.ReferenceSpec("hover")
    for cfg in (rp.ReplayConfig(reference=ref, live=live), rp.ReplayConfig(reference=ref)):
        res = rp.replay(sc, inv, cfg)
        est = res.data[:, res.columns.index("Fx") : res.columns.index("Fx") + 24]
        np.testing.assert_array_equal(est, np.array([r[3:27] for r in live_rows]))
        ag = res.metrics["setpoint_agreement"]
        assert ag["float32_identical"] == ag["ticks_compared"] == len(live_rows)
    # the swing the filter estimated follows the cable-angle sensor
    assert res.metrics["estimation"]["alpha_x_vs_sensor"]["rms"] < 0.01


def test_offboard_flight_with_an_unknown_reference_runs_the_estimator_only(tmp_path: Path) -> None:
    data, live_rows = offboard_log(seconds=0.8)
    path = tmp_path / "off.tlog"
    path.write_bytes(data)
    code, m = _replay_cli(path, tmp_path / "r", "--no-figures")
    assert code == 0
    assert m["estimation"]["ticks"] == len(live_rows) and m["estimation"]["tick_source"] == "logged setpoints"
    assert m["tracking"] is None and any("reference" in n for n in m["estimation"]["notes"])
    ts = _columns(tmp_path / "r" / "timeseries.slts")
    assert np.all(np.isnan(ts["sp_thrust"])) and np.all(np.isfinite(ts["log_thrust"]))


def test_a_tick_log_from_another_flight_is_refused(tmp_path: Path) -> None:
    data, _ = offboard_log(seconds=0.6)
    _, other = offboard_log(seconds=0.6, scenario="circle")
    sc = rp.scan(TlogReader(data))
    write_live_table(tmp_path / "live.csv", [(*r[:27], *(v + 0.1 for v in r[27:])) for r in other])
    cfg = rp.ReplayConfig(reference=rp.ReferenceSpec("hover"), live=rp.load_live_table(tmp_path / "live.csv"))
    with pytest.raises(rp.LiveLogMismatchError):
        rp.replay(sc, rp.inventory(sc), cfg)


def test_damaged_offboard_log_still_replays(tmp_path: Path) -> None:
    data, live_rows = offboard_log(seconds=1.0)
    rng = np.random.default_rng(21)
    buf = bytearray(data)
    for pos in rng.choice(len(buf), size=30, replace=False):
        buf[pos] ^= 0x5A
    path = tmp_path / "damaged.tlog"
    path.write_bytes(bytes(buf[: len(buf) - 7]))  # and cut inside the last packet
    code, m = _replay_cli(path, tmp_path / "r", "--scenario", "hover")
    assert code == 0
    r = m["reader"]
    assert r["bad_crc"] + r["resyncs"] > 0 and r["truncated"] == 1
    assert m["estimation"]["all_finite"]
    assert 0.9 * len(live_rows) <= m["estimation"]["ticks"] <= len(live_rows)


# ------------------------------------------------------------------------------------ inventory and reports ---


def test_inventory_of_a_clean_log() -> None:
    sc = rp.scan(TlogReader(flight_log(LogSpec(seconds=2.0))))
    inv = rp.inventory(sc)
    assert inv["autopilot"] == "px4" and inv["vehicle_type"] == "quadrotor" and inv["autopilot_sysid"] == 1
    assert inv["has_load_sensor"] and inv["has_local_position"] and inv["has_imu"]
    # the only thing missing: EXTENDED_SYS_STATE (airborne is then judged by height above where it armed)
    assert len(inv["missing"]) == 1 and inv["missing"][0].startswith("no EXTENDED_SYS_STATE")
    assert inv["flew"] and len(inv["airborne_segments"]) == 1
    rates = inv["systems"][0]["rates_hz"]
    assert rates["ATTITUDE"] == pytest.approx(250.0, rel=0.01)
    assert rates["LOCAL_POSITION_NED"] == pytest.approx(50.0, rel=0.02)
    assert inv["message_counts"]["HEARTBEAT"] == 3


def test_log_without_heartbeat_is_replayed_from_its_attitude_telemetry(tmp_path: Path) -> None:
    path = tmp_path / "nohb.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=2.0, heartbeat=False)))
    code, m = _replay_cli(path, tmp_path / "r")
    assert code == 0
    assert m["log"]["autopilot_sysid"] == 1 and m["log"]["autopilot"] is None
    assert any("no HEARTBEAT" in s for s in m["log"]["missing"])
    assert m["estimation"]["ticks"] > 400


def test_log_without_a_load_sensor_is_estimated_from_the_imu(tmp_path: Path) -> None:
    path = tmp_path / "noload.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=2.0, load=False)))
    code, m = _replay_cli(path, tmp_path / "r")
    assert code == 0
    assert not m["log"]["has_load_sensor"] and not m["estimation"]["load_sensor_used"]
    assert any("cable-angle sensor" in s for s in m["log"]["missing"])
    assert m["estimation"]["all_finite"]


def test_sensorless_swing_estimate_follows_the_sensor_it_ignores(tmp_path: Path) -> None:
    path = tmp_path / "a.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=4.0)))
    code, m = _replay_cli(path, tmp_path / "r", "--no-load-sensor")
    assert code == 0 and not m["estimation"]["load_sensor_used"]
    assert m["estimation"]["swing_max_rad"] > 0.1
    assert m["estimation"]["alpha_x_vs_sensor"]["rms"] < 0.02
    assert m["estimation"]["alpha_y_vs_sensor"]["rms"] < 0.02


@pytest.mark.parametrize(
    ("spec", "reason"),
    [
        (LogSpec(seconds=1.0, mav_type=1), "not a multirotor"),
        (LogSpec(seconds=1.0, local_position=False), "no local position"),
    ],
)
def test_unusable_logs_get_a_report_and_exit_code_3(
    spec: LogSpec, reason: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "x.tlog"
    path.write_bytes(flight_log(spec))
    code, m = _replay_cli(path, tmp_path / "r")
    assert code == 3
    assert m["replayed"] is False and any(reason in r for r in m["reasons"])
    assert reason in capsys.readouterr().out
    assert not (tmp_path / "r" / "timeseries.slts").exists()


def test_mavlink1_log_replays(tmp_path: Path) -> None:
    path = tmp_path / "v1.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=2.0, mavlink1=True)))
    code, m = _replay_cli(path, tmp_path / "r")
    assert code == 0 and m["reader"]["mavlink1"] == m["reader"]["packets"] > 0
    assert m["estimation"]["alpha_y_vs_sensor"]["rms"] < 0.01
    assert m["estimation"]["position_vs_autopilot_m"]["rms"] < 0.05
    for name in ("swing.png", "flat_outputs.png"):
        assert (tmp_path / "r" / name).stat().st_size > 1000


def test_time_window(tmp_path: Path) -> None:
    path = tmp_path / "a.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=3.0)))  # vehicle time 12 .. 15 s
    code, m = _replay_cli(path, tmp_path / "r", "--from", "13", "--to", "14")
    assert code == 0 and m["config"]["from_s"] == 13.0
    t = _columns(tmp_path / "r" / "timeseries.slts")["t"]
    assert t.min() >= 13.0 and t.max() <= 14.0 and len(t) > 200


def test_offboard_modes_of_both_autopilots() -> None:
    assert rp.is_offboard_mode(12, 6 << 16, 1 | 128)
    assert not rp.is_offboard_mode(12, 3 << 16, 1)
    assert rp.is_offboard_mode(3, 4, 1) and rp.is_offboard_mode(3, 20, 1)
    assert not rp.is_offboard_mode(3, 5, 1) and not rp.is_offboard_mode(3, 4, 0)


@pytest.mark.parametrize("content", [b"", b"time,x\n1,2\n" * 40, bytes(range(256)) * 8])
def test_empty_or_non_tlog_file_is_a_one_line_error(
    content: bytes, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "x.tlog"
    path.write_bytes(content)
    assert main(["replay", str(path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("slung replay: error:") and "\n" not in err and "tlog" in err


def test_missing_file_and_bad_window_are_usage_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(tmp_path / "nope.tlog")]) == 2
    path = tmp_path / "a.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=0.5)))
    assert main(["replay", str(path), "--from", "5", "--to", "4", "--out", str(tmp_path / "r")]) == 2
    assert "--to" in capsys.readouterr().err


def test_progress_bar_draws_on_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    from offboard.logs.replay_cli import _progress_bar

    bar = _progress_bar()
    for f in (0.0, 0.5, 0.5, 1.0):
        bar(f)
    err = capsys.readouterr().err
    assert err.count("%") == 3 and " 50%" in err and "100%" in err and err.endswith("\n")


def test_estimator_runs_only_while_the_vehicle_reports_itself_in_the_air(tmp_path: Path) -> None:
    path = tmp_path / "ground.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=2.5, landed_until_s=1.0)))  # vehicle time 12 .. 14.5 s
    code, m = _replay_cli(path, tmp_path / "r", "--no-figures")
    assert code == 0 and m["estimation"]["airborne_only"] and m["estimation"]["filter_starts"] == 1
    t = _columns(tmp_path / "r" / "timeseries.slts")["t"]
    assert 13.0 <= t.min() <= 13.25 and t.max() > 14.4


def test_a_reboot_in_the_log_restarts_the_estimator(tmp_path: Path) -> None:
    path = tmp_path / "two-boots.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=1.5, boot_s=30.0)) + flight_log(LogSpec(seconds=1.5, boot_s=5.0)))
    code, m = _replay_cli(path, tmp_path / "r", "--no-figures")
    assert code == 0
    assert m["log"]["boots"] == 2 and any("reboot" in s for s in m["log"]["missing"])
    t = _columns(tmp_path / "r" / "timeseries.slts")["t"]
    assert ((t > 30.0) & (t < 31.6)).sum() > 300 and ((t > 5.0) & (t < 6.6)).sum() > 300
    assert m["estimation"]["all_finite"] and m["estimation"]["alpha_x_vs_sensor"]["rms"] < 0.02


def test_replay_of_a_trajectory_file_flight_uses_the_file_the_run_recorded(tmp_path: Path) -> None:
    """`slung fly --trajectory FILE` records the file's path in metrics.json; the replay finds the reference there
    (no --trajectory needed) and recomputes the flight's setpoints exactly."""
    traj = tmp_path / "hop.toml"
    traj.write_text(
        "[[waypoint]]\nt = 0.0\nx = 0.0\ny = 0.0\nz = 1.0\n[[waypoint]]\nt = 3.0\nx = 0.3\ny = 0.1\nz = 1.1\n",
        encoding="utf-8",
    )
    port = free_udp_port()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004).start()
    p = argparse.ArgumentParser()
    fly_configure(p)
    out = tmp_path / "flight"
    args = p.parse_args(
        ["--connect", f"udpin:127.0.0.1:{port}", "--trajectory", str(traj), "--no-figures", "--out", str(out)]
    )
    try:
        m, folder = fly(
            args, lockstep=True, truth_probe=emu.truth, quiet=True, on_reference_start=emu.set_reference_start
        )
    finally:
        emu.stop()
    assert m["flight"]["ended_by"] == "completed"
    assert m["config"]["trajectory"] == str(traj.resolve())
    code, r = _replay_cli(folder / "flight.tlog", tmp_path / "r")
    assert code == 0
    n = len(_columns(folder / "timeseries_live.slts")["t_vehicle"])
    assert n > 700  # 3 s at 250 Hz, the duration the file gives
    assert r["live_agreement"]["setpoint_identical"] == n
    assert r["setpoint_agreement"]["float32_identical"] == n
    # a reference was known: the replay reports tracking errors against the file's waypoints
    assert r["tracking"]["e_Fx"]["rms"] < 0.05 and r["tracking"]["e_z"]["rms"] < 0.05
