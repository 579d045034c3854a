"""Moves as a user thinks of them (issue 37 Build 2): D metres, arrive by T, the load at rest at both ends, on the
rounded bang-bang acceleration (``offboard.control.reference_move``), planned against the vehicle's pre-flight
check, and when the asked time cannot be flown, the fastest feasible one proposed instead of a bare refusal."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from estimators.model.vehicle import load_vehicle
from offboard.control.feasibility import FeasibilityLimits, check_reference
from offboard.control.reference import TrajectoryError
from offboard.control.reference_move import (
    RAMPS,
    MoveReference,
    MoveSpec,
    RoundedBangBang,
    peak_over_bound,
    plan_move,
    unit_distance,
)
from offboard.control.smc import ControllerParams
from offboard.control.trajectory_file import load_trajectory_file
from offboard.flight.command_mapping import MappingConfig

ROOT = Path(__file__).resolve().parents[1]
G = 9.80665


@pytest.mark.parametrize("ramp", [0.05, 0.1, 0.25])
def test_the_profile_goes_d_metres_in_t_from_rest_to_rest(ramp: float) -> None:
    s = RoundedBangBang(3.0, 2.0, 2.5, ramp)
    for t in (0.0, 1.99, 2.0):
        assert s.derivatives(t) == pytest.approx((0.0,) * 7, abs=1e-12)
    for t in (4.5, 4.51, 30.0):
        d = s.derivatives(t)
        assert d[0] == pytest.approx(3.0, abs=1e-12) and d[1:] == pytest.approx((0.0,) * 6, abs=1e-9)
    ts = np.linspace(2.0, 4.5, 5001)
    acc = np.array([s.derivatives(t, 3)[2] for t in ts])
    # its peak acceleration is the bound's 4 D / T^2 times the profile's factor, reached and not exceeded
    assert acc.max() == pytest.approx(peak_over_bound(ramp) * 4.0 * 3.0 / 2.5**2, rel=1e-9)
    assert acc.min() == pytest.approx(-acc.max(), rel=1e-9)


def test_the_corners_are_smooth_through_the_flat_chains_derivatives() -> None:
    """Derivatives 0..6 continuous at every corner (the degree-15 step's C^7), and each the derivative of the one
    before (central differences)."""
    s = RoundedBangBang(3.0, 1.0, 3.0, 0.1)
    for b in s.breakpoints:
        left, right = s.derivatives(b - 1e-9), s.derivatives(b + 1e-9)
        scale = [max(1.0, abs(v)) for v in left]
        assert all(abs(a - c) <= 1e-4 * k for a, c, k in zip(left, right, scale)), (b, left, right)
    h = 1e-5
    for t in (1.2, 2.3, 2.5, 3.9):
        d, dp, dm = s.derivatives(t), s.derivatives(t + h), s.derivatives(t - h)
        for k in range(6):
            roundoff = 1e-9 * max(1.0, abs(d[k])) / h
            assert (dp[k] - dm[k]) / (2 * h) == pytest.approx(d[k + 1], rel=1e-5, abs=roundoff)


def test_the_profile_is_far_closer_to_the_bound_than_the_polynomial_steps() -> None:
    """1.11x-1.81x the bound's acceleration, against 3.8x (position step) and 3.1x (velocity step)."""
    assert unit_distance(1e-9) == pytest.approx(0.25, rel=1e-6)  # the sharp bang-bang
    factors = [peak_over_bound(r) for r in RAMPS]
    assert factors == sorted(factors)
    assert factors[0] == pytest.approx(1.109, abs=1e-3) and factors[-1] == pytest.approx(1.813, abs=1e-3)


def _feasible_on(vehicle_name: str):  # the check slung fly runs (default mapping limits, torque-level params)
    vehicle = load_vehicle(vehicle_name)
    limits = FeasibilityLimits.from_config(ControllerParams.for_vehicle(vehicle), MappingConfig(), 0.8)

    def feasible(r: MoveReference) -> str | None:
        res = check_reference(r, r.duration, vehicle, limits)
        return None if res.feasible else res.messages[0]

    return feasible


def test_a_feasible_move_gets_the_shortest_corners_the_check_accepts() -> None:
    feasible = _feasible_on("ardupilot-sitl-quad")
    plan = plan_move(MoveSpec(10.0, 6.0), feasible)
    assert plan.reference is not None and plan.ramp is not None
    i = RAMPS.index(plan.ramp)
    assert all(feasible(MoveSpec(10.0, 6.0).reference(r)) is not None for r in RAMPS[:i])


def test_an_infeasible_time_is_answered_with_the_fastest_feasible_one() -> None:
    feasible = _feasible_on("ardupilot-sitl-quad")
    spec = MoveSpec(3.0, 2.5)
    plan = plan_move(spec, feasible)
    assert plan.reference is None and plan.why
    assert plan.fastest_s is not None and 2.5 < plan.fastest_s < 4.0
    assert plan.fastest_ramp is not None and feasible(spec.reference(plan.fastest_ramp, plan.fastest_s)) is None
    assert feasible(spec.reference(RAMPS[-1], plan.fastest_s - 0.1)) is not None


def test_the_move_file_kind(tmp_path: Path) -> None:
    f = tmp_path / "m.toml"
    f.write_text('kind = "move"\ndistance = 3.0\narrive_by = 3.0\ndirection_deg = 90\nz = 2.0\n')
    ref = load_trajectory_file(f)
    assert isinstance(ref, MoveReference) and not ref.ramp_given and ref.duration == pytest.approx(2.0 + 3.0 + 15.0)
    end = ref.sample(ref.duration)
    assert (end.fx[0], end.fy[0], end.z[0]) == pytest.approx((0.0, 3.0, 2.0), abs=1e-12)  # 90 deg: towards y
    f.write_text('kind = "move"\ndistance = 3.0\narrive_by = 3.0\nz = 2.0\nramp = 0.4\n')
    with pytest.raises(TrajectoryError, match=r"ramp must be in \(0, 0.25\]"):
        load_trajectory_file(f)
    f.write_text('kind = "move"\ndistance = -1\narrive_by = 3.0\nz = 2.0\n')
    with pytest.raises(TrajectoryError, match="distance must be > 0"):
        load_trajectory_file(f)


def test_slung_fly_says_why_and_proposes_the_fastest_time_before_connecting(tmp_path: Path) -> None:
    f = tmp_path / "m.toml"
    f.write_text('kind = "move"\ndistance = 3.0\narrive_by = 2.5\nz = 2.0\n')
    cmd = [sys.executable, "-m", "offboard.cli", "fly", "--connect", "udpin:127.0.0.1:9", "--vehicle"]
    cmd += ["ardupilot-sitl-quad", "--trajectory", str(f), "--out", str(tmp_path / "out")]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr
    m = re.search(r"3 m in 2.5 s cannot be flown \(.+\); the fastest feasible arrival is ([0-9.]+) s", lines[0])
    assert m and 2.5 < float(m.group(1)) < 4.0, lines[0]
