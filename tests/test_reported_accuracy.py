"""The autopilot's reported accuracies (ESTIMATOR_STATUS pos_horiz_accuracy / pos_vert_accuracy, GPS_RAW_INT h_acc /
v_acc) read from the wire and bounding the measured filter's position noise (``offboard.flight.link.telemetry``,
``estimators.filters.measured_kf``, ``docs/estimation.md``): the emulator (PX4 flavour, ``--ekf px4-sih``) sends
ESTIMATOR_STATUS over a real UDP socket as PX4 SITL does; without an estimate error model it sends none."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest
from emulator_helpers import free_port

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from estimators.filters.kf import KalmanEstimator
from estimators.filters.measured_kf import MeasuredKalmanEstimator, MeasuredTuning
from estimators.model.control_state import ControlState
from estimators.model.measurements import PositionVelocity, ReportedAccuracy
from estimators.model.vehicle import load_vehicle
from offboard.flight.link.telemetry import TelemetryDecoder
from sim_bridge.emulator_api import EmulatorConfig, start_emulator

SIH = load_vehicle("px4-sih")
REST = ControlState((0.0,) * 6, (0.0,) * 6, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def _estimator() -> MeasuredKalmanEstimator:
    est = MeasuredKalmanEstimator(SIH, load_sensor=False, rate_hz=250.0)
    est.initialize(0.0, REST)
    return est


def _accuracy_from_emulator(ekf: str, wait_s: float) -> list[ReportedAccuracy]:
    """Every ReportedAccuracy the live decoder makes of the emulator's datagrams within ``wait_s`` s."""
    port = free_port()
    running = start_emulator(
        EmulatorConfig(flavor="px4", vehicle="px4-sih", mavlink=(f"udpout:127.0.0.1:{port}",), ekf=ekf)
    )
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    dec = TelemetryDecoder(system=1)
    out: list[ReportedAccuracy] = []
    try:
        end = time.monotonic() + wait_s
        while time.monotonic() < end and len(out) < 2:
            m = conn.recv_match(blocking=True, timeout=0.2)
            if m is not None and (r := dec.decode(m)) is not None and isinstance(r, ReportedAccuracy):
                out.append(r)
    finally:
        conn.close()
        running.stop()
    return out


def test_the_emulator_reports_px4_sitl_s_accuracy_on_the_wire_and_the_filter_is_bounded_by_it() -> None:
    got = _accuracy_from_emulator("px4-sih", 20.0)
    assert len(got) == 2, "no ESTIMATOR_STATUS from the emulator's PX4 flavour with --ekf px4-sih"
    a = got[0]
    assert (a.pos_h, a.pos_v) == pytest.approx((0.29, 0.03), abs=1e-6)  # PX4 SITL's figures (float32 on the wire)
    assert got[1].t - a.t == pytest.approx(1.0, abs=0.05)  # 1 Hz, stamped with the vehicle's time
    est = _estimator()
    nominal = est.noise_bounds()
    assert nominal["pos_xy"] == pytest.approx((0.02, 0.6))  # nominal floor, 30x ceiling
    est.push(a)
    b = est.noise_bounds()
    assert b["pos_xy"] == pytest.approx((0.02, 0.29), rel=1e-6)
    assert b["pos_z"] == pytest.approx((0.03, 0.03), rel=1e-6)
    assert b["vel_xy"] == nominal["vel_xy"]  # only the position channels
    assert est.stats()["accuracy_reports"] == 1 and est.stats()["accepted"] == 0


def test_without_an_estimate_error_model_the_emulator_reports_no_accuracy() -> None:
    assert _accuracy_from_emulator("none", 4.0) == []  # the truth has no accuracy to report (position from 1.5 s)


def _encoded(mav: mavutil.mavlink.MAVLink, msg: object) -> object:
    """``msg`` packed to bytes and parsed back, as a receiver gets it."""
    buf = msg.pack(mav)  # type: ignore[attr-defined]
    return mavutil.mavlink.MAVLink(None).parse_buffer(buf)[0]


def test_gps_raw_int_stands_in_until_the_estimator_reports_and_dilutions_are_not_lengths() -> None:
    mav = mavutil.mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    dec = TelemetryDecoder(system=1)
    lpn = _encoded(mav, mav.local_position_ned_encode(12_345, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0))
    assert isinstance(dec.decode(lpn), PositionVelocity)

    def gps(fix: int, h_mm: int, v_mm: int) -> object:
        return _encoded(mav, mav.gps_raw_int_encode(0, fix, 0, 0, 0, 70, 110, 0, 0, 10, 0, h_mm, v_mm, 400, 0, 0))

    r = dec.decode(gps(3, 900, 1780))
    assert r == ReportedAccuracy(12.345, 0.9, 1.78)  # stamped with the newest vehicle time (time_usec is 0)
    assert dec.decode(gps(2, 900, 1780)) is None  # no 3D fix
    assert dec.decode(gps(3, 0, 0)) is None  # accuracy unknown: eph / epv (70, 110) are HDOP x 100, not used
    status = _encoded(mav, mav.estimator_status_encode(46_452_000, 895, 0, 0, 0, 0, 0, math.nan, 0.286, 0.0285))
    assert dec.decode(status) == pytest.approx(ReportedAccuracy(46.452, 0.286, 0.0285))
    assert dec.decode(gps(3, 900, 1780)) is None and dec.counts["refused_secondary_accuracy"] == 1
    bad = _encoded(mav, mav.estimator_status_encode(1, 0, 0, 0, 0, 0, 0, 0, math.nan, 0.1))
    assert dec.decode(bad) is None and dec.counts["refused_nonfinite"] == 1


def test_the_adapted_position_noise_stays_between_the_nominal_and_the_reported_accuracy() -> None:
    """Innovations that want 0.5 m of position noise get it without a report and only the reported 0.2 m with one;
    a report finer than the nominal 2 cm (an RTK receiver's 5 mm) lets quiet innovations lower the noise to it."""
    rng = np.random.default_rng(0)

    def adapted(report: float | None, noise: float) -> float:
        est = _estimator()
        if report is not None:
            est.push(ReportedAccuracy(0.0, report, report))
        for k in range(1, 3001):  # 100 s of positions at 30 Hz, at rest
            t = k / 30.0
            x, y = rng.normal(0.0, noise, 2)
            est.push(PositionVelocity(t, float(x), float(y), 2.0, 0.0, 0.0, 0.0))
            est.estimate(t + 0.02)
        return est.noise_levels()["pos_xy"]

    loud = adapted(None, 0.5)
    assert loud > 0.3
    assert adapted(0.2, 0.5) == pytest.approx(0.2, rel=1e-9)
    assert adapted(None, 0.001) == pytest.approx(0.02, rel=1e-9)  # the nominal floor
    fine = adapted(0.005, 0.001)
    assert 0.005 <= fine < 0.01


def test_the_model_based_filter_counts_a_report_as_not_used() -> None:
    kf = KalmanEstimator(SIH.with_changes(mass_load=0.2), load_sensor=False, rate_hz=250.0)
    kf.initialize(0.0, REST)
    kf.push(ReportedAccuracy(0.0, 0.3, 0.03))
    assert kf.stats()["not_used"] == 1
    assert MeasuredTuning().noise_ceiling == 30.0  # (the nominal ceiling the first test reads: 0.02 m x 30)
