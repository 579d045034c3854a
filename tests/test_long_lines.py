"""Lines from 0.5 m to 30 m (issue 38): the vehicle file accepts them, and the watchdogs scale with the line."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import pytest

from estimators.model.vehicle import VehicleFileError, load_vehicle
from offboard.flight.fly_cli import build_loop_config
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.supervisor import Supervisor, tracking_limit_for

BUNDLED = Path(__file__).resolve().parents[1] / "estimators" / "model" / "vehicles" / "ardupilot-sitl-quad.toml"


def _with_line(tmp_path: Path, line_m: float) -> Path:
    text = BUNDLED.read_text(encoding="utf-8").replace("cable_length_m = 1.0", f"cable_length_m = {line_m!r}")
    path = tmp_path / f"quad-{line_m:g}m.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("line_m", [0.5, 1.0, 5.0, 10.0, 20.0, 30.0])
def test_every_line_a_user_can_hang_is_accepted(tmp_path: Path, line_m: float) -> None:
    v = load_vehicle(_with_line(tmp_path, line_m))
    assert v.cable_length == line_m
    # the pendulum's period across the range: 1.4 s on 0.5 m (with the vehicle's reaction) to 11 s on 30 m
    period = 2.0 * math.pi / v.pendulum_frequency
    assert 1.1 < period < 11.0


def test_a_line_beyond_30_m_is_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(VehicleFileError, match=r"cable_length = 30.5 m is outside the plausible range 0.05..30 m"):
        load_vehicle(_with_line(tmp_path, 30.5))


def _args(*extra: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    fly_configure(p)
    return p.parse_args(["--connect", "udpin:127.0.0.1:14550", "--out", "unused", "--scenario", "hover", *extra])


def test_the_tracking_limit_scales_with_the_line() -> None:
    """A swing the swing watchdog allows moves a 30 m line's load by metres: the default tracking limit is 2 m for
    the vehicle plus that, so an 8 deg swing taken over on 30 m (4.2 m of load offset) is not a tracking error."""
    assert tracking_limit_for(0.0, 0.8) == pytest.approx(2.0)
    assert tracking_limit_for(30.0, 0.8) == pytest.approx(2.0 + 30.0 * math.sin(0.8))
    for line_m in (1.0, 10.0, 30.0):
        cfg = build_loop_config(_args(), lockstep=True, cable_length=line_m)
        assert cfg.tracking_limit_m == pytest.approx(tracking_limit_for(line_m, 0.8))
        s = Supervisor("ardupilot", (255, 190), tracking_limit_m=cfg.tracking_limit_m)
        offset = line_m * math.sin(math.radians(8.0))
        assert s.check_tracking(offset + 1.5, 0.0, 0.0) is None
        v = s.check_tracking(cfg.tracking_limit_m + 0.01, 0.0, 0.0)
        assert v is not None and v.kind == "tracking_error"
    # the fixed 2 m of before ended that take-over on 30 m with the vehicle exactly on its reference
    assert Supervisor("ardupilot", (255, 190), tracking_limit_m=2.0).check_tracking(offset, 0.0, 0.0) is not None
    # the user's own limit is kept, whatever the line; a smaller swing limit lowers the default
    assert build_loop_config(_args("--tracking-limit", "1.5"), True, cable_length=30.0).tracking_limit_m == 1.5
    small = build_loop_config(_args("--swing-limit", "0.2"), True, cable_length=30.0).tracking_limit_m
    assert small == pytest.approx(2.0 + 30.0 * math.sin(0.2))
