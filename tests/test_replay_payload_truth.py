"""The payload's truth in a replay, against a known answer. DataFlash: a log written by tests/dataflash_writer.py
from the project's own plant model (a hover with a swinging load), carrying ArduPilot SITL's slung-payload message
SLUP and the attitude controller's RATE; the swing the plant simulated is known, so the payload truth read from
SLUP, the report's comparison of the estimate with it, and the body rates taken from RATE are all checked against
it. Tlog: the payload reporting as its own MAVLink system (GLOBAL_POSITION_INT, as the slung-payload SITL does),
checked against the same log's ideal cable-angle sensor."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from dataflash_writer import sim_dataflash
from tlog_fixtures import LogSpec, flight_log

from estimators.model.measurements import Attitude
from offboard.cli import main
from offboard.logs import replay as rp
from offboard.logs.log_formats import scan_log
from offboard.logs.replay_health import offset_swing
from offboard.logs.tlog import TlogReader
from offboard.report.html_plotly import unpacked


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    data, truth = sim_dataflash(8.0)
    path = tmp_path_factory.mktemp("df") / "sim-slup.bin"
    path.write_bytes(data)
    return path, np.asarray(truth)


def _truth_at(truth: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The simulated swing (alpha_x, alpha_y) at the ticks (the plant's 1 ms steps hold every tick time)."""
    i = np.clip(np.searchsorted(truth[:, 0], t - 1e-9), 0, len(truth) - 1)
    assert np.max(np.abs(truth[i, 0] - t)) < 1e-6
    return truth[i, 1:]


def test_slup_gives_the_swing_the_plant_simulated(sim_log: tuple[Path, np.ndarray]) -> None:
    """SLUP's payload offset (5 Hz, NED from the vehicle) read through DFReader and interpolated to the 200 Hz ticks
    is the simulated swing within 0.01 rad RMS per axis (measured 0.003 / 0.006: the 5 Hz samples cut the peaks a
    little); the replay compares its estimate with it and the estimate is within 0.02 rad RMS of it (measured
    0.004 / 0.008) for a swing of 0.17 rad: a sign or axis mistake would be off by the swing itself."""
    path, truth = sim_log
    sc = scan_log(path)
    inv = rp.inventory(sc)
    assert inv["payload_truth"] == "SLUP" and inv["log_format"] == "dataflash"
    res = rp.replay(sc, inv, rp.ReplayConfig())
    t = res.column("t")
    want = _truth_at(truth, t)
    assert res.swing_truth is not None and res.swing_truth.shape == (len(t), 2)
    err = res.swing_truth - want
    assert np.all(np.isfinite(err))
    assert np.sqrt(np.mean(err**2, axis=0)).max() < 0.01
    assert np.max(np.hypot(want[:, 0], want[:, 1])) > 0.15  # the swing is there to be found
    vs = res.metrics["estimation"]["swing_vs_truth"]
    assert vs["source"].startswith("SLUP") and vs["ticks"] == len(t)
    assert vs["alpha_x"]["rms"] < 0.02 and vs["alpha_y"]["rms"] < 0.02
    assert vs["truth_swing_max_rad"] == pytest.approx(float(np.max(np.hypot(*want.T))), abs=0.02)
    est = np.column_stack((res.column("alpha_x"), res.column("alpha_y")))
    assert np.sqrt(np.mean((est - want) ** 2, axis=0)).max() < 0.02  # against the simulation itself


def test_the_report_shows_the_payload_truth(
    sim_log: tuple[Path, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = sim_log
    out = tmp_path / "r"
    assert main(["replay", str(path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "swing vs payload truth" in text
    m = json.loads((out / "metrics.json").read_text())
    assert m["log"]["payload_truth"] == "SLUP" and m["estimation"]["swing_vs_truth"]["ticks"] > 1500
    html = unpacked((out / "report.html").read_text())  # the figures' scripts, packed in the page
    assert "alpha_x payload truth" in html and "alpha_y payload truth" in html
    assert (out / "swing.png").stat().st_size > 10_000 and (out / "attitude_vs_autopilot.png").is_file()


def test_a_slack_or_landed_payload_is_no_truth(tmp_path: Path) -> None:
    """SLUP samples with the payload on the ground (Land 1) or the line slack (Tens 0) give no swing angle."""
    from dataflash_writer import DataFlashWriter

    w = DataFlashWriter()
    w.define("SLUP")
    w.write("SLUP", 1_000_000, 0, 1.0, 1.0, 0.1, 0.0, 0.99, *([0.0] * 9))
    w.write("SLUP", 1_200_000, 1, 1.0, 1.0, 0.1, 0.0, 0.99, *([0.0] * 9))
    w.write("SLUP", 1_400_000, 0, 0.0, 0.9, 0.1, 0.0, 0.89, *([0.0] * 9))
    path = tmp_path / "slup.bin"
    path.write_bytes(w.data())
    sc = scan_log(path)
    offsets = [(e.vt, e.payload) for e in sc.events if e.kind == "payload"]
    assert len(offsets) == 1 and offsets[0][1] == pytest.approx((0.1, 0.0, 0.99))
    ax, ay = offset_swing([1.0, 1.1], offsets)
    # north offset, hanging below: the cable leans north (model x), so alpha_y = atan2(0.1, 0.99) as planar_swing
    assert ay[0] == pytest.approx(math.atan2(0.1, 0.99)) and ax[0] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(ax[1])  # after the last sample: nothing to interpolate


#: the raw gyro's bias (rad/s FRD) in the rate tests: ArduPilot's AHRS removes it before RATE is logged
GYRO_BIAS = (0.05, -0.03, 0.02)


def _body_rates(path: Path, **log: bool) -> tuple[np.ndarray, dict[str, str]]:
    """The body rates (p, q, r rad/s, model FLU) of every Attitude record of a 2 s ``sim_dataflash`` log written
    with ``log``'s options, and where the scan took them from."""
    path.write_bytes(sim_dataflash(2.0, gyro_bias=GYRO_BIAS, slup=False, **log)[0])
    sc = scan_log(path)
    att = [e.payload for e in sc.events if e.kind == "m" and isinstance(e.payload, Attitude)]
    return np.array([(m.p, m.q, m.r) for m in att]), sc.sources


def test_body_rates_come_from_rate_where_present_else_from_the_imu_gyro(tmp_path: Path) -> None:
    """The IMU's raw gyro carries a bias that ArduPilot's AHRS removes before the attitude controller logs RATE.
    With RATE in the log, ATT's body rates are RATE's (deg/s -> rad/s, FRD -> FLU): the true rates; without it,
    the biased IMU gyro's, and the scan says which."""
    rates_a, src_a = _body_rates(tmp_path / "rate.bin")
    rates_b, src_b = _body_rates(tmp_path / "norate.bin", rate=False)
    assert src_a["body_rates"] == "RATE" and src_b["body_rates"] == "IMU gyro" and src_a["rate_unit"] == "deg/s"
    assert len(rates_a) == len(rates_b) == 101
    # FRD -> model FLU: x kept, y and z negated
    want_bias = np.array([GYRO_BIAS[0], -GYRO_BIAS[1], -GYRO_BIAS[2]])
    diff = rates_b - rates_a
    assert np.allclose(diff[1:], want_bias, atol=1e-5), diff[:3]
    # RATE's are the plant's true rates: tiny (small torques) next to the bias
    assert np.max(np.abs(rates_a)) < 0.02


def test_a_payload_systems_global_position_is_the_swing_s_truth_in_a_tlog(tmp_path: Path) -> None:
    """The vehicle's and the payload's GLOBAL_POSITION_INT at 50 Hz (the payload as system 2, an airship, as
    ArduPilot's slung-payload SITL reports it) beside an ideal cable-angle sensor: the truth they give is the
    sensor's angle within the positions' resolution (1e-7 degree, 1.1 cm, over the 0.3 m cable: 0.037 rad a step;
    measured 0.010 / 0.015 rad RMS, 0.024 / 0.036 max), for a swing of 0.15 rad; and the figures get it."""
    path = tmp_path / "payload.tlog"
    path.write_bytes(flight_log(LogSpec(seconds=4.0, payload_hz=50.0)))
    sc = rp.scan(TlogReader.from_path(path))
    inv = rp.inventory(sc)
    assert inv["payload_truth"] == "GLOBAL_POSITION_INT" and inv["load_sysid"] == 2
    res = rp.replay(sc, inv, rp.ReplayConfig())
    vs = res.metrics["estimation"]["swing_vs_truth"]
    assert vs["source"].startswith("GLOBAL_POSITION_INT of system 2") and vs["ticks"] > 900
    sensor = np.column_stack((res.column("meas_alpha_x"), res.column("meas_alpha_y")))
    assert res.swing_truth is not None
    err = res.swing_truth - sensor
    ok = np.isfinite(err).all(axis=1)
    assert ok.sum() > 900 and np.nanmax(np.hypot(sensor[:, 0], sensor[:, 1])) > 0.12
    assert np.sqrt(np.mean(err[ok] ** 2, axis=0)).max() < 0.025 and np.abs(err[ok]).max() < 0.06
    assert vs["alpha_x"]["rms"] < 0.04 and vs["alpha_y"]["rms"] < 0.04  # the estimate against that truth


def test_rate_in_centidegrees_as_arducopter_before_3_4_logged_it(tmp_path: Path) -> None:
    """ArduCopter 3.3 logged RATE's R, P, Y in centidegrees/s (the gyro times 100 * 180 / pi), later versions in
    degrees/s, and an old log does not say which: the scan tells them apart by their ratio to the IMU gyro, so
    both logs give the same body rates."""
    ra, _ = _body_rates(tmp_path / "deg.bin")
    rb, src = _body_rates(tmp_path / "cdeg.bin", rate_centideg=True)
    assert src["body_rates"] == "RATE" and src["rate_unit"].startswith("centideg/s")
    np.testing.assert_allclose(rb, ra, rtol=1e-5, atol=1e-9)
