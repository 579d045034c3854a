"""slung sweep: the batched path equals the scalar one, a resumed sweep gives the same table, Dask gives the
same results as one process, and the file's errors are one-line UserErrors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from sweep_helpers import assert_engines_write_the_same_table
from sweep_helpers import short_file as _short_file

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.controllers import registry
from offboard.control.controllers.sliding_mode import SlidingModeController
from offboard.harness import batched, sim, sweep
from offboard.harness.sweep_cli import execute
from offboard.logs.runlog import SimConfig

V = Vehicle()


def _drawn_runs(cfg: sweep.SweepConfig) -> tuple[list, list, list, list, list[int]]:
    """Runs 0-2 of the file: their draws, true vehicles, scenarios, sensor presets and sensor seeds."""
    draws = [sweep.draw(cfg, r, V) for r in range(3)]
    vehicles = [sweep.plant_vehicle(V, d) for d in draws]
    scs = [sweep.scenario(cfg, d) for d in draws]
    presets = [sweep.sensor_preset(cfg, d) for d in draws]
    return draws, vehicles, scs, presets, [int(d["sensor_seed"]) for d in draws]


@pytest.mark.parametrize("switching", ["sign", "smooth"])
def test_batched_path_equals_the_scalar_path(tmp_path: Path, switching: str) -> None:
    """Three drawn runs (different masses, cable lengths, inertia, gusts and initial swings) advanced together
    give the trajectories of ``offboard.harness.sim.run`` on each (true state, ideal actuators) to 1e-9."""
    cfg = sweep.load_config(_short_file(tmp_path))
    params = smc.ControllerParams.for_vehicle(V, switching=switching)
    draws = [sweep.draw(cfg, r, V) for r in range(3)]
    vehicles = [sweep.plant_vehicle(V, d) for d in draws]
    assert len({v.cable_length for v in vehicles}) == 3
    scs = [sweep.scenario(cfg, d) for d in draws]
    log = batched.simulate(scs, vehicles, params)
    for b in range(3):
        ref = sim.run(scs[b], vehicles[b], params, SimConfig())
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(log["alpha"][:, b], ref.column("alpha"), rtol=0.0, atol=1e-9)
        assert ref.column("alpha").max() > 0.05  # the runs swing: the comparison is not of two resting states


def test_batched_path_with_drag_equals_the_scalar_path(tmp_path: Path) -> None:
    """Three drawn runs on vehicles with still-air drag (each its own SIH_KDV / SIH_KDW, one without) advanced
    together: the trajectories of ``offboard.harness.sim.run`` on each, to 1e-9, and the drag is felt."""
    from dataclasses import replace

    cfg = sweep.load_config(_short_file(tmp_path))
    params = smc.ControllerParams.for_vehicle(V)
    draws = [sweep.draw(cfg, r, V) for r in range(3)]
    drags = ((1.0, 0.025), (0.0, 0.0), (0.4, 0.0))
    vehicles = [replace(sweep.plant_vehicle(V, d), linear_drag=k, angular_drag=kw) for d, (k, kw) in zip(draws, drags)]
    scs = [sweep.scenario(cfg, d) for d in draws]
    log = batched.simulate(scs, vehicles, params)
    for b in range(3):
        ref = sim.run(scs[b], vehicles[b], params, SimConfig())
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
    calm = sim.run(scs[0], replace(vehicles[0], linear_drag=0.0, angular_drag=0.0), params, SimConfig())
    assert np.abs(calm.data[:, 1:19] - log["x"][:, :, 0]).max() > 1e-3  # the first run's drag changed its flight


def test_batched_path_with_the_filter_equals_the_scalar_path(tmp_path: Path) -> None:
    """Three drawn runs with the Kalman filter on their drawn sensors (noise, latency: records late past the
    filter's horizon are dropped) and the mixer with their drawn motor lags, advanced together: the plant's
    trajectories and the estimates' errors of ``offboard.harness.sim.run`` on each, to 1e-9."""
    cfg = sweep.load_config(_short_file(tmp_path, estimator="kf", move=1.0, hold=0.5))
    params = registry.smc_params(V)
    draws, vehicles, scs, presets, seeds = _drawn_runs(cfg)
    assert max(d["sensor_latency_s"] for d in draws) > 0.006  # past the 12 ms horizon for the 6 ms positions
    assert len({v.motor_time_constant for v in vehicles}) == 3
    log = batched.simulate(
        scs, vehicles, params, estimator="kf", actuators="mixer", sensors=presets, seeds=seeds, load_sensor=True
    )
    for b in range(3):
        sim_cfg = SimConfig(estimator="kf", sensors=cfg.sensors, actuators="mixer", seed=seeds[b])
        law = SlidingModeController(params)
        ref = sim.run(
            scs[b],
            vehicles[b],
            smc.ControllerParams.for_vehicle(V),
            sim_cfg,
            controller=law,
            sensor_preset=presets[b],
            command_lag=True,
        )
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        for col in ("est_Fx0", "est_Fy0"):  # the filter's estimate, not only the plant it steers
            np.testing.assert_allclose(log[col][:, b], ref.column(col), rtol=0.0, atol=1e-9)
        assert np.abs(ref.column("est_Fx0")).max() > 1e-3  # a real estimate, not the true state
        assert ref.column("alpha").max() > 0.05


@pytest.mark.parametrize("law", ["cascade", "zv", "zvd", "swing-feedback", "lqr"])
def test_batched_baselines_with_the_filter_equal_the_scalar_path(tmp_path: Path, law: str) -> None:
    """The baselines (the stock cascade, its shaped and swing-feedback rows, LQR) over three drawn runs with the
    filter, the drawn sensors and the mixer, advanced together: the plant's trajectories and the estimates of
    ``offboard.harness.sim.run`` flying the registry's controller on each, to 1e-9."""
    cfg = sweep.load_config(_short_file(tmp_path, estimator="kf", move=4.0, hold=0.5))
    params = registry.smc_params(V)
    _, vehicles, scs, presets, seeds = _drawn_runs(cfg)
    log = batched.simulate(
        scs, vehicles, params, estimator="kf", actuators="mixer", sensors=presets, seeds=seeds, law=law
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
        )
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(log["est_Fx0"][:, b], ref.column("est_Fx0"), rtol=0.0, atol=1e-9)
        assert ref.column("alpha").max() > 0.1  # the load swings in the move
    with pytest.raises(ValueError, match="smc-attitude"):
        batched.simulate(scs, vehicles, params, law="smc-attitude")


@pytest.mark.parametrize("controller", ["smc", "cascade"])
def test_batched_sweep_gives_the_scalar_sweeps_table(tmp_path: Path, controller: str) -> None:
    """``slung sweep`` with the batched engine (filter, mixer) writes the scalar engine's table: the same verdicts,
    the same figures to 1e-9."""
    assert_engines_write_the_same_table(tmp_path, controller, ("scalar", "batched"))


def _table(out: Path) -> list[str]:
    return (out / "results.csv").read_text(encoding="utf-8").splitlines()


def test_interrupted_and_resumed_sweep_gives_the_same_table(tmp_path: Path) -> None:
    f = _short_file(tmp_path)
    whole = tmp_path / "whole"
    execute(3, ["smc", "cascade"], whole, file=str(f), workers=0, chunk=1, figures=False, progress=False)
    cut = tmp_path / "cut"
    with pytest.raises(KeyboardInterrupt):
        execute(
            3,
            ["smc", "cascade"],
            cut,
            file=str(f),
            workers=0,
            chunk=1,
            figures=False,
            progress=False,
            stop_after_chunks=3,
        )
    assert len(_table(cut)) == 1 + 3  # three chunks of one were kept
    # a kill in the middle of a write leaves half a line: it is dropped and its run flown again
    with open(cut / "results.csv", "a", encoding="utf-8") as fh:
        fh.write("1,cascade,0.5")
    s = execute(3, ["smc", "cascade"], cut, file=str(f), workers=0, chunk=1, figures=False, progress=False)
    assert s["this_invocation"]["resumed_runs"] == 3 and s["this_invocation"]["runs"] == 3
    assert _table(cut) == _table(whole)
    summary = json.loads((cut / "summary.json").read_text())
    for c in ("smc", "cascade"):
        assert summary[c]["runs"] == 3 and 0.0 <= summary[c]["success_rate"] <= 1.0
    assert summary["sim_seconds_per_wall_second"] > 0
    with pytest.raises(UserError):  # another configuration into the same folder is refused
        execute(3, ["smc"], cut, file=str(f), engine="batched", workers=0, figures=False, progress=False)


@pytest.mark.slow
def test_two_worker_dask_cluster_gives_the_results_of_one_process(tmp_path: Path) -> None:
    f = _short_file(tmp_path)
    one, two = tmp_path / "one", tmp_path / "two"
    execute(2, ["smc", "lqr"], one, file=str(f), workers=0, chunk=1, figures=False, progress=False)
    s = execute(2, ["smc", "lqr"], two, file=str(f), workers=2, chunk=1, figures=True, progress=False)
    assert _table(one) == _table(two)
    assert s["scheduler"].startswith("local cluster")
    assert (two / "sweep_success.png").stat().st_size > 1000
    assert "Plotly.newPlot" in (two / "report.html").read_text(encoding="utf-8")


@pytest.mark.slow
def test_two_worker_dask_cluster_with_the_batched_engine_gives_the_results_of_one_process(tmp_path: Path) -> None:
    """The batched engine (the filter and the mixer): chunks of 2 runs on two workers write the table of
    one chunk of 4 in this process (a run's result does not depend on its batch)."""
    f = _short_file(tmp_path, engine="batched", estimator="kf", move=1.0, hold=0.5)
    one, two = tmp_path / "one", tmp_path / "two"
    execute(4, ["smc"], one, file=str(f), workers=0, figures=False, progress=False)
    s = execute(4, ["smc"], two, file=str(f), workers=2, chunk=2, figures=False, progress=False)
    assert s["engine_by_controller"] == {"smc": "batched"}
    assert _table(one) == _table(two)


def test_sweep_file_errors_are_user_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    for text, word in (
        ("[parameters]\nwingspan = {low = 1, high = 2}\n", "wingspan"),
        ("[parameters]\nmass_load = {relative = 1.5}\n", "relative"),
        ("[parameters]\ngust_n = {relative = 0.1}\n", "nominal"),
        ("[success]\nmax_swing_rad = -1\n", "max_swing_rad"),
        ("[run]\nengine = 'gpu'\n", "engine"),
        ("[run\n", "sweep file"),
    ):
        bad.write_text(text, encoding="utf-8")
        with pytest.raises(UserError, match=word):
            sweep.load_config(bad)
    with pytest.raises(UserError, match="cannot read"):
        sweep.load_config(tmp_path / "missing.toml")


def test_sweep_says_when_the_files_move_is_beyond_the_vehicle(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The file's move is checked before the runs (``offboard.control.feasibility``, as ``slung sim`` checks its
    reference): 3 m in 1 s asks the paper's vehicle for more swing, tilt and thrust than it has, which the sweep says
    on stderr and records in the summary, and still flies; the default 4 s move passes without a word."""
    for move, hold, feasible in ((1.0, 0.5, False), (4.0, 0.2, True)):
        (tmp_path / str(move)).mkdir()
        f = _short_file(tmp_path / str(move), engine="scalar", estimator="truth", move=move, hold=hold)
        out = tmp_path / str(move) / "out"
        s = execute(1, ["cascade"], out, file=str(f), workers=0, figures=False, progress=False)
        err = capsys.readouterr().err
        said = [ln for ln in err.splitlines() if ln.startswith("feasibility check of the file's move")]
        summary = json.loads((out / "summary.json").read_text())
        assert s["reference_feasibility"]["feasible"] is feasible
        assert summary["reference_feasibility"] == s["reference_feasibility"]
        assert len(said) == len(summary["reference_feasibility"]["messages"])
        if feasible:
            assert said == []
        else:
            assert any("infeasible: swing" in ln for ln in said) and any("thrust" in ln for ln in said)
        assert s["this_invocation"]["runs"] == 1  # flown all the same


def test_draws_depend_on_the_run_only_and_cover_the_ranges() -> None:
    cfg = sweep.load_config(None)
    a = [sweep.draw(cfg, r, V) for r in range(200)]
    assert a[7] == sweep.draw(cfg, 7, V)  # a pure function of (seed, run)
    masses = np.array([d["mass_vehicle"] for d in a])
    assert masses.min() >= 0.7 * V.mass_vehicle - 1e-12 and masses.max() <= 1.3 * V.mass_vehicle + 1e-12
    assert masses.max() - masses.min() > 0.45 * V.mass_vehicle  # spread over most of +-30 %
    lat = np.array([d["sensor_latency_s"] for d in a])
    assert lat.min() >= 0.0 and lat.max() <= 0.02


def test_the_sweep_report_html_holds_the_success_rates_per_bin(tmp_path: Path) -> None:
    """report.html of a sweep (issue 14: every sim, fly, demo, replay, compare and sweep run writes one): the figure's
    data are the success rates and worst swings per parameter bin of a known table, and the page is self-contained."""
    from offboard.harness.sweep import PARAMETERS
    from offboard.report.sweep_report import sweep_figure, write_html

    def row(c: str, k: int, mass: float, ok: bool, swing: float) -> dict[str, str]:
        r = {n: "1.0" for n in PARAMETERS}
        r.update(controller=c, run=str(k), mass_vehicle=repr(mass), success="1" if ok else "0")
        r.update(residual_swing_rad=repr(swing), tracking_rms_m="0.1")
        return r

    # masses 0.3 .. 0.8 kg in six equal bins (one run per bin and controller): "a" fails in the lightest two bins
    masses = [0.3, 0.4, 0.5, 0.6, 0.7, 0.8]
    table = [row("a", k, m, k >= 2, 0.01 * (k + 1)) for k, m in enumerate(masses)]
    table += [row("b", k, m, True, 0.002) for k, m in enumerate(masses)]
    fig = sweep_figure(table, ["a", "b"])
    success = [tr for tr in fig.data if tr.type == "scatter" and tr.xaxis == "x"]  # row 1, column 1: mass
    assert [tr.name for tr in success] == ["a", "b"]
    assert list(success[0].y) == [0.0, 0.0, 1.0, 1.0, 1.0, 1.0] and list(success[1].y) == [1.0] * 6
    worst = [tr for tr in fig.data if tr.type == "scatter" and tr.xaxis == "x2"]
    assert np.allclose(list(worst[0].y), [0.01 * (k + 1) for k in range(6)])
    assert np.allclose(success[0].x, [0.3 + 0.5 / 12 * (2 * k + 1) for k in range(6)])
    summary = {"controllers": {"a": {"runs": 6, "success_rate": 4 / 6}, "b": {"runs": 6, "success_rate": 1.0}}}
    page = write_html(tmp_path, table, ["a", "b"], summary).read_text(encoding="utf-8")
    assert "a: 6 runs, b: 6 runs" in page and "slung-sweep" in page and "0.666667" in page
    # self-contained: plotly inlined, nothing fetched from the network
    assert "<script src=" not in page and "<link" not in page and "Plotly.newPlot" in page


@pytest.mark.parametrize("law", ["cascade", "zvd", "swing-feedback", "lqr"])
def test_batched_baselines_give_the_scalar_commands_and_hover_on_a_non_finite_estimate(law: str) -> None:
    """The batched baselines' commands against the registry's scalar controllers fed the same estimates, tick by
    tick (no plant between them): equal to 1e-12, and a run whose estimate turns NaN for a tick gets the hover
    command while the others fly on, then resumes with the memory it had, as the scalar law does."""
    from estimators.model.control_state import ControlState
    from offboard.control.scenarios import make_scenario
    from offboard.harness.batched import batched_law

    rng = np.random.default_rng(7)
    reference = make_scenario("rest-to-rest").reference
    batch, shaper = batched_law(law, V, 3)
    scalars = [registry.make(law, V) for _ in range(3)]
    for tick in range(60):
        t = 0.02 * tick
        states = []
        for b in range(3):
            fx = tuple(rng.normal(0.0, 0.3, 6))
            fy = tuple(rng.normal(0.0, 0.3, 6))
            rest = tuple(rng.normal(0.0, 0.05, 12))
            if b == 1 and tick == 30:
                rest = (math.nan, *rest[1:])
            states.append(ControlState(fx, fy, *rest))
        est = {
            "fx": np.array([s.fx for s in states]).T,
            "fy": np.array([s.fy for s in states]).T,
            **{n: np.array([getattr(s, n) for s in states]) for n in ControlState._fields[2:]},
        }
        ref = reference.sample(t)
        want = [c.step(t, s, ref.fx, ref.fy, ref.z, ref.psi) for c, s in zip(scalars, states)]
        refs = (ref.fx, ref.fy, ref.z, ref.psi) if shaper is None else shaper(t, ref.fx, ref.fy, ref.z, ref.psi)
        u, _ = batch(t, est, *refs)
        for b, w in enumerate(want):
            np.testing.assert_allclose(u[:, b], (w.thrust, w.tau_phi, w.tau_theta, w.tau_psi), rtol=0, atol=1e-12)
        if tick == 30:
            assert u[0, 1] == V.hover_thrust and not u[1:, 1].any()
