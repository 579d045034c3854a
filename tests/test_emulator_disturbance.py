"""``slung emulate --disturbance paper``: slung sim's bounded random disturbances (``sim_bridge.plant.disturbances``)
act on the emulator's plant, on the documented clock (origin: the first offboard entry, boot, or a harness-set time),
and move the vehicle. The plant inputs are read from the emulator running in this process; the flights are flown over
real UDP on 127.0.0.1 in lockstep."""

from __future__ import annotations

import argparse
from typing import Any

import pytest
from emulator_helpers import Emu, InProcessEmu, fly_lockstep_hold

from estimators.model.vehicle import Vehicle
from sim_bridge import emulator_cli
from sim_bridge.plant.disturbances import DisturbanceSpec, RandomDisturbance

V = Vehicle()
SEED = 5


def test_plant_inputs_are_random_disturbance_from_the_offboard_entry() -> None:
    with InProcessEmu(
        "--lockstep",
        "--lockstep-grace",
        "1",
        "--est-ready",
        "0.2",
        "--disturbance",
        "paper",
        "--disturbance-start",
        "1.0",
        "--seed",
        str(SEED),
    ) as e:
        e.emu.input_log = []
        fly_lockstep_hold(e, 4.0, V)
        summary = e.stop()
        log = e.emu.input_log
    origin_s = summary["offboard_entry_s"]
    assert origin_s is not None and summary["disturbance"]["origin_s"] == origin_s
    origin_us = round(origin_s * 1e6)
    d = RandomDisturbance(DisturbanceSpec(start=1.0), SEED)
    before = [v for t, v in log if t < origin_us]
    after = [(t, v) for t, v in log if t >= origin_us]
    assert len(before) > 100 and len(after) > 3500
    assert all(v == (0.0,) * 9 for v in before)
    for t, v in after:
        assert v == d((t - origin_us) * 1e-6)  # exactly: the same function of the same time
    # onset 1 s after the offboard entry, bounded by the spec, and really there
    onset = [t for t, v in after if any(v)]
    assert (onset[0] - origin_us) * 1e-6 == pytest.approx(1.0, abs=0.0011)
    fx, fy, fz = (max(abs(v[i]) for _, v in after) for i in range(3))
    tz = max(abs(v[8]) for _, v in after)
    assert max(fx, fy, fz) <= 0.5 and tz <= 0.02
    assert min(fx, fy, fz) > 0.1 and tz > 0.004
    assert all(v[3:8] == (0.0,) * 5 for _, v in after)  # no force on the load, no roll / pitch torque
    assert summary["disturbance"]["max_abs_force_xyz_n"] == pytest.approx([fx, fy, fz], abs=1e-12)


def _trace(*extra: str) -> tuple[list[tuple[float, float, float]], dict]:
    with Emu("--lockstep", "--lockstep-grace", "1", "--est-ready", "0.2", "--seed", str(SEED), *extra) as e:
        r = fly_lockstep_hold(e, 5.0, V)
        summary = e.stop()
    return r["trace"], summary


def test_disturbances_move_the_vehicle_after_their_onset() -> None:
    calm, s0 = _trace()
    windy, s1 = _trace("--disturbance", "paper", "--disturbance-start", "1.5")
    assert s0["disturbance"] is None and s1["disturbance"]["origin"] == "offboard"
    assert len(calm) == len(windy) > 400
    # trace rows: (ms since the offboard entry, north m, down m)
    quiet = [(a, b) for a, b in zip(calm, windy) if a[0] <= 1500]
    assert all(a == b for a, b in quiet)  # nothing acts before the onset
    late = [(a, b) for a, b in zip(calm, windy) if a[0] >= 2500]
    dev = max(max(abs(a[1] - b[1]), abs(a[2] - b[2])) for a, b in late)
    assert dev > 0.02
    f = s1["disturbance"]["max_abs_force_xyz_n"]
    assert max(f) <= 0.5 and min(f) > 0.05 and s1["disturbance"]["max_abs_torque_yaw_nm"] <= 0.02


def _build(*argv: str) -> Any:
    """(emulator, autopilot, link) built from command-line arguments, not running."""
    parser = argparse.ArgumentParser()
    emulator_cli.configure(parser)
    return emulator_cli.build(parser.parse_args(["--mavlink", "udpin:127.0.0.1:0", *argv]))


def test_default_is_the_paper_spec_and_the_boot_and_harness_origins() -> None:
    emu, _, link = _build("--disturbance", "paper", "--seed", "9")
    try:
        assert emu.disturbance.spec == DisturbanceSpec()  # the spec of slung sim's paper scenario
        ref = RandomDisturbance(DisturbanceSpec(), 9)
        assert all(emu.disturbance(t) == ref(t) for t in (25.5, 30.0, 41.3))
    finally:
        link.close()
    # boot origin: --disturbance-start is absolute simulation time; a harness may set the origin itself
    for origin, setter in (("boot", None), ("harness", 0.3), ("offboard", 0.3)):
        emu, _, link = _build(
            "--disturbance", "paper", "--disturbance-start", "0.5", "--disturbance-origin", origin, "--seed", "9"
        )
        try:
            if setter is not None:
                emu.set_disturbance_origin(setter)
            emu.input_log = []
            emu.step(1500)
            o = 0.0 if setter is None else setter
            d = RandomDisturbance(DisturbanceSpec(start=0.5), 9)
            assert all(v == d(max(t - round(o * 1e6), 0) * 1e-6) for t, v in emu.input_log)
            first = next(t for t, v in emu.input_log if any(v)) * 1e-6
            assert first == pytest.approx(o + 0.5, abs=0.0011)
        finally:
            link.close()
    with pytest.raises(ValueError):
        emu.set_disturbance_origin(float("nan"))
    # harness origin never set (and offboard never entered): no disturbance at all
    for origin in ("harness", "offboard"):
        emu, _, link = _build("--disturbance", "paper", "--disturbance-start", "0.0", "--disturbance-origin", origin)
        try:
            emu.input_log = []
            emu.step(1000)
            assert len(emu.input_log) == 1000 and not any(any(v) for _, v in emu.input_log)
        finally:
            link.close()
