"""The emulator's PX4 flavour against real PX4 SITL, same vehicle (px4-sih), same client: a 0.2 rad roll step sent
by SET_ATTITUDE_TARGET in OFFBOARD; the truth's 10-90 % rise times agree within 1.5x, and the emulator's
10 %-to-peak time lies within 1.5x of real PX4's run-to-run spread of that figure
(bench/calibrate_emulator_px4.py; the full table with hover noise is in docs/emulator.md). One PX4 instance (8);
the two sides fly one after the other, each in real time (about 40 s)."""

from __future__ import annotations

import argparse
import importlib.util
import math
import sys
import threading
from pathlib import Path
from typing import Any

import pytest
from real_components import require_px4_sitl

ROOT = Path(__file__).resolve().parents[1]
INSTANCE = 8
#: real PX4 SITL's truth 10 %-to-peak times over four recorded runs, s (docs/emulator.md, 2026-12-02, px4-sih)
PX4_PEAK_SPREAD_S = (0.48, 0.90)


def _bench() -> Any:
    """bench/calibrate_emulator_px4.py as a module (bench/ is not a package)."""
    name = "calibrate_emulator_px4"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[name] = mod  # its dataclasses look their module up there
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


@pytest.mark.slow
def test_roll_step_response_matches_real_px4_within_1_5x() -> None:
    require_px4_sitl()
    bench = _bench()
    args = argparse.Namespace(
        ground=0.0, hover=0.0, step=0.2, settle=8.0, step_only=True, vehicle="px4-sih", seed=0, ekf="px4-sih"
    )
    out: dict[str, Any] = {}

    def side(name: str, fn: Any) -> None:
        try:
            out[name] = fn()
        except BaseException as exc:  # reported below
            out[name] = exc

    # one after the other: flown side by side, the emulator's in-process plant took CPU from PX4 SITL, whose
    # step then peaked at 0.56 s instead of the 0.64-0.92 s it shows alone
    for name, fn in (("px4", lambda: bench.run_px4(INSTANCE, args)), ("emulator", lambda: bench.run_emulator(args))):
        t = threading.Thread(target=side, args=(name, fn))
        t.start()
        t.join(timeout=240)
    for name in ("px4", "emulator"):
        if isinstance(out.get(name), BaseException):
            raise out[name]
    px4, emu = out["px4"]["figures"], out["emulator"]["figures"]
    for key in ("step_rise_s", "step_peak_s"):
        a, b = px4[key], emu[key]
        assert math.isfinite(a) and math.isfinite(b) and a > 0.05, (key, a, b)
    a, b = px4["step_rise_s"], emu["step_rise_s"]
    assert 1 / 1.5 <= b / a <= 1.5, f"step_rise_s: PX4 {a:.3f} s, emulator {b:.3f} s"
    # The 10 %-to-peak time is the time of the highest sample of a noisy, drifting flat top (EKF2's roll error and
    # SIH's gyro noise, docs/emulator.md "10 % to peak"): real PX4's own runs spread 0.48-0.90 s, and only 2 of 6
    # pairs of PX4 runs agree with each other within 1.5x, so one PX4 run is no yardstick for one emulator run. The
    # emulator's peak time must lie within 1.5x of PX4's spread: the recorded runs' and this run's.
    lo, hi = min(PX4_PEAK_SPREAD_S[0], px4["step_peak_s"]), max(PX4_PEAK_SPREAD_S[1], px4["step_peak_s"])
    assert lo / 1.5 <= emu["step_peak_s"] <= 1.5 * hi, (
        f"step_peak_s: emulator {emu['step_peak_s']:.3f} s outside 1.5x of PX4's {lo:.3f}-{hi:.3f} s"
    )
    # both reached the commanded tilt (the step really happened on both sides). PX4's attitude loop regulates EKF2's
    # roll, which is off the truth by 1.4-2.3 deg in these hovers (docs/deploy.md 2a): 0.12-0.2 of this 0.2 rad
    # step, so PX4's own reported roll is held to the command and the true roll only to having rolled. A CI run of
    # 2026-12-02 17:10 UTC: EKF2's roll 0.000-0.003 rad before the step against a true 0.023-0.035, 0.198 at its
    # end against a true 0.187; the truth's step came to 0.83 of the command, PX4's own to 0.99
    assert px4["att_step_final_fraction"] == pytest.approx(1.0, abs=0.15), px4
    assert px4["step_final_fraction"] == pytest.approx(1.0, abs=0.3), px4
    assert emu["step_final_fraction"] == pytest.approx(1.0, abs=0.15)
