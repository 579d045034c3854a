"""The compiled sweep engine (``offboard.harness.compiled``) against the scalar path (``offboard.harness.sim.run``):
drawn runs of the default sweep file flown by machine code give the scalar path's trajectories and estimates to
1e-9, for every controller the engine flies, and ``slung sweep --engine compiled`` writes the scalar engine's
table. (The component kernels have their own tests: ``test_compiled_plant``, ``_kf``, ``_laws``, ``_schedule``.)"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from sweep_helpers import assert_engines_write_the_same_table, short_file

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.controllers import registry
from offboard.harness import sim, sweep
from offboard.harness.compiled import engine
from offboard.harness.compiled import inputs as cin
from offboard.harness.sweep_cli import execute
from offboard.logs.runlog import SimConfig

V = Vehicle()


def _short_file(tmp_path: Path, engine: str = "compiled", estimator: str = "kf", move: float = 1.0, hold: float = 0.5):
    """The default distribution, short, the compiled engine and the filter unless told otherwise."""
    return short_file(tmp_path, engine, estimator, move, hold, gust_start=(0.5, 2.0))


def _drawn(cfg: sweep.SweepConfig, n: int = 3) -> tuple[list, list, list, list[int]]:
    """Runs 0..n-1 of the file: true vehicles, scenarios, sensor presets, sensor seeds."""
    draws = [sweep.draw(cfg, r, V) for r in range(n)]
    return (
        [sweep.plant_vehicle(V, d) for d in draws],
        [sweep.scenario(cfg, d) for d in draws],
        [sweep.sensor_preset(cfg, d) for d in draws],
        [int(d["sensor_seed"]) for d in draws],
    )


@pytest.mark.parametrize("switching", ["sign", "smooth"])
def test_true_state_runs_equal_the_scalar_path(tmp_path: Path, switching: str) -> None:
    """The true state into the law, ideal actuators: three drawn runs (masses, cable lengths, inertia, gusts,
    initial swings) fly the scalar path's trajectories to 1e-9; one on a vehicle with still-air drag."""
    cfg = sweep.load_config(_short_file(tmp_path, estimator="truth", move=2.0, hold=1.0))
    params = smc.ControllerParams.for_vehicle(V, switching=switching)
    vehicles, scs, _, _ = _drawn(cfg)
    vehicles[2] = replace(vehicles[2], linear_drag=0.8, angular_drag=0.02)
    log = engine.simulate(scs, vehicles, params)
    for b in range(3):
        ref = sim.run(scs[b], vehicles[b], params, SimConfig())
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(log["alpha"][:, b], ref.column("alpha"), rtol=0.0, atol=1e-9)
        assert ref.column("alpha").max() > 0.05  # the runs swing: not a comparison of two resting states


@pytest.mark.parametrize("law", ["smc", "cascade", "zvd", "swing-feedback", "lqr"])
def test_runs_with_the_filter_and_the_mixer_equal_the_scalar_path(tmp_path: Path, law: str) -> None:
    """The sweep's default setting: the measured-input Kalman filter on each run's drawn sensors (noise, latency:
    late records dropped), the mixer with each run's motor lag, the command into the filter through the nominal
    motor lag. Three drawn runs: the scalar path's plant trajectories and estimates to 1e-9, for every row."""
    cfg = sweep.load_config(_short_file(tmp_path, move=2.0 if law != "smc" else 1.0))
    params = registry.smc_params(V)
    vehicles, scs, presets, seeds = _drawn(cfg)
    assert len({v.motor_time_constant for v in vehicles}) == 3
    log = engine.simulate(
        scs,
        vehicles,
        params,
        estimator="kf",
        actuators="mixer",
        sensors=presets,
        seeds=seeds,
        tuning=registry.filter_tuning(law),
        law=law,
    )
    for b in range(3):
        sim_cfg = SimConfig(estimator="kf", sensors=cfg.sensors, actuators="mixer", seed=seeds[b])
        ref = sim.run(
            scs[b],
            vehicles[b],
            params,
            sim_cfg,
            controller=registry.make(law, V),
            sensor_preset=presets[b],
            command_lag=True,
            tuning=registry.filter_tuning(law),
        )
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        for col in ("est_Fx0", "est_Fy0"):  # the filter's estimate, not only the plant it steers
            np.testing.assert_allclose(log[col][:, b], ref.column(col), rtol=0.0, atol=1e-9)
        assert np.abs(ref.column("est_Fx0")).max() > 1e-3  # a real estimate, not the true state
        assert ref.column("alpha").max() > 0.05


def test_figures_without_a_log_equal_the_figures_of_the_logged_run(tmp_path: Path) -> None:
    """A sweep flies without a log (``log_every = 0``), and its kernel then skips the swing angle's atan2 and the
    estimate error's hypot where they cannot be a new largest: the figures are those of the same runs flown with
    the log (every tick's angle taken) bit for bit, and the peak and residual are the logged angle's maxima."""
    f = _short_file(tmp_path, move=4.0, hold=3.0)
    # no initial swing: the largest swing then grows during the move, tick after tick (the case the skip must get)
    f.write_text(f.read_text().replace("high = 0.15}", "high = 0.0}"), encoding="utf-8")
    cfg = sweep.load_config(f)
    vehicles, scs, presets, seeds = _drawn(cfg)
    kw = dict(estimator="kf", actuators="mixer", sensors=presets, seeds=seeds, law="smc")
    logged = engine.simulate(scs, vehicles, registry.smc_params(V), log_every=1, **kw)
    bare = engine.simulate(scs, vehicles, registry.smc_params(V), log_every=0, **kw)
    np.testing.assert_array_equal(bare["fig"], logged["fig"])
    alpha = logged["alpha"]
    np.testing.assert_array_equal(bare["fig"][:, engine.FIG_PEAK], alpha.max(axis=0))
    assert (np.argmax(alpha, axis=0) > 100).all()  # the peak came mid-move, after a hundred growing ticks
    arrival = scs[0].arrival_time
    after = logged["t"] >= arrival + 2.0
    assert after.any() and not after.all()
    np.testing.assert_array_equal(bare["fig"][:, engine.FIG_RESIDUAL], alpha[after].max(axis=0))
    assert (bare["fig"][:, engine.FIG_EST_ERR] > 0.0).all()


@pytest.mark.parametrize("controller", ["smc", "cascade"])
def test_compiled_sweep_gives_the_scalar_sweeps_table(tmp_path: Path, controller: str) -> None:
    """``slung sweep`` with the compiled engine writes the scalar engine's table: the same verdicts, the same
    figures to 1e-9."""
    assert_engines_write_the_same_table(tmp_path, controller, ("scalar", "compiled"))


@pytest.mark.slow
def test_two_worker_dask_cluster_with_the_compiled_engine_gives_the_results_of_one_process(tmp_path: Path) -> None:
    """Chunks of 2 runs on two Dask workers (each loading the compiled kernels) write the table of one chunk of 4 in
    this process, for the sliding-mode law and a baseline."""
    f = _short_file(tmp_path)
    one, two = tmp_path / "one", tmp_path / "two"
    execute(4, ["smc", "lqr"], one, file=str(f), workers=0, figures=False, progress=False)
    s = execute(4, ["smc", "lqr"], two, file=str(f), workers=2, chunk=2, figures=False, progress=False)
    assert s["engine_by_controller"] == {"smc": "compiled", "lqr": "compiled"}
    assert (one / "results.csv").read_text(encoding="utf-8") == (two / "results.csv").read_text(encoding="utf-8")


def test_the_compiled_engine_flies_every_row_and_the_scalar_engine_is_the_scalar_path(tmp_path: Path) -> None:
    """The compiled engine flies every row (``smc-attitude``: ``tests/test_compiled_attitude.py``), the scalar one
    none; the attitude-level law flies only through PX4's attitude loops; the engines are these two (the numpy
    batched path is gone: a file naming it gets one line naming the engines)."""
    cfg = sweep.load_config(_short_file(tmp_path))
    assert {sweep.engine_for(cfg, c) for c in registry.CONTROLLERS} == {"compiled"}
    scalar_cfg = sweep.load_config(_short_file(tmp_path, engine="scalar"))
    assert {sweep.engine_for(scalar_cfg, c) for c in registry.CONTROLLERS} == {"scalar"}
    assert sweep.ENGINES == ("scalar", "compiled")
    with pytest.raises(UserError, match=r"run\.engine must be one of scalar, compiled, got 'batched'"):
        sweep.load_config(_short_file(tmp_path, engine="batched"))
    with pytest.raises(ValueError, match="'smc-attitude' with actuators px4-attitude"):
        engine.simulate([], [], registry.smc_params(V), law="smc-attitude", actuators="mixer")
    with pytest.raises(ValueError, match="'smc' with actuators ideal or mixer"):
        engine.simulate([], [], registry.smc_params(V), law="smc", actuators="px4-attitude")


def test_a_file_with_actuators_the_fast_engines_do_not_model_is_flown_by_the_scalar_path(tmp_path: Path) -> None:
    """``actuators = "px4"`` (PX4's allocator behind the torque-level law) is the scalar path's alone: with the
    compiled engine in the file the sweep still flies, every row by the scalar path, and says so in its summary,
    where the compiled engine would have raised in the middle of the sweep."""
    for eng in ("compiled",):
        (tmp_path / eng).mkdir()
        f = _short_file(tmp_path / eng, engine=eng)
        text = f.read_text(encoding="utf-8").replace('actuators = "mixer"', 'actuators = "px4"')
        f.write_text(text, encoding="utf-8")
        cfg = sweep.load_config(f)
        assert cfg.actuators == "px4"
        assert {sweep.engine_for(cfg, c) for c in ("smc", "cascade", "smc-attitude")} == {"scalar"}
        s = execute(1, ["smc"], tmp_path / eng / "out", file=str(f), workers=0, figures=False, progress=False)
        assert s["engine_by_controller"] == {"smc": "scalar"} and s["controllers"]["smc"]["runs"] == 1


def test_a_vehicle_without_a_load_is_refused_by_sweep_and_compare_in_one_line(tmp_path: Path) -> None:
    """Sweep and compare judge a load's swing and tracking; without a load (``px4-sih``) the plant swings a massless
    pendulum and every figure means nothing (the compiled engine's filter raised in its warm-up, the scalar
    runs "failed" on that swing): both commands refuse such a vehicle with one
    line naming it, exit 2, no traceback."""
    import subprocess
    import sys

    vehicle = Path(sweep.__file__).parents[2] / "estimators" / "model" / "vehicles" / "px4-sih.toml"
    f = _short_file(tmp_path)
    f.write_text(f.read_text(encoding="utf-8") + f'\n[vehicle]\nfile = "{vehicle}"\n', encoding="utf-8")
    with pytest.raises(UserError, match="'px4-sih' carries no load"):
        sweep.load_config(f)
    for argv in (
        ["sweep", "--runs", "1", "--file", str(f), "--out", str(tmp_path / "s")],
        ["compare", "--scenario", "hover", "--vehicle", "px4-sih", "--out", str(tmp_path / "c")],
    ):
        p = subprocess.run([sys.executable, "-m", "offboard.cli", *argv], capture_output=True, text=True, timeout=120)
        assert p.returncode == 2, p.stderr
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and "carries no load" in lines[0] and "Traceback" not in p.stderr, p.stderr
        assert not (tmp_path / argv[-1]).exists() or not any((tmp_path / argv[-1]).iterdir())


def test_warm_up_loads_the_compiled_engine_only_for_its_rows(tmp_path: Path) -> None:
    """``slung sweep`` loads (or compiles) the kernels in its own process before the Dask workers start: a run of
    each compiled row; nothing for an engine that is not compiled."""
    assert sweep.warm_up(sweep.load_config(_short_file(tmp_path, engine="scalar")), ["smc", "lqr"]) == 0.0
    assert sweep.warm_up(sweep.load_config(_short_file(tmp_path)), ["smc", "lqr"]) > 0.0


def test_only_the_shaped_rows_have_a_reference_of_their_own() -> None:
    """The sweep samples its reference once for every row that flies it unshaped (``inputs.SHAPED_LAWS``): the
    rows whose registry controller really has a shaper in front of it (``ShapedCascade``) are exactly those."""
    for law in cin.COMPILED_LAWS:
        has_shaper = getattr(registry.make(law, V), "shaper", None) is not None
        assert has_shaper == (law in cin.SHAPED_LAWS), law
        assert (cin.law_shaper(law, V) is not None) == has_shaper, law
