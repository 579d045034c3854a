"""slung sweep: a resumed sweep gives the same table, Dask gives the same results as one process, the file's errors
are one-line UserErrors, and the compiled engine flies the drag as the scalar path (the engine's other equalities:
``tests/test_compiled_engine.py``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from sweep_helpers import short_file as _short_file

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.harness import sim, sweep
from offboard.harness.compiled import engine
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


def test_compiled_path_with_drag_equals_the_scalar_path(tmp_path: Path) -> None:
    """Three drawn runs on vehicles with still-air drag (each its own SIH_KDV / SIH_KDW, one without) flown by the
    compiled engine: the trajectories of ``offboard.harness.sim.run`` on each, to 1e-9, and the drag is felt."""
    from dataclasses import replace

    cfg = sweep.load_config(_short_file(tmp_path))
    params = smc.ControllerParams.for_vehicle(V)
    draws = [sweep.draw(cfg, r, V) for r in range(3)]
    drags = ((1.0, 0.025), (0.0, 0.0), (0.4, 0.0))
    vehicles = [replace(sweep.plant_vehicle(V, d), linear_drag=k, angular_drag=kw) for d, (k, kw) in zip(draws, drags)]
    scs = [sweep.scenario(cfg, d) for d in draws]
    log = engine.simulate(scs, vehicles, params)
    for b in range(3):
        ref = sim.run(scs[b], vehicles[b], params, SimConfig())
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
    calm = sim.run(scs[0], replace(vehicles[0], linear_drag=0.0, angular_drag=0.0), params, SimConfig())
    assert np.abs(calm.data[:, 1:19] - log["x"][:, :, 0]).max() > 1e-3  # the first run's drag changed its flight


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
        execute(3, ["smc"], cut, file=str(f), engine="compiled", workers=0, figures=False, progress=False)


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
