"""What the filters give the log besides the estimate: the covariance, the standard deviations of
``estimators.filters.factory.SIGMA_NAMES`` and the normalized innovations per stream. Reading them every tick must leave
the filter exactly as it was (the live loop reads them, the replay must stay bit-identical), and each must be what
it says: the sigmas those of the covariance, an innovation the residual over its predicted standard deviation."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from test_estimators import V, truth_state
from test_measured_kf import _hover_stream

from estimators.filters.factory import INNOVATION_STREAMS, SIGMA_NAMES, make_estimator
from estimators.filters.kf import STATE_NAMES
from estimators.filters.small_kf import update_one
from estimators.model.control_state import ControlState
from estimators.model.measurements import PositionVelocity
from sim_bridge.plant import dynamics

_HOVER = dynamics.make_state(position=(0.0, 0.0, 1.0), euler=(0.0, 0.0, 0.3), cable=(0.05, -0.03, -1.0))


def _fly(kind: str, read: bool, seconds: float = 3.0) -> tuple[list[ControlState], object]:
    """A hover stream through filter ``kind`` ticked at 250 Hz (with the hover command fed back, which the
    torque-driven filter uses); ``read``: every read-out after every tick, as the live loop does."""
    est = make_estimator(kind, V, load_sensor=False, rate_hz=250.0)
    est.initialize(0.0, truth_state(_HOVER))
    recs, ticks = _hover_stream(7, seconds, jitter_us=False)
    hover = (V.mass_vehicle + V.mass_load) * V.gravity
    out, j = [], 0
    for k, t in enumerate(ticks):
        while j < len(recs) and recs[j].t <= t - 0.003:
            est.push(recs[j])
            j += 1
        out.append(est.estimate(t))
        est.push_command(t, hover, (0.01 * math.sin(k), -0.01 * math.cos(k), 0.0))
        if read:
            est.covariance()
            est.sigmas()
            est.innovations()
    return out, est


@pytest.mark.parametrize("kind", ["kf", "kf-torque"])
def test_reading_covariance_sigmas_and_innovations_changes_nothing(kind: str) -> None:
    """Two filters on one stream, one read after every tick: every estimate, the final covariance and the
    counters are identical bit for bit (the torque-driven filter's covariance read used to move the counter that
    times its re-symmetrization, so a read changed later estimates in the last bits)."""
    quiet, a = _fly(kind, read=False)
    read, b = _fly(kind, read=True)
    assert len(quiet) == len(read) > 500
    assert all(x == y for x, y in zip(quiet, read, strict=True))
    np.testing.assert_array_equal(a.covariance(), b.covariance())  # type: ignore[attr-defined]
    assert a.stats() == b.stats() and a.sigmas() == b.sigmas()  # type: ignore[attr-defined]


def test_measured_filter_sigmas_are_those_of_its_covariance() -> None:
    _, est = _fly("kf", read=False)
    p = est.covariance()  # type: ignore[attr-defined]
    i = {n: k for k, n in enumerate(est.state_names)}  # type: ignore[attr-defined]
    sd = dict(zip(SIGMA_NAMES, est.sigmas(), strict=True))  # type: ignore[attr-defined]
    var = {n: p[k, k] for n, k in i.items()}
    l2 = V.cable_length**2
    assert sd["p_x"] == pytest.approx(math.sqrt(var["p_x"]), rel=1e-12)
    assert sd["fx0"] == pytest.approx(math.sqrt(var["p_x"] + l2 * var["alpha_y"]), rel=1e-12)
    assert sd["fy0"] == pytest.approx(math.sqrt(var["p_y"] + l2 * var["alpha_x"]), rel=1e-12)
    assert sd["alpha_x"] == pytest.approx(math.sqrt(var["alpha_x"]), rel=1e-12)
    assert sd["z"] == pytest.approx(math.sqrt(var["z"]), rel=1e-12)
    assert sd["psi"] == pytest.approx(math.sqrt(var["psi"]), rel=1e-12)
    # roll and pitch: the world tilt rotated by the heading, plus the heading's own uncertainty to first order
    e = est.estimate(est._t_out)  # type: ignore[attr-defined]
    cp, sp = math.cos(e.psi), math.sin(e.psi)
    v_theta = cp * cp * var["n_x"] + sp * sp * var["n_y"] + e.phi**2 * var["psi"]
    assert sd["theta"] == pytest.approx(math.sqrt(v_theta), rel=1e-9)
    assert all(v > 0.0 for v in sd.values())


def test_torque_filter_sigmas_are_those_of_its_covariance() -> None:
    _, est = _fly("kf-torque", read=False)
    p = est.covariance()  # type: ignore[attr-defined]
    i = {n: k for k, n in enumerate(STATE_NAMES)}
    sd = dict(zip(SIGMA_NAMES, est.sigmas(), strict=True))  # type: ignore[attr-defined]
    ell = V.cable_length
    px, ay = i["p_x"], i["alpha_y"]
    assert sd["fx0"] == pytest.approx(math.sqrt(p[px, px] + ell**2 * p[ay, ay] + 2 * ell * p[px, ay]), rel=1e-12)
    assert sd["p_y"] == pytest.approx(math.sqrt(p[i["p_y"], i["p_y"]]), rel=1e-12)
    assert sd["z"] == pytest.approx(math.sqrt(p[i["z"], i["z"]]), rel=1e-12)
    assert sd["alpha_x"] == pytest.approx(math.sqrt(p[i["alpha_x"], i["alpha_x"]]), rel=1e-12)


def test_innovation_is_the_rms_of_the_records_normalized_residuals_and_a_gated_one_is_counted() -> None:
    """A position record off the prediction in x only: nu_pos is the RMS over the record's four channels (x, vx, y,
    vy, fused one after the other) of residual over sqrt(P + R), recomputed here with the filter's own scalar
    update; 2 cm off: small and accepted; 1 m off: the x channel beyond the gate and gated_pos counts it."""
    _, est = _fly("kf", read=False)
    f: Any = est  # the filter's internals: the prediction and the noise the innovation is normalized by
    pos, gated_pos = INNOVATION_STREAMS.index("pos"), len(INNOVATION_STREAMS) + INNOVATION_STREAMS.index("pos")
    gate = f._gate[1]
    for offset, refused in ((0.02, False), (1.0, True)):
        f.estimate(f._t_out + f.delay + 0.01)  # every record still queued fused first
        assert f.stats()["buffered"] == 0
        before = f.innovations()[gated_pos]
        t = f._t_out + 0.004
        x, p = f._predicted(f._kin[0], t)
        x_meas, vx_meas = x[0] + offset, x[1]  # on the prediction but for the offset in x
        (y, vy, _), (z, vz, _) = f._predicted(f._kin[1], t)[0], f._predicted(f._kin[2], t)[0]
        r_p, r_v = f._ch["pos_xy"].value(), f._ch["vel_xy"].value()
        nu_x = offset / math.sqrt(p[0][0] + r_p)
        accepted = update_one(x, p, 0, x_meas, r_p, gate) is not None  # x, then vx against the corrected state
        nu_v = (vx_meas - x[1]) / math.sqrt(p[1][1] + r_v)
        expected = math.sqrt((nu_x**2 + nu_v**2) / 4.0)  # y and vy: on the prediction, zero innovations
        assert accepted != refused
        f.push(PositionVelocity(t, x_meas, y, z, vx_meas, vy, vz))
        f.estimate(t + f.delay + 0.001)
        nu = f.innovations()
        assert nu[pos] == pytest.approx(expected, rel=1e-9)
        assert (nu_x**2 > gate) == refused
        assert nu[gated_pos] == before + (1 if refused else 0)


def test_the_reports_gate_is_the_filters() -> None:
    from estimators.filters.kf import chi2_quantile
    from estimators.filters.measured_kf import MeasuredTuning
    from offboard.report.filter_readouts import GATE_SIGMAS

    assert math.sqrt(chi2_quantile(MeasuredTuning().gate_probability, 1)) == GATE_SIGMAS


def test_a_simulation_with_the_filter_logs_its_sigmas_and_draws_the_band() -> None:
    """``slung sim --estimator kf``: the log carries the filter's standard deviations (sd_* columns of LOG_COLUMNS),
    report.html's error panels draw +-2 of them, and metrics.json says how often the true error stayed inside
    (measured 0.84-0.99 on this hover; a filter overconfident by 2x would cover about 0.68 at most)."""
    from estimators.model.vehicle import load_vehicle
    from offboard.control import smc
    from offboard.control.scenarios import make_scenario
    from offboard.harness.sim import run
    from offboard.logs.runlog import SimConfig
    from offboard.report import metrics as metrics_mod
    from offboard.report.run_report_html import build_panels

    vehicle = load_vehicle(None)
    cfg = SimConfig(plant_dt=0.001, control_rate=250.0, sensors="px4-typical", estimator="kf", attitude_model="rigid")
    log = run(make_scenario("hover", duration=6.0), vehicle, smc.ControllerParams.for_vehicle(vehicle), cfg)
    sd = log.column("sd_fx0")
    assert np.all(np.isfinite(sd)) and np.all(sd > 0.0) and np.all(np.isfinite(log.column("sd_alpha_y")))
    panels = {p.title: p for p in build_panels(log)}
    swing = panels["Swing estimate minus truth"]
    for tr, name in zip(swing.traces, ("sd_alpha_x", "sd_alpha_y"), strict=True):
        assert tr.band is not None
        np.testing.assert_array_equal(tr.band[1], 2.0 * log.column(name))
    within = metrics_mod.compute(log)["estimation"]["within_2sigma"]
    assert set(within) == {"alpha_x", "alpha_y", "F_x", "F_y", "z", "psi"}
    assert min(within.values()) >= 0.7, within
