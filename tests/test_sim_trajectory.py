"""``slung sim --trajectory FILE``: a trajectory file simulated before it is flown (vehicle at rest at the
reference's start, heading included, no disturbance), with the pre-flight feasibility check's findings printed
as warnings (a simulation never refuses)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from offboard.cli import main

TURN = """
[[waypoint]]
t = 0.0
x = 1.0
y = 2.0
z = 1.5
psi_deg = 30
[[waypoint]]
t = 6.0
x = 2.0
y = 2.5
z = 1.5
psi_deg = 60
"""
HOP = "[[waypoint]]\nt = 0.0\nx = 0.0\ny = 0.0\nz = 1.0\n[[waypoint]]\nt = 1.5\nx = 0.3\ny = 0.1\nz = 1.1\n"


def test_a_trajectory_file_is_simulated_from_rest_at_its_start(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    traj = tmp_path / "turn.toml"
    traj.write_text(TURN, encoding="utf-8")
    assert main(["sim", "--trajectory", str(traj), "--no-figures", "--out", str(tmp_path / "s")]) == 0
    m = json.loads((tmp_path / "s" / "metrics.json").read_text())
    assert m["scenario"] == "trajectory:turn.toml" and m["duration_s"] == pytest.approx(6.0)
    # tracked from the first instant: the plant started at the reference's position and heading (30 deg)
    assert m["max"]["e_Fx"] < 0.005 and m["max"]["e_Fy"] < 0.005 and m["max"]["e_psi"] < 0.005
    assert "feasibility check" not in capsys.readouterr().err  # a gentle move: nothing to warn about


def test_an_infeasible_trajectory_is_simulated_with_the_checks_findings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    traj = tmp_path / "hop.toml"
    traj.write_text(HOP, encoding="utf-8")
    assert main(["sim", "--trajectory", str(traj), "--no-figures", "--out", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err
    assert "feasibility check: infeasible: pitch torque" in err
    m = json.loads((tmp_path / "s" / "metrics.json").read_text())
    assert m["control"]["tau_max"] >= 0.8  # the controller hits the torque limit the check named


def test_scenario_and_trajectory_are_exclusive_and_a_missing_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["sim", "--scenario", "hover", "--trajectory", "x.toml", "--out", str(tmp_path / "a")])
    assert exc.value.code == 2
    assert main(["sim", "--trajectory", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("slung sim: error:") and "missing.toml" in err[-1]
