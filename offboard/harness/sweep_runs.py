"""What the compiled engine needs to fly a chunk of a sweep at once: the chunk's runs drawn as the
scalar path draws them one by one (``offboard.harness.sweep.run_one``), and the table's rows from their figures."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from offboard.harness import sweep


@dataclass(frozen=True)
class DrawnRuns:
    """What the compiled engine needs to fly ``runs`` of a sweep at once: each run's draws, true
    vehicle and scenario, the nominal vehicle's law parameters, and the ``simulate`` keywords of the estimator (the
    sensor presets, their seeds and the controller's filter tuning with the filter)."""

    runs: list[int]
    draws: list[dict[str, float]]
    vehicles: list[Any]
    scenarios: list[Any]
    params: Any
    simulate_kw: dict[str, Any]


def drawn_runs(config: sweep.SweepConfig, controller: str, runs: list[int]) -> DrawnRuns:
    """The runs ``runs`` of the file ``config`` for ``controller``, drawn as ``sweep.run_one`` draws them."""
    from estimators.model.vehicle import load_vehicle
    from offboard.control.controllers import registry

    nominal = load_vehicle(config.vehicle_file)
    draws = [sweep.draw(config, r, nominal) for r in runs]
    kw: dict[str, Any] = {"estimator": "truth" if config.estimator == "truth" else "kf"}
    if kw["estimator"] == "kf":
        kw.update(sensors=[sweep.sensor_preset(config, d) for d in draws], seeds=[int(d["sensor_seed"]) for d in draws])
        kw.update(tuning=registry.filter_tuning(controller))
    return DrawnRuns(
        runs,
        draws,
        [sweep.plant_vehicle(nominal, d) for d in draws],
        [sweep.scenario(config, d) for d in draws],
        registry.smc_params(nominal),
        kw,
    )


def batch_rows(
    config: sweep.SweepConfig,
    controller: str,
    drawn: DrawnRuns,
    figures: list[dict[str, Any]],
    sim_s: float,
    wall_s: float,
) -> list[dict[str, Any]]:
    """The table's rows of a batch flown at once: each run's parameters, its ``figures`` (those of
    ``sweep.evaluate``), its verdict, the simulated time ``sim_s`` (s) and the batch's wall time ``wall_s`` (s)
    shared out."""
    rows = []
    for r, d, f in zip(drawn.runs, drawn.draws, figures):
        failure = sweep.verdict(config, f)
        row: dict[str, Any] = {"run": r, "controller": controller}
        row.update({k: d[k] for k in sweep.PARAMETERS})
        row.update(f)
        row.update({"success": failure == "", "failure": failure, "sim_s": sim_s, "wall_s": wall_s / len(drawn.runs)})
        rows.append(row)
    return rows


__all__ = ["DrawnRuns", "batch_rows", "drawn_runs"]
