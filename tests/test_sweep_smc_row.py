"""The ``smc`` row of ``slung sweep`` (``registry.smc_params``, ``registry.filter_tuning``): the filter's external
acceleration fed forward is the same in the compiled engine as in the scalar path, and on two of the default sweep's
runs that failed before it (docs/compare.md, "What is left, per failure") the row's law and filter fly: a late
gust's residual swing falls under the bound, a large initial swing on slow motors no longer ends at the watchdog."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from estimators.filters.measured_model import MeasuredTuning
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.controllers import registry
from offboard.control.controllers.sliding_mode import SlidingModeController
from offboard.harness import sim, sweep
from offboard.harness.compiled import engine
from offboard.logs.runlog import SimConfig

V = Vehicle()
FF = MeasuredTuning(external_feedforward=True)


def _fly_run(run: int, params: smc.ControllerParams, tuning: MeasuredTuning | None) -> dict[str, object]:
    """Run ``run`` of the default sweep through the scalar path, as ``sweep.run_one`` flies it, with the given
    law and filter tuning; its figures and verdict (``sweep.evaluate``)."""
    cfg = sweep.load_config(None)
    p = sweep.draw(cfg, run, V)
    sc = sweep.scenario(cfg, p)
    sim_cfg = SimConfig(estimator="kf", sensors=cfg.sensors, actuators="mixer", seed=int(p["sensor_seed"]))
    log = sim.run(
        sc,
        sweep.plant_vehicle(V, p),
        smc.ControllerParams.for_vehicle(V),
        sim_cfg,
        controller=SlidingModeController(params),
        sensor_preset=sweep.sensor_preset(cfg, p),
        command_lag=True,
        tuning=tuning,
    )
    return sweep.evaluate(cfg, log.data, sc.arrival_time, log.slack_steps)


def test_the_external_feedforward_of_the_compiled_filter_equals_the_scalar_one(tmp_path: Path) -> None:
    """Two drawn runs with a 1 N gust during a short move, the row's filter tuning: the plant and the estimate to
    1e-9 in both paths, and the feed-forward acts (the trajectories differ from those without it)."""
    cfg = replace(sweep.load_config(None), move_time_s=1.0, hold_s=1.0)
    params = registry.smc_params(V)
    draws = []
    for r in (1, 2):
        d = sweep.draw(cfg, r, V)
        d.update(gust_n=1.0, gust_start_s=1.2)
        draws.append(d)
    vehicles = [sweep.plant_vehicle(V, d) for d in draws]
    scs = [sweep.scenario(cfg, d) for d in draws]
    presets = [sweep.sensor_preset(cfg, d) for d in draws]
    seeds = [int(d["sensor_seed"]) for d in draws]
    kw = {"estimator": "kf", "actuators": "mixer", "sensors": presets, "seeds": seeds, "load_sensor": True}
    log = engine.simulate(scs, vehicles, params, tuning=FF, **kw)
    off = engine.simulate(scs, vehicles, params, **kw)
    for b in range(2):
        sim_cfg = SimConfig(estimator="kf", sensors=cfg.sensors, actuators="mixer", seed=seeds[b])
        ref = sim.run(
            scs[b],
            vehicles[b],
            smc.ControllerParams.for_vehicle(V),
            sim_cfg,
            controller=SlidingModeController(params),
            sensor_preset=presets[b],
            command_lag=True,
            tuning=FF,
        )
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        for col in ("est_Fx0", "est_Fy0"):
            np.testing.assert_allclose(log[col][:, b], ref.column(col), rtol=0.0, atol=1e-9)
        assert np.abs(log["x"][:, 0:2, b] - off["x"][:, 0:2, b]).max() > 1e-3  # the feed-forward moved the vehicle


def test_a_late_gust_leaves_less_swing_with_the_external_force_fed_forward() -> None:
    """Sweep run 435 (0.80 N gust from 4.99 s, ending 1 s before the residual-swing window): over the bound without
    the feed-forward, well under it with it (the same law)."""
    params = registry.smc_params(V)
    without = _fly_run(435, params, None)
    with_ff = _fly_run(435, params, FF)
    assert without["residual_swing_rad"] > 0.05
    assert with_ff["residual_swing_rad"] < 0.045
    assert with_ff["failure"] == ""


def test_a_large_initial_swing_on_slow_motors_no_longer_ends_at_the_watchdog() -> None:
    """Sweep run 7 (0.36 kg vehicle, 35 ms motors, noise x1.9, initial swing 0.136 rad): the paper's poles with each
    axis clipped alone swing past the watchdog (0.8 rad); the row's law and filter fly it within every bound."""
    before = replace(registry.smc_params(V), gains=smc.Gains.from_poles(rho_F=registry.RHO_F), shared_roll_pitch=False)
    assert _fly_run(7, before, None)["failure"] == "swing_watchdog"
    now = _fly_run(7, registry.smc_params(V), registry.filter_tuning("smc"))  # type: ignore[arg-type]
    assert now["failure"] == ""
    assert now["peak_swing_rad"] < 0.5


def test_the_attitude_level_row_feeds_the_external_acceleration_forward_and_rejects_the_gust_better() -> None:
    """``smc-attitude``'s row flies the filter with the external acceleration fed forward, as ``smc``'s does: on
    ``slung compare --scenario gust`` (1 N on the vehicle for 1 s, the filter on px4-typical sensors, PX4's attitude
    loops in process) its swing after the gust and its tracking error fall against the filter's default tuning
    (6 Dec 2026: residual swing 0.183 -> 0.041 rad, tracking RMS 0.46 -> 0.12 m)."""
    from offboard.harness import compare

    assert registry.filter_tuning("smc-attitude") == FF and registry.filter_tuning("smc-attitude", "truth") is None
    case = compare.cases("gust")[0]
    cfg, _ = compare.controller_as_flown("smc-attitude", V, SimConfig(estimator="kf", sensors="px4-typical"))
    params = smc.ControllerParams.for_vehicle(V)
    figures = {}
    for name, tuning in (("ff", FF), ("default", None)):
        _, law = compare.controller_as_flown("smc-attitude", V, SimConfig(estimator="kf", sensors="px4-typical"))
        log = sim.run(case.scenario, V, params, cfg, controller=law, tuning=tuning, command_lag=True)
        figures[name] = compare.case_figures(case, log)
    a, b = figures["ff"], figures["default"]
    assert a["residual_swing_rad"] < 0.5 * b["residual_swing_rad"], (a, b)
    assert a["tracking_rms_m"] < 0.5 * b["tracking_rms_m"], (a, b)
