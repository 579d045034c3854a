"""The compiled engine's ``smc-attitude`` row against the scalar path: the attitude-level law
(``offboard.control.compiled.attitude_law``) against ``offboard.control.smc_attitude.step``, PX4's attitude path
(``sim_bridge.inner.compiled.px4_loops``) against ``sim_bridge.inner.px4_attitude_path.Px4AttitudePath`` and
Python's ``math.hypot`` (``layout.py_hypot``), each to the last bit on random inputs; then drawn runs of the default
sweep file flown by ``engine.simulate`` equal ``sim.run`` flown as ``sweep.run_one`` flies the row (to 1e-9: the
compiled plant's RK4 step is the scalar one's to a few ulp), and ``slung sweep --engine compiled`` writes the
scalar engine's table."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from sweep_helpers import assert_engines_write_the_same_table, short_file

from estimators.kernels import EST_SIZE, py_hypot
from estimators.model.control_state import ControlState
from estimators.model.vehicle import Vehicle
from offboard.control import smc, smc_attitude
from offboard.control.compiled import attitude_law as cal
from offboard.control.compiled.reference_row import REF_SIZE
from offboard.control.controllers import registry
from offboard.flight.command_mapping import MappingConfig
from offboard.harness import sim, sweep
from offboard.harness.compare import controller_as_flown
from offboard.harness.compiled import engine
from offboard.harness.compiled import inputs as cin
from offboard.logs.runlog import SimConfig
from sim_bridge.inner.compiled import px4_loops as cpx
from sim_bridge.inner.px4_attitude_path import Px4AttitudePath

V = Vehicle()


def _short_file(tmp_path: Path, estimator: str = "kf") -> Path:
    """The default distribution, short (a 1 s move, 0.5 s hold), the compiled engine."""
    return short_file(tmp_path, "compiled", estimator, 1.0, 0.5, gust_start=(0.5, 2.0))


# ---- the parts, on random inputs ------------------------------------------------------------------------------------
def test_py_hypot_is_pythons_hypot_to_the_last_bit() -> None:
    """CPython's ``math.hypot`` (its own algorithm, correctly rounded almost always), which libm's ``hypot``
    (numba's) misses in the last bit about once in a thousand: equal on 200 000 pairs over 16 decades and on the
    special values."""
    rng = np.random.default_rng(1)
    n = 200_000
    a = rng.normal(size=n) * 10.0 ** rng.uniform(-8, 8, size=n)
    b = rng.normal(size=n) * 10.0 ** rng.uniform(-8, 8, size=n)
    ours = np.array([py_hypot(x, y) for x, y in zip(a.tolist(), b.tolist())])
    np.testing.assert_array_equal(ours, [math.hypot(x, y) for x, y in zip(a.tolist(), b.tolist())])
    assert (ours != np.hypot(a, b)).sum() > 50  # the inputs do tell the two algorithms apart
    special = [(0.0, 0.0), (-0.0, 3.0), (3.0, -4.0), (math.inf, math.nan), (math.nan, 1.0), (1e-310, 3e-310)]
    special += [(5e-324, 0.0), (1e308, 1e308), (-math.inf, 2.0)]
    for x, y in special:
        np.testing.assert_array_equal(py_hypot(x, y), math.hypot(x, y))


def _estimate(v: np.ndarray) -> ControlState:
    """The estimate vector (``layout.EST_*``) as the scalar law's ControlState."""
    return ControlState(tuple(v[0:6]), tuple(v[6:12]), *v[12:24])


def _memory(m: smc.ControllerMemory) -> list[float]:
    """The scalar law's memory in the layout of ``attitude_law.AM_*`` (no last step time: NaN)."""
    t = math.nan if m.t is None else m.t
    return [m.int_z, m.int_psi, m.int_fx, m.int_fy, t, m.dist_x, m.dist_y, m.vel_x, m.vel_y]


@pytest.mark.parametrize(("load", "drag"), [(True, False), (False, False), (True, True), (False, True)])
def test_attitude_law_equals_the_scalar_law_to_the_last_bit(load: bool, drag: bool) -> None:
    """3000 ticks of random estimates (small to far off, so the thrust, tilt-rate and tilt limits clip) and
    references at random time steps (some backward), a NaN estimate and an infinite reference among them: every
    command, saturation flag and memory equal ``smc_attitude.step``'s. Without a load the disturbance observer runs
    (its pole set, its bound reached). With the vehicle's drag in the law's model too (SIH's 1 N per m/s)."""
    vehicle = V if load else V.with_changes(mass_load=0.0)
    if drag:
        vehicle = vehicle.with_changes(linear_drag=1.0)
    params = cin.sweep_attitude_params(vehicle)
    assert (cal.attitude_constants(params)[cal.A_DRAG_TILT] > 0.0) == (drag and load)  # the law models it with a load
    if not load:
        params = replace(params, gains=replace(params.gains, wn_d=1.5))
    c, mem = cal.attitude_constants(params), cal.attitude_memory()
    memory = smc.ControllerMemory()
    rng = np.random.default_rng(5)
    u = np.zeros(cal.COMMAND_SIZE)
    t, saturated, hover = 0.0, 0, 0
    for k in range(3000):
        t += rng.uniform(0.0, 0.02) if k % 50 else -0.01
        est = rng.normal(0.0, 0.3, EST_SIZE) * rng.choice([0.1, 1.0, 5.0])
        ref = rng.normal(0.0, 0.3, REF_SIZE)
        est[3] = math.nan if k == 700 else est[3]
        ref[2] = math.inf if k == 900 else ref[2]
        cmd, memory = smc_attitude.step(
            t, _estimate(est), tuple(ref[0:7]), tuple(ref[7:14]), tuple(ref[14:21]), tuple(ref[21:28]), memory, params
        )
        sat = cal.attitude_step(c, mem, t, est, ref, u)
        want = [cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi, cmd.phi_sp, cmd.theta_sp, cmd.psi_sp]
        np.testing.assert_array_equal(u, want, err_msg=f"tick {k}")
        np.testing.assert_array_equal(mem[: cal.AM_EX], _memory(memory), err_msg=f"tick {k}")
        assert sat == cmd.saturated
        saturated += sat
        hover += not cmd.valid
    assert 100 < saturated < 2900 and hover == 2  # the limits clip now and then; the screens met their two ticks
    if not load:
        assert 0.0 < math.hypot(memory.dist_x, memory.dist_y) <= c[cal.A_DIST_MAX] + 1e-12


def test_px4_attitude_path_equals_the_scalar_path_to_the_last_bit() -> None:
    """Twenty runs of 400 plant steps of random plant states under random setpoints (thrusts beyond both limits,
    tilts beyond the mapping's): every wrench equals ``Px4AttitudePath``'s (as ``sim.run`` clips and gives the
    setpoint), and the allocator saturates in some rate-loop periods, not in all."""
    rng = np.random.default_rng(3)
    c = cpx.px4_constants(V, 0.001, MappingConfig().max_tilt)
    max_tilt = c[cpx.PX_MAX_TILT]
    wrench = np.zeros(13)
    periods = saturated = 0
    for _ in range(20):
        path, s = Px4AttitudePath(V, 0.001), cpx.px4_state(0.25 * V.hover_thrust)
        path.reset(0.25 * V.hover_thrust)
        for k in range(400):
            if k % 10 == 0:
                phi, theta, psi = rng.normal(0.0, 0.6, 3)
                thrust = rng.uniform(-2.0, 25.0)
                clip = (min(max(phi, -max_tilt), max_tilt), min(max(theta, -max_tilt), max_tilt))
                path.set_setpoint(*clip, psi, thrust)
                cpx.px4_set_setpoint(c, s, phi, theta, psi, thrust)
            x = rng.normal(0.0, 0.5, 18)
            want = path.step(x)
            cpx.px4_step(c, s, x, wrench)
            np.testing.assert_array_equal(wrench[:4], want)
        np.testing.assert_array_equal(s[cpx.PS_INTEG : cpx.PS_INTEG + 3], path.rate.integ)
        periods += 200
        saturated += s[cpx.PS_N_SATURATED]
    assert 0 < saturated < periods


# ---- whole runs ------------------------------------------------------------------------------------------------------
def _scalar_run(cfg: sweep.SweepConfig, scenario, vehicle: Vehicle, preset, seed: int) -> sim.SimLog:
    """``sim.run`` as ``sweep.run_one`` flies the ``smc-attitude`` row (``controller_as_flown``, the command lag,
    the row's filter tuning)."""
    sensors = cfg.sensors if cfg.estimator == "kf" else None
    base = SimConfig(estimator=cfg.estimator, sensors=sensors, actuators=cfg.actuators, seed=seed)
    sim_cfg, law = controller_as_flown("smc-attitude", V, base)
    assert sim_cfg.actuators == "px4-attitude"
    return sim.run(
        scenario,
        vehicle,
        smc.ControllerParams.for_vehicle(V),
        sim_cfg,
        controller=law,
        sensor_preset=preset,
        command_lag=True,
        tuning=registry.filter_tuning("smc-attitude", cfg.estimator),
    )


@pytest.mark.parametrize("estimator", ["kf", "truth"])
def test_runs_through_px4s_attitude_loops_equal_the_scalar_sweeps(tmp_path: Path, estimator: str) -> None:
    """Three drawn runs (masses, cable lengths, inertia, motor lags, gusts, initial swings; with the filter, the
    drawn sensors): the scalar path's plant trajectories, the filter's estimates and the law's saturated time to
    1e-9. The runs swing, the law clips its tilt and PX4's allocator saturates in each (every path exercised)."""
    cfg = sweep.load_config(_short_file(tmp_path, estimator=estimator))
    draws = [sweep.draw(cfg, r, V) for r in range(3)]
    vehicles = [sweep.plant_vehicle(V, d) for d in draws]
    scs = [sweep.scenario(cfg, d) for d in draws]
    presets = [sweep.sensor_preset(cfg, d) for d in draws]
    seeds = [int(d["sensor_seed"]) for d in draws]
    assert len({v.motor_time_constant for v in vehicles}) == 3
    kw = {"sensors": presets, "seeds": seeds, "tuning": registry.filter_tuning("smc-attitude")}
    log = engine.simulate(
        scs, vehicles, registry.smc_params(V), estimator=estimator, actuators="px4-attitude", law="smc-attitude", **kw
    )
    for b in range(3):
        ref = _scalar_run(cfg, scs[b], vehicles[b], presets[b], seeds[b])
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        for col in ("est_Fx0", "est_Fy0"):  # the filter's estimate errors (zero with the true state)
            np.testing.assert_allclose(log[col][:, b], ref.column(col), rtol=0.0, atol=1e-9)
        assert abs(log["saturated"][b] - ref.column("saturated").sum() * 0.001) < 1e-9
        assert ref.column("alpha").max() > 0.05  # the runs swing: not a comparison of two resting states
        assert log["saturated"][b] > 0.0 and log["allocator_saturated"][b] > 0.0
    if estimator == "kf":
        assert np.abs(log["est_Fx0"]).max() > 1e-3  # a real estimate, not the true state


def test_compiled_sweep_gives_the_scalar_sweeps_table_for_smc_attitude(tmp_path: Path) -> None:
    """``slung sweep`` with the compiled engine flies ``smc-attitude`` itself and writes the scalar engine's table:
    the same verdicts, the same figures to 1e-9."""
    assert_engines_write_the_same_table(tmp_path, "smc-attitude", ("scalar", "compiled"))


@pytest.mark.parametrize("estimator", ["truth", "kf"])
def test_the_compiled_sweep_builds_the_attitude_law_as_the_scalar_sweep(estimator: str) -> None:
    """On a vehicle with drag and a load: the compiled engine's law constants (``inputs.law_arrays``, with the
    tuning the sweep gives the row's filter) are the scalar sweep's law's (``compare.controller_as_flown``), the
    drag in the law's model only where the filter does not feed its external acceleration forward (with it, the
    compiled sweep once counted the drag twice: 4.4 m of tracking error where the scalar flew 0.36)."""
    from estimators.model.vehicle import load_vehicle
    from offboard.harness.compare import controller_as_flown
    from offboard.logs.runlog import SimConfig

    nominal = load_vehicle("px4-hil-load")
    _, law = controller_as_flown("smc-attitude", nominal, SimConfig(actuators="mixer", estimator=estimator))
    tuning = registry.filter_tuning("smc-attitude", estimator)
    _, c, _, _ = cin.law_arrays("smc-attitude", registry.smc_params(nominal), estimator, tuning)
    np.testing.assert_array_equal(c, cal.attitude_constants(law.params))
    assert (c[cal.A_DRAG_TILT] > 0.0) == (estimator == "truth")
