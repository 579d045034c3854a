"""`slung replay` on the logs users really have: what was flown (armed and off the ground), mode tables per
vehicle, clock steps that are not reboots, divergence detected and recovered from, never a number beyond 1e6 or
NaN printed as a result. Real third-party logs are in tests/data (provenance: tests/data/SOURCES.md)."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from dataflash_writer import DataFlashWriter, ulog_to_dataflash
from tlog_fixtures import LogSpec, flight_log

from offboard.cli import main
from offboard.logs import replay as rp
from offboard.logs.flight_modes import is_offboard_mode, mode_name
from offboard.logs.log_inventory import clock_jump
from offboard.logs.tlog import TlogReader

DATA = Path(__file__).parent / "data"


def _replay(path: Path, out: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, dict, str]:
    code = main(["replay", str(path), "--out", str(out), "--no-figures", *extra])
    text = capsys.readouterr().out
    return code, json.loads((out / "metrics.json").read_text()), text


def _no_unusable_number_printed(text: str) -> None:
    """No result printed is NaN, infinite or beyond 1e6 (counts of packets and bytes are not results)."""
    assert not re.search(r"\b(nan|inf)\b", text, re.I)
    for line in text.splitlines():
        if line.strip().startswith(("packets", "log:", "skipped", "telemetry")):
            continue
        for v in re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", line):
            assert abs(float(v)) <= 1e6, line


def test_mode_tables_are_per_vehicle_type() -> None:
    # ArduCopter: GUIDED 4 and GUIDED_NOGPS 20; ArduPlane: GUIDED is 15 and 20 is QLAND (not offboard)
    assert is_offboard_mode(3, 4, 1, 2) and is_offboard_mode(3, 20, 1, 2) and not is_offboard_mode(3, 5, 1, 2)
    assert is_offboard_mode(3, 15, 1, 1) and not is_offboard_mode(3, 20, 1, 1) and not is_offboard_mode(3, 4, 1, 1)
    assert mode_name(3, 1, 1, 20) == "QLAND" and mode_name(3, 2, 1, 20) == "GUIDED_NOGPS"
    assert mode_name(3, 21, 1, 20) == "QLAND"  # a QuadPlane reporting as a VTOL type uses Plane's table
    assert is_offboard_mode(3, 15, 1, 10) and mode_name(3, 10, 1, 4) == "HOLD"  # Rover
    assert is_offboard_mode(3, 4, 1, 12) and mode_name(3, 12, 1, 9) == "SURFACE"  # Sub
    assert is_offboard_mode(12, 6 << 16, 1, 2) and mode_name(12, 2, 1, (4 << 16) | (3 << 24)) == "LOITER"
    assert not is_offboard_mode(3, 4, 0, 2)  # custom mode not enabled


def test_a_clock_step_is_not_a_reboot() -> None:
    assert clock_jump(500.0, 501.4) == "step" and clock_jump(5.0, 300.0) == "reboot"
    assert clock_jump(100.0, 100.5) is None and clock_jump(101.0, 100.0) is None


def test_a_real_ardupilot_quadplane_tlog(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ArduPlane QuadPlane telemetry (node-mavlink's sample log): RAW_IMU is decoded as the live loop does, Plane's
    mode table names QLAND (not offboard), the 1.4 s clock step is not a reboot, messages stamped 0 do not stretch
    the span, and the vehicle is refused as a fixed wing, said once."""
    sc = rp.scan(TlogReader.from_path(DATA / "ardupilot-quadplane-node-mavlink.tlog"))
    inv = rp.inventory(sc)
    assert inv["autopilot"] == "ardupilot" and inv["ardupilot_firmware"] == "plane"
    assert inv["measurements"]["Imu"] > 700 and inv["has_imu"]  # RAW_IMU
    assert "QLAND" in inv["flight_modes"] and "GUIDED" in inv["flight_modes"]
    assert inv["boots"] == 1 and inv["clock_steps"] == 1
    ap = next(s for s in inv["systems"] if s["sysid"] == 1)
    assert ap["vehicle_time_span_s"] < 1000.0  # not from 0 (GPS_RAW_INT without a fix, HOME_POSITION)
    code, m, text = _replay(DATA / "ardupilot-quadplane-node-mavlink.tlog", tmp_path / "r", capsys)
    assert code == 3 and m["replayed"] is False and "not a multirotor" in m["reasons"][0]
    assert "fixed wing (fixed wing)" not in text and "(reboots)" not in text and "without a reboot" in text


def test_a_disarmed_log_is_not_called_a_flight(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "disarmed.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=2.0, armed=False)))
    code, m, text = _replay(path, tmp_path / "r", capsys)
    assert code == 3 and not m["log"]["flew"] and m["log"]["airborne_segments"] == []
    assert any("never armed" in r for r in m["reasons"]) and "never armed" in text


def test_a_ground_only_log_exits_3_naming_why(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "ground.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=2.0, landed_until_s=10.0)))  # EXTENDED_SYS_STATE: on the ground
    code, m, text = _replay(path, tmp_path / "r", capsys)
    assert code == 3 and m["log"]["armed_s"] > 1.9
    assert any("never off the ground" in r and "EXTENDED_SYS_STATE" in r for r in m["reasons"])
    assert "never off the ground" in text and "Replayed 0 ticks" not in text


def test_a_planted_position_jump_is_reported_with_its_time_and_recovered_from(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The autopilot's position jumps 50 m north at vehicle time 14 s (boot 12 s + 2 s): the replay reports the
    divergence then, restarts from the autopilot's state, and agrees with it again; metrics.json does not call
    the run all finite, and nothing absurd is printed."""
    path = tmp_path / "jump.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=4.0, position_jump=(2.0, 50.0))))
    code, m, text = _replay(path, tmp_path / "r", capsys)
    est = m["estimation"]
    assert code == 0 and est["divergences"], est
    first = est["divergences"][0]
    assert 14.0 <= first["t_s"] <= 14.5 and "autopilot" in first["reason"]
    assert est["all_finite"] is False and 0 < est["diverged_ticks"] < 10
    assert est["usable_ticks"] == est["ticks"] - est["diverged_ticks"]
    assert est["position_vs_autopilot_m"]["rms"] < 0.1 and est["position_vs_autopilot_m"]["max"] < 1.0
    assert "divergence" in text and "14.0" in text
    _no_unusable_number_printed(text)


# ------------------------------------------------------------------------------- on-board logs: ULog, DataFlash ---


def shared_log(name: str) -> Path:
    """A third-party log kept in the project's shared folder (``shared/logs``, beside the repository or its
    worktrees; ``$SLUNG_SHARED_LOGS`` overrides): such logs come from public repositories and are not committed
    here (tests/data/SOURCES.md lists them with their licences). Skips when absent, saying where it looked.
    """
    env = os.environ.get("SLUNG_SHARED_LOGS")
    here = Path(__file__).resolve().parent.parent
    dirs = [Path(env)] if env else [p / "shared" / "logs" for p in (here.parent, *here.parents)]
    for d in dirs:
        if (d / name).is_file():
            return d / name
    # A plain skip even under SLUNG_REQUIRE_REAL: this is an input the project may not ship (it came through the
    # snapshot tool, whose files live only in the steering repo's shared/), so CI has it only once it is placed
    # there; failing CI for it would block every landing until then. The closing note asks for it.
    pytest.skip(f"third-party log {name} absent: not in {dirs[0]} (see tests/data/SOURCES.md)")


def test_a_px4_sitl_ulog_flight_replays_through_the_same_estimator(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The project's own PX4 SITL (SIH quadrotor) take-off and hover, PX4's own ULog cut to 10..40 s: the airborne
    segment starts at the take-off PX4 detected, and the estimate stays with PX4's own estimate."""
    code, m, text = _replay(DATA / "px4-sitl-sih-hover.ulg", tmp_path / "r", capsys, "--vehicle", "px4-sih")
    inv, est = m["log"], m["estimation"]
    assert code == 0 and inv["log_format"] == "ulog" and inv["autopilot"] == "px4"
    assert "AUTO_TAKEOFF" in inv["flight_modes"] and len(inv["airborne_segments"]) == 1
    seg = inv["airborne_segments"][0]
    assert 15.0 < seg["from_s"] < 25.0 and seg["to_s"] > 39.0
    assert est["ticks"] > 4900 and est["position_vs_autopilot_m"]["rms"] < 2.0
    assert est["usable_ticks"] > 0.9 * est["ticks"]
    # SIH carries nothing: the IMU says so (offboard.logs.replay_load), and no swing is reported
    assert m["load"]["attached"] is False and "swing_max_rad" not in est
    _no_unusable_number_printed(text)


def test_the_estimate_of_the_px4_sitl_hover_stays_within_half_a_metre_of_px4s(tmp_path: Path) -> None:
    """(The measured-attitude filter drifted 1.2 m RMS in height on this log when it first landed; its innovation-
    adapted position noise brought it to 0.01 m.)"""
    from estimators.model.vehicle import load_vehicle
    from offboard.logs.log_formats import scan_log

    sc = scan_log(DATA / "px4-sitl-sih-hover.ulg")

    res = rp.replay(sc, rp.inventory(sc), rp.ReplayConfig(vehicle=load_vehicle("px4-sih")))
    est = res.metrics["estimation"]
    assert est["position_vs_autopilot_m"]["rms"] < 0.5 and est["height_vs_autopilot_m"]["rms"] < 0.5


def test_a_px4_tlog_on_the_ground_exits_3(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The companion's tlog of the same PX4 SITL before it armed (hover setpoints streamed, never armed)."""
    code, m, text = _replay(DATA / "px4-sitl-sih-ground.tlog", tmp_path / "r", capsys)
    assert code == 3 and m["replayed"] is False and not m["log"]["flew"]
    assert "never armed" in m["reasons"][0] and "not replayed: no flight" in text


def test_an_arducopter_dataflash_flight_stays_with_the_autopilot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """ArduCopter 3.3 DataFlash log of a real Pixhawk flight (dronekit-la-testdata log171.bin, CC BY-SA 3.0; not
    SITL, shared/logs/SOURCES.md): one airborne segment from the NOT_LANDED event, cut where the vehicle flipped
    over (238.9 s); the estimate within 2 m RMS of the EKF's position. The vehicle carried nothing and the IMU says
    so: no swing states, no swing reported, no divergence (tests/test_replay_load.py has the other two logs)."""
    path = shared_log("arducopter-pixhawk-dronekit-la-log171.bin")
    code, m, text = _replay(path, tmp_path / "r", capsys, "--vehicle", "ardupilot-sitl-quad")
    inv, est = m["log"], m["estimation"]
    assert code == 0 and inv["log_format"] == "dataflash" and inv["ardupilot_firmware"] == "copter"
    assert inv["flight_modes"] == ["LOITER", "ACRO"] and len(inv["airborne_segments"]) == 1
    assert inv["airborne_segments"][0]["from_s"] == pytest.approx(82.8, abs=0.2)
    assert est["position_vs_autopilot_m"]["rms"] < 2.0 and est["height_vs_autopilot_m"]["rms"] < 2.0
    assert m["load"]["attached"] is False and "swing_max_rad" not in est
    assert est["divergences"] == [] and est["diverged_ticks"] == 0
    assert [f["t_s"] for f in est["flips"]] == [pytest.approx(238.9, abs=0.3)]
    _no_unusable_number_printed(text)


def test_the_px4_sitl_flight_as_dataflash_replays_like_its_ulog(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``slung replay FILE.bin`` in CI without a third-party log: the project's own PX4 SITL ULog is converted, in
    the test, into an ArduCopter DataFlash log of the same flight (tests/dataflash_writer.py: IMU, ATT, XKF1, ARM,
    EV, MODE, MSG in ArduPilot's layout and units). Read by pymavlink's DFReader, it replays as the ULog does
    (segment from the NOT_LANDED event, the estimate with the EKF's position), and the two replays agree tick by
    tick: flat outputs within 2 cm, attitude within 0.01 rad; body rates within 0.25 rad/s RMS only, because the
    DataFlash path takes them from the raw IMU gyro where the ULog path reads PX4's filtered
    vehicle_angular_velocity; with a load (the paper's vehicle) the swing within 0.05 rad RMS."""
    from estimators.model.vehicle import load_vehicle
    from offboard.logs.log_formats import scan_log

    ulg = DATA / "px4-sitl-sih-hover.ulg"
    path = tmp_path / "px4-sitl-sih-hover.bin"
    path.write_bytes(ulog_to_dataflash(ulg))
    code, m, text = _replay(path, tmp_path / "r", capsys, "--vehicle", "px4-sih")
    inv, est = m["log"], m["estimation"]
    assert code == 0 and inv["log_format"] == "dataflash" and inv["autopilot"] == "ardupilot"
    assert inv["ardupilot_firmware"] == "copter" and inv["flight_modes"] == ["LOITER", "AUTO"]
    assert inv["measurements"]["Imu"] > 7000 and len(inv["airborne_segments"]) == 1
    seg = inv["airborne_segments"][0]
    assert 15.0 < seg["from_s"] < 25.0 and seg["to_s"] > 39.0
    assert est["ticks"] > 4900 and est["position_vs_autopilot_m"]["rms"] < 2.0
    assert est["usable_ticks"] > 0.9 * est["ticks"]
    assert m["load"]["attached"] is False and "swing_max_rad" not in est
    _no_unusable_number_printed(text)

    def runs(config: rp.ReplayConfig) -> tuple[np.ndarray, Callable[[str], np.ndarray]]:
        a, b = (rp.replay(sc, rp.inventory(sc), config) for sc in (scan_log(ulg), scan_log(path)))
        ticks, ia, ib = np.intersect1d(np.round(a.column("t"), 4), np.round(b.column("t"), 4), return_indices=True)
        assert len(ticks) > 0.99 * min(len(a.data), len(b.data))
        return ticks, lambda name: np.abs(a.column(name)[ia] - b.column(name)[ib])

    ticks, diff = runs(rp.ReplayConfig(vehicle=load_vehicle("px4-sih")))  # the flown vehicle: no swing states
    for name in ("Fx", "Fy", "z", "pos_x", "pos_y", "pos_z"):
        assert np.nanmax(diff(name)) < 0.02, name
    for name in ("phi", "theta", "psi"):
        assert np.nanmax(diff(name)) < 0.01, name
    for name in ("phi_rate", "theta_rate", "psi_rate"):
        assert np.sqrt(np.nanmean(diff(name) ** 2)) < 0.25, name
    # the paper's vehicle (a hanging load): the swing estimated from the accelerometer and rates agrees to 0.05 rad
    # RMS; in the first 2 s after take-off the raw gyro's transient makes it differ by up to 0.36 rad, then 0.05
    ticks, diff = runs(rp.ReplayConfig())
    for name in ("alpha_x", "alpha_y"):
        assert np.sqrt(np.nanmean(diff(name) ** 2)) < 0.05, name
        assert np.nanmax(diff(name)[ticks > ticks[0] + 2.0]) < 0.05, name


def test_the_dataflash_writer_round_trips_through_dfreader(tmp_path: Path) -> None:
    """Scaled fields (centidegrees ``c``, 0..36000 ``C``), strings and the FMT lengths as pymavlink reads them; a
    string longer than its field is refused, not cut."""
    from pymavlink import DFReader

    w = DataFlashWriter()
    w.define("XKF1")
    w.define("MSG")
    w.write("XKF1", 1_500_000, 0, -12.34, 5.67, 359.99, 1.0, -2.0, 0.5, 0.5, 10.0, -20.0, -3.0, 0.0, 0.0, 0.0, 12.0)
    w.write("MSG", 1_600_000, "ArduCopter V4.5.7")
    with pytest.raises(ValueError, match="longer"):
        w.write("MSG", 1_700_000, "x" * 65)
    path = tmp_path / "w.bin"
    path.write_bytes(w.data())
    r = DFReader.DFReader_binary(str(path), zero_time_base=True)
    xkf = r.recv_match(type="XKF1")
    assert xkf.TimeUS == 1_500_000 and xkf.Roll == pytest.approx(-12.34) and xkf.Yaw == pytest.approx(359.99)
    assert (xkf.PN, xkf.PE, xkf.PD, xkf.OH) == (10.0, -20.0, -3.0, 12.0)
    assert r.recv_match(type="MSG").Message == "ArduCopter V4.5.7"
