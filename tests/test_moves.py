"""Moves as a user gives them (`offboard/control/reference_moves.py`, `move_planning.py`, `slung fly --move`): the
smoothed bang-bang's rest-to-rest ends and smoothness, its peak acceleration against 4D/T^2, monotone progress, the
speed limit, the pre-flight planning and its proposal of the fastest feasible time, and the command line's refusals.
Design: docs/references.md, "Moves"."""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from estimators.model.vehicle import load_vehicle
from offboard.control.feasibility import check_reference
from offboard.control.move_planning import TIME_RESOLUTION, plan_move
from offboard.control.reference import TrajectoryError
from offboard.control.reference_moves import Move, move_profile
from offboard.control.trajectory_file import load_trajectory_file
from offboard.flight.fly_move import move_file_text, move_limits

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = load_vehicle("ardupilot-sitl-quad")
LIMITS = move_limits(VEHICLE, argparse.Namespace(output="attitude", mask=None, swing_limit=0.8))


def _derivatives(scalar: Move, ts: np.ndarray, n: int = 8) -> np.ndarray:
    return np.array([scalar.derivatives(float(t), n) for t in ts])


@pytest.mark.parametrize(("ramp", "cruise"), [(0.3, 0.0), (0.75, 0.0), (0.4, 1.0)])
def test_rest_to_rest_ends_and_smoothness(ramp: float, cruise: float) -> None:
    """At rest at both ends (every derivative 1..6 zero there and the value exact), continuous in derivatives 0..6
    across every breakpoint (position C^6 with the order-4 ramps), and each derivative the rate of the one below."""
    shape = move_profile(3.0, ramp, cruise)
    m = Move(1.0, 4.0, 2.0, shape)
    end = 2.0 + 3.0
    for t in (2.0, end):
        d = m.derivatives(t, 7)
        assert d[1:] == pytest.approx((0.0,) * 6, abs=1e-9)
    assert m.derivatives(end)[0] == 4.0 and m.derivatives(2.0)[0] == 1.0
    assert m.derivatives(end + 1.0)[0] == 4.0 and m.derivatives(1.0)[0] == 1.0
    scale = np.abs(_derivatives(m, np.linspace(2.0, end, 601))).max(axis=0)
    for b in m.breakpoints:
        left = np.array(m.derivatives(b - 1e-9, 7))
        right = np.array(m.derivatives(b + 1e-9, 7))
        # a jump would be a finite share of the derivative's scale; continuity leaves 1e-9 times the next order
        assert np.all(np.abs(left - right) <= 1e-6 * scale[:7] + 1e-6), (b, left - right)
    ts = np.linspace(2.0, end, 20001)
    d = _derivatives(m, ts, 8)
    h = ts[1] - ts[0]
    top = np.abs(d).max(axis=0)
    for k in range(6):
        fd = np.gradient(d[:, k], h)
        # a central difference is off by h^2/6 max|f^(3)| where smooth, by up to h max|f^(2)| / 2 where f^(2) steps
        # (the 7th derivative at the ramps' ends): h max|d_(k+2)| bounds both
        tol = h * top[k + 2] + 1e-9 * top[k + 1]
        assert np.max(np.abs(fd[2:-2] - d[2:-2, k + 1])) < tol, k


@pytest.mark.parametrize("frac", [0.01, 0.05, 0.125, 0.25, 0.4])
def test_peak_acceleration_against_the_bound(frac: float) -> None:
    """The peak acceleration, sampled, is the profile's ``peak_acceleration`` times D, never below 4D/T^2, and
    tends to it as the ramps shorten (1.31x at T/8, 1.83x at T/4, 2.70x at 0.4 T, overlapping: docs/references.md)."""
    T, D = 2.5, 3.0
    shape = move_profile(T, frac * T)
    m = Move(0.0, D, 0.0, shape)
    acc = _derivatives(m, np.linspace(0.0, T, 20001), 3)[:, 2]
    peak = float(np.abs(acc).max())
    assert peak == pytest.approx(shape.peak_acceleration * D, rel=1e-6 if frac <= 0.25 else 1e-4)  # overlap: sampled
    assert shape.peak_over_bound == pytest.approx(peak * T**2 / (4.0 * D), rel=1e-4)
    assert shape.peak_over_bound >= 1.0
    assert shape.peak_over_bound < 1.0 + 2.6 * frac + 10 * frac**2  # the ramps' lost area, ~ 1 / (1 - 2 tau / T)
    if frac == 0.01:
        assert shape.peak_over_bound < 1.03


def test_progress_is_monotone_and_the_speed_limit_holds() -> None:
    """The speed never turns back (the load never moves away from the goal); a speed limit adds a cruise at it."""
    D = 10.0
    free = plan_move((0, 0, 2), (D, 0, 2), VEHICLE, LIMITS, arrive_by=8.0, t_start=0.0, hold=0.0)
    limited = plan_move((0, 0, 2), (D, 0, 2), VEHICLE, LIMITS, arrive_by=8.0, max_speed=1.8, t_start=0.0, hold=0.0)
    assert free.peak_speed > 1.8 and free.profile.cruise == 0.0
    assert limited.profile.cruise > 0.0 and limited.peak_speed <= 1.8 * (1 + 1e-6)
    for plan in (free, limited):
        ts = np.linspace(0.0, 8.0, 8001)
        v = np.array([plan.reference.sample(float(t)).fx[1] for t in ts])
        assert v.min() >= -1e-9
        assert float(v.max()) == pytest.approx(plan.peak_speed, rel=1e-3)


def test_a_time_that_cannot_be_flown_is_refused_with_the_fastest_feasible_one() -> None:
    """3 m in 2.5 s asks more tilt rate than the move's budget on the ArduPilot SITL quad: refused, naming why and
    the fastest feasible time, which itself plans (and passes the full pre-flight check), while a time one
    resolution step shorter does not."""
    with pytest.raises(TrajectoryError, match=r"cannot be flown: nominal tilt rate .*fastest feasible is ") as err:
        plan_move((0, 0, 2), (3, 0, 2), VEHICLE, LIMITS, arrive_by=2.5)
    fastest = float(str(err.value).split("fastest feasible is ")[1].split(" s")[0])
    assert 2.5 < fastest < 10.0
    plan = plan_move((0, 0, 2), (3, 0, 2), VEHICLE, LIMITS, arrive_by=fastest)
    assert plan.feasible and plan.profile.duration == fastest
    assert check_reference(plan.reference, plan.reference.duration, VEHICLE, LIMITS).feasible
    with pytest.raises(TrajectoryError):
        plan_move((0, 0, 2), (3, 0, 2), VEHICLE, LIMITS, arrive_by=fastest - 2.5 * TIME_RESOLUTION)
    forced = plan_move((0, 0, 2), (3, 0, 2), VEHICLE, LIMITS, arrive_by=2.5, force=True)
    assert not forced.feasible and forced.profile.duration == 2.5 and forced.fastest == pytest.approx(fastest)


def test_the_fastest_and_the_acceleration_limit() -> None:
    """Without a time the plan is the fastest feasible; an acceleration limit lengthens it to what the limit allows."""
    fastest = plan_move((0, 0, 2), (3, 0, 2), VEHICLE, LIMITS)
    assert fastest.feasible and fastest.fastest == fastest.profile.duration
    gentle = plan_move((0, 0, 2), (3, 0, 2), VEHICLE, LIMITS, max_accel=0.5)
    assert gentle.peak_acceleration <= 0.5 and gentle.profile.duration > fastest.profile.duration
    # within the resolution, the limit binds: a little faster would exceed it
    assert gentle.peak_acceleration > 0.5 * (gentle.profile.duration / (gentle.profile.duration + 0.1)) ** 2


def test_the_move_file_flies_the_same_reference(tmp_path: Path) -> None:
    """What `slung fly --move` writes into its run folder (kind "move") reads back as the same reference."""
    plan = plan_move((1, -2, 2), (4, 2, 3), VEHICLE, LIMITS, arrive_by=6.0, t_start=2.0, hold=4.0)
    f = tmp_path / "move.toml"
    f.write_text(move_file_text(plan, (1, -2, 2), (4, 2, 3), 4.0), encoding="utf-8")
    back = load_trajectory_file(f)
    assert back.duration == pytest.approx(plan.reference.duration)
    for t in np.linspace(0.0, 12.0, 97):
        a, b = plan.reference.sample(float(t)), back.sample(float(t))
        for ch in ("fx", "fy", "z"):
            assert getattr(a, ch) == pytest.approx(getattr(b, ch), rel=1e-12, abs=1e-12)
    # a straight line: every axis the same profile, scaled
    mid = back.sample(2.0 + 3.0)
    assert (mid.fx[0] - 1) / 3 == pytest.approx((mid.fy[0] + 2) / 4) == pytest.approx(mid.z[0] - 2)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--move", "3,zero,2"], "--move: expected X,Y,Z in metres"),
        (["--scenario", "hover", "--arrive-by", "3"], "--arrive-by applies to --move only"),
        (["--move", "3,0,2", "--arrive-by", "2.5"], "cannot be flown"),
    ],
)
def test_the_command_line_refuses_in_one_line(tmp_path: Path, extra: list[str], message: str) -> None:
    """Bad --move input and a time that cannot be flown end before any connection: exit 2, one line, no traceback."""
    cmd = [sys.executable, "-m", "offboard.cli", "fly", "--connect", "udpin:127.0.0.1:9", "--out", str(tmp_path)]
    r = subprocess.run([*cmd, "--vehicle", "ardupilot-sitl-quad", *extra], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in r.stderr
    if message == "cannot be flown":
        assert "fastest feasible is" in lines[0] and "--arrive-by" in lines[0]


def test_a_move_flies_against_the_emulator_near_the_bound(tmp_path: Path) -> None:
    """`slung fly --move 3,0,2 --arrive-by 4` against the emulator's ArduPilot flavour (lockstep, the ArduPilot SITL
    quad with 1.2 kg on 1 m), judged on the emulator's truth: it completes, the vehicle stays within 0.2 m of the
    goal no later than 0.5 s after the asked time, and the true swing peaks within 2x the bound atan(4D/(gT^2)) at
    that arrival (1.1x on 2026-12-08) and is under 1.5 deg 2 s after it."""
    from emulator_helpers import fly_against_emulator

    from offboard.logs.timeseries_file import read_table

    argv = ["--vehicle", "ardupilot-sitl-quad", "--move", "3,0,2", "--arrive-by", "4", "--duration", "10"]
    m, folder = fly_against_emulator(
        [*argv, "--no-figures", "--out", str(tmp_path / "f")], "ardupilot", "ardupilot-sitl-quad"
    )
    assert m["flight"]["ended_by"] == "completed"
    assert (folder / "move.toml").is_file() and json_path_trajectory(folder).endswith("move.toml")
    table = read_table(folder / "timeseries.slts")
    col = {n: table.data[:, i] for i, n in enumerate(table.columns)}
    t, x, swing, ref = col["t"], col["x"], col["alpha"], col["Fx_ref"]
    start = float(t[np.argmax(np.abs(ref - ref[0]) > 1e-6)]) - (t[1] - t[0])  # the move's start, to one sample
    goal = float(ref[-1])
    away = np.where((np.abs(x - goal) > 0.2) & (t > start))[0]
    arrival = float(t[away[-1] + 1]) - start
    assert arrival <= 4.0 + 0.5
    bound = math.atan(4 * 3.0 / (9.80665 * arrival**2))
    during = (t >= start) & (t <= start + arrival)
    assert float(swing[during].max()) <= 2.0 * bound
    after = t >= start + arrival + 2.0
    assert after.sum() >= 10 and float(swing[after].max()) < math.radians(1.5)


def json_path_trajectory(folder: Path) -> str:
    """The trajectory file the run recorded for replay (``metrics.json`` ``config.trajectory``)."""
    import json

    return str(json.loads((folder / "metrics.json").read_text())["config"]["trajectory"])
