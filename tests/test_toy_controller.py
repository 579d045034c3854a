"""A new controller is one module plus one registry line (issue 35): the toy controller of ``tests/toy_controller.py``
(a PD on the vehicle's position with swing following, to an attitude setpoint and thrust), registered at run time
with one call of ``registry.register`` and no edit of the product, flies through ``slung sim``, ``fly`` (against
the bundled emulator, lockstep), ``demo``, ``replay``, ``compare`` and ``sweep`` (the scalar engine: the compiled one
has no kernel for it), each run naming it in its outputs and bringing the load where it was asked to go."""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from toy_controller import NAME, make_toy

from offboard.cli import main
from offboard.control.controllers import registry
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, free_udp_port
from offboard.logs.timeseries_file import read_table

#: a gentle 2 m move along x at 1 m height in 4 s, from rest at t = 1 s to rest at t = 5 s (gentle: the toy PD is no
#: swing-damping law, and slung fly's watchdog ends a flight at 0.8 rad of swing)
MOVE = """\
waypoint = [
    {t = 0.0, x = 0.0, y = 0.0, z = 1.0},
    {t = 1.0, x = 0.0, y = 0.0, z = 1.0},
    {t = 5.0, x = 2.0, y = 0.0, z = 1.0},
]
"""


@pytest.fixture(scope="module", autouse=True)
def toy_registered() -> Iterator[None]:
    registry.register(NAME, make_toy)  # the one registry line
    yield
    del registry.CONTROLLERS[NAME]


@pytest.fixture()
def move_file(tmp_path: Path) -> Path:
    path = tmp_path / "move.toml"
    path.write_text(MOVE, encoding="utf-8")
    return path


def _final_load_x(folder: Path, table: str = "timeseries") -> tuple[float, float]:
    """The load's last x position (m) and its reference, from a run folder's time series."""
    t = read_table(folder / f"{table}.slts")
    return float(t["load_x"][-1]), float(t["Fx_ref"][-1])


def test_sim_flies_the_toy_to_the_goal(tmp_path: Path, move_file: Path) -> None:
    out = tmp_path / "sim"
    code = main(["sim", "--trajectory", str(move_file), "--duration", "9", "--controller", NAME, "--no-figures",
                 "--out", str(out)])  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert code == 0 and m["completed"]
    assert m["config"]["controller"] == NAME
    assert m["config"]["actuators"] == "px4-attitude"  # an attitude-level controller flies through PX4's loops
    load_x, ref_x = _final_load_x(out)
    assert ref_x == pytest.approx(2.0) and abs(load_x - 2.0) < 0.05, load_x  # 4 s after the move, at the goal
    # a toy, no swing-damping law (0.32 rad at the stop on 7 Dec 2026), but within slung fly's 0.8 rad watchdog
    assert m["max"]["alpha"] < 0.5, m["max"]


def test_fly_flies_the_toy_over_mavlink_and_replay_reruns_it(tmp_path: Path, move_file: Path) -> None:
    port = free_udp_port()
    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(["--connect", f"udpin:127.0.0.1:{port}", "--lockstep", "--trajectory", str(move_file),
                         "--duration", "7", "--settle", "0", "--controller", NAME, "--no-figures",
                         "--out", str(tmp_path / "fly")])  # fmt: skip
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004).start()
    try:
        m, folder = fly(args, lockstep=True, truth_probe=emu.truth, quiet=True)
    finally:
        emu.stop()
    cfg = json.loads((folder / "metrics.json").read_text())["config"]
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    assert cfg["controller"] == NAME and cfg["law"] == "attitude"
    load_x, ref_x = _final_load_x(folder)  # the emulator's true plant, in the flight's coordinates
    assert ref_x > 1.9 and abs(load_x - ref_x) < 0.1, (load_x, ref_x)
    # the replay re-runs the toy on the log: every setpoint and estimate the live loop had, bit for bit
    code = main(["replay", str(folder / "flight.tlog"), "--no-figures", "--out", str(tmp_path / "r")])
    rm = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert code == 0 and rm["config"]["controller"] == NAME
    agree = rm["live_agreement"]
    assert agree["setpoint_identical"] == agree["estimate_identical"] == m["loop"]["ticks"], agree
    # and another controller re-run on the same log sends other setpoints
    assert main(["replay", str(folder / "flight.tlog"), "--controller", "smc", "--no-figures",
                 "--out", str(tmp_path / "r2")]) == 0  # fmt: skip
    other = json.loads((tmp_path / "r2" / "metrics.json").read_text())
    assert other["config"]["controller"] == "smc"
    assert other["live_agreement"]["setpoint_identical"] < agree["setpoint_identical"] / 2, other["live_agreement"]


def test_demo_flies_the_toy(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    code = main(["demo", "--controller", NAME, "--scenario", "hover", "--duration", "3", "--disturbance", "none",
                 "--no-figures", "--out", str(out)])  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert code == 0 and m["config"]["controller"] == NAME
    assert m["rms"]["e_Fx"] < 0.1 and m["rms"]["e_z"] < 0.1, m["rms"]  # the emulator's true load held in place


def test_a_controller_that_cannot_fly_the_output_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["fly", "--connect", "udpin:127.0.0.1:9", "--scenario", "hover", "--out", str(tmp_path / "f")]
    assert main([*base, "--controller", NAME, "--output", "actuator"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "commands attitude and thrust: use --output attitude" in err, err
    assert main([*base, "--controller", "no-such-law"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown controller 'no-such-law'" in err and NAME in err, err
    assert main([*base, "--controller", NAME, "--law", "torque"]) == 2  # --law is the sliding-mode law's
    assert "not with --controller toy-pd" in capsys.readouterr().err
    sim = ["sim", "--scenario", "hover", "--controller", NAME, "--motor-lag", "--out", str(tmp_path / "s")]
    assert main(sim) == 2  # --motor-lag configures the sliding-mode law only
    assert "not with --controller toy-pd" in capsys.readouterr().err


def test_compare_and_sweep_fly_the_toy(tmp_path: Path) -> None:
    out = tmp_path / "compare"
    assert main(["compare", "--scenario", "gust", "--controllers", NAME, "--no-figures", "--out", str(out)]) == 0
    row = json.loads((out / "compare.json").read_text())[NAME]
    assert row["completed"] and row["tracking_max_m"] < 1.0, row  # the gust pushed it 0.45 m off on 7 Dec 2026
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text('[run]\nmove_time_s = 2.0\ndistance_m = 1.0\nhold_s = 2.0\nengine = "compiled"\n')
    out = tmp_path / "sweep"
    assert main(["sweep", "--file", str(sweep_file), "--runs", "2", "--controllers", NAME, "--workers", "0",
                 "--no-figures", "--out", str(out)]) == 0  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    assert summary["engine_by_controller"] == {NAME: "scalar"}  # the compiled engine has no kernel for it
    done = summary["controllers"][NAME]
    assert done["runs"] == 2 and done["success_rate"] == 1.0, done  # within the default success criteria
    rows = (out / "results.csv").read_text().splitlines()
    assert [r.split(",")[1] for r in rows[1:]] == [NAME, NAME], rows  # the controller's name in the table
