"""The compiled controllers (``offboard.control.compiled.laws``) against the scalar laws (``offboard.control.smc.step``
and the registry's controllers, ``offboard.control.controllers``): fed the same estimates and references tick after
tick, each run's command and saturation flag agree to 1e-12 (absolute: commands of a few N and N m; the memories
feed every later command). The one difference by design: the compiled ``smc`` does not screen its estimate (a NaN
reaches its command and memory; the scalar law hovers), so a run is compared up to its first NaN there.

The estimates are the true states of a flown rest-to-rest move (three vehicles, sampled every 10 ms) plus noise,
with one run pushed far off its reference for a while (the speed, tilt, torque and thrust limits clip) and another
whose attitude estimate is NaN for a few ticks.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any

import numba
import numpy as np
import pytest

from estimators.kernels import EST_ALPHA_Y, EST_FX, EST_FY, EST_PSI, EST_SIZE, EST_THETA, EST_Z
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants, truth_control_state
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.compiled import laws
from offboard.control.compiled.reference_row import REF_SIZE
from offboard.control.controllers import registry
from offboard.control.scenarios import make_scenario
from offboard.harness.compiled import engine
from offboard.harness.compiled import inputs as cin

V = Vehicle()
#: the controller's period (s): the flown move's states every 10 plant steps of 1 ms
DT = 0.01
RUNS = 3
#: run 1's attitude estimate is NaN on these ticks
NAN_TICKS = range(150, 154)
ATOL = 1e-12

#: the noise added to the true state, per field of the estimate (SI): the flat chains' orders 0..5, then z, z',
#: the attitude, its rates, the swing angles and their rates
NOISE = np.array(
    [0.01, 0.02, 0.05, 0.2, 1.0, 5.0] * 2 + [0.01, 0.02] + [0.005] * 3 + [0.02] * 3 + [0.005] * 2 + [0.03] * 2
)

#: the rows tested: (row of laws.TORQUE_LAWS, the smc law's parameters or the baseline's nominal vehicle)
CASES: dict[str, tuple[str, Any]] = {
    "smc-sign": ("smc", smc.ControllerParams.for_vehicle(V, switching="sign")),
    "smc-smooth": ("smc", smc.ControllerParams.for_vehicle(V, switching="smooth")),
    "smc-row-sign": ("smc", registry.smc_params(V, "sign")),  # actuation lag, shared roll / pitch margin
    "smc-row-smooth": ("smc", registry.smc_params(V, "smooth")),
    "cascade": ("cascade", V),
    "zvd": ("zvd", V),
    "swing-feedback": ("swing-feedback", V),
    "lqr": ("lqr", V),  # the motors' lag designed in: 24 states
    "lqr-no-lag": ("lqr", replace(V, motor_time_constant=0.0)),  # 20 states
}


def _offsets(tick: int) -> tuple[float, float]:
    """Run 2's push off the reference at ``tick``: (the offset of F_x, m, F_y's a third of it; the heading's, rad)."""
    ramp = min(1.0, max(0.0, (tick - 100) / 60.0)) if tick < 220 else 0.0  # up to 15 m: past the speed limit
    heading = 0.8 if 240 <= tick < 280 else 0.0
    return 15.0 * ramp, heading


@pytest.fixture(scope="module")
def flight() -> tuple[np.ndarray, list[Any]]:
    """(the estimates (ticks, RUNS, EST_SIZE), the reference samples) of a rest-to-rest move (3 m in 2.5 s, swings
    up to 0.7 rad) flown by the smc row on three vehicles (the nominal one, a heavier load, a longer cable), the
    true states plus noise, run 2 pushed off (:func:`_offsets`), run 1's attitude NaN on ``NAN_TICKS``."""
    scenario = make_scenario("rest-to-rest", duration=3.0)
    vehicles = [V, replace(V, mass_load=1.3 * V.mass_load), replace(V, cable_length=1.4 * V.cable_length)]
    k = flat_constants(V)
    log = engine.simulate([scenario] * RUNS, vehicles, registry.smc_params(V), log_every=round(DT / 0.001))
    xs = [log["x"][:, :, b] for b in range(RUNS)]
    rng = np.random.default_rng(11)
    ests = np.empty((len(xs[0]), RUNS, EST_SIZE))  # a run's estimate contiguous, as the driver has it
    for b, x_run in enumerate(xs):
        for tick, x in enumerate(x_run):
            truth = truth_control_state(x, k)
            ests[tick, b, EST_FX : EST_FX + 6], ests[tick, b, EST_FY : EST_FY + 6] = truth.fx, truth.fy
            ests[tick, b, EST_Z:] = truth[2:]
    ests += NOISE * rng.standard_normal(ests.shape)
    for tick in range(ests.shape[0]):
        push, heading = _offsets(tick)
        ests[tick, 2, [EST_FX, EST_FY]] += (push, push / 3.0)
        ests[tick, 2, EST_PSI] += heading
    ests[list(NAN_TICKS), 1, EST_THETA] = math.nan
    reference = scenario.reference
    return ests, [reference.sample(tick * DT) for tick in range(ests.shape[0])]


def _control_state(est: np.ndarray) -> ControlState:
    """The scalar laws' estimate from a compiled estimate vector (``layout.EST_*``)."""
    fx, fy = tuple(float(v) for v in est[EST_FX : EST_FX + 6]), tuple(float(v) for v in est[EST_FY : EST_FY + 6])
    return ControlState(fx, fy, *(float(v) for v in est[EST_Z:]))


def _ref_row(fx: tuple, fy: tuple, z: tuple, psi: tuple) -> np.ndarray:
    """The reference row (``layout.REF_*``) of a (shaped) sample's four 7-tuples."""
    row = np.concatenate([fx, fy, z, psi]).astype(float)
    assert row.shape == (REF_SIZE,)
    return row


class _Scalar:
    """The scalar law of a case, one instance per run, one tick at a time (as ``offboard.harness.sim.run`` calls
    it): ``smc.step`` with its memory for the smc cases, else the registry's controller (``zv`` / ``zvd`` shape the
    raw reference themselves)."""

    def __init__(self, row: str, arg: Any) -> None:
        self.params = arg if row == "smc" else None
        self.mem = [smc.ControllerMemory() for _ in range(RUNS)]
        self.laws = None if row == "smc" else [registry.make(row, arg) for _ in range(RUNS)]

    def step(self, tick: int, b: int, est: np.ndarray, sample: Any) -> tuple[np.ndarray, bool]:
        """(u (4,), saturated) of run ``b`` for the estimate ``est`` (EST_SIZE,) at ``tick``."""
        refs = (sample.fx, sample.fy, sample.z, sample.psi)
        if self.laws is None:
            cmd, self.mem[b] = smc.step(tick * DT, _control_state(est), *refs, self.mem[b], self.params)
        else:
            cmd = self.laws[b].step(tick * DT, _control_state(est), *refs)
        return np.array([cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi]), bool(cmd.saturated)


def _fly_both(case: str, flight: tuple[np.ndarray, list[Any]]) -> dict[str, np.ndarray]:
    """Both paths over the flight, compared tick by tick (commands, saturation); returns the compiled commands
    (ticks, 4, RUNS) and saturation flags (ticks, RUNS)."""
    row, arg = CASES[case]
    ests, samples = flight
    scalar = _Scalar(row, arg)
    vehicle, params = (V, arg) if row == "smc" else (arg, registry.smc_params(arg))
    code, c, K = laws.law_constants(row, vehicle, params)
    shaper = cin.law_shaper(row, vehicle)  # the driver shapes the reference once for all runs
    mems = [laws.law_memory(code, c) for _ in range(RUNS)]
    us, sats = np.empty((len(samples), 4, RUNS)), np.empty((len(samples), RUNS), dtype=bool)
    for tick, sample in enumerate(samples):
        refs = (sample.fx, sample.fy, sample.z, sample.psi)
        ref = _ref_row(*(refs if shaper is None else shaper(tick * DT, *refs)))
        for b in range(RUNS):
            u_k = us[tick, :, b]
            sats[tick, b] = laws.law_step(
                code, c, K, mems[b], tick * DT, 0.0 if tick == 0 else DT, ests[tick, b], ref, u_k
            )
            want, want_sat = scalar.step(tick, b, ests[tick, b], sample)
            if row == "smc" and b == 1 and tick >= NAN_TICKS[0]:
                continue  # the compiled smc flies the NaN on (see the module docstring)
            where = f"{case}, tick {tick}, run {b}"
            np.testing.assert_allclose(u_k, want, rtol=0, atol=ATOL, err_msg=where)
            assert sats[tick, b] == want_sat, where
    return {"u": us, "sat": sats}


@pytest.mark.parametrize("case", list(CASES))
def test_the_compiled_law_equals_the_scalar_law_tick_by_tick(case: str, flight: Any) -> None:
    """Each run's command and saturation flag, tick after tick over a 3 s flight, equal the scalar law's to 1e-12;
    the clipping paths are taken (some ticks saturate, not all)."""
    got = _fly_both(case, flight)
    sat = got["sat"]
    assert 0 < sat.sum() < sat.size, f"{case}: {sat.sum()} of {sat.size} saturated"
    assert sat[:, 2].any() and not sat[:100, 0].all()  # the pushed run clips; the others fly within the limits
    u = got["u"]
    if CASES[case][0] != "smc":  # the baselines hover through the NaN ticks, then fly on
        hover = np.array([V.hover_thrust, 0.0, 0.0, 0.0])
        for tick in NAN_TICKS:
            np.testing.assert_array_equal(u[tick, :, 1], hover)
        assert np.isfinite(u[NAN_TICKS[-1] + 1 :, :, 1]).all()
        assert not np.array_equal(u[NAN_TICKS[-1] + 1, :, 1], hover)
    else:  # the compiled smc does not screen its estimate: the NaN reaches the command
        assert np.isnan(u[NAN_TICKS[0], :, 1]).any()


def test_the_shared_margin_scales_the_roll_pitch_pair(flight: Any) -> None:
    """The smc row's shared roll / pitch margin is exercised: on some ticks the pair sits on the margin
    (``|tau_phi| / tp_max + |tau_theta| / tt_max = 1``)."""
    u = _fly_both("smc-row-sign", flight)["u"]
    share = np.abs(u[:, 1]) / V.roll_pitch_torque_max + np.abs(u[:, 2]) / V.roll_pitch_torque_max
    assert np.isclose(share, 1.0, rtol=0, atol=1e-12).sum() > 5


def test_zv_and_zvd_are_the_cascade_and_the_codes_are_distinct() -> None:
    """The shaped rows fly the cascade's code and gains (the driver shapes their reference); every law has its own
    code and its memory the layout's size."""
    params = registry.smc_params(V)
    code, c, K = laws.law_constants("cascade", V, params)
    for row in ("zv", "zvd"):
        code_s, c_s, K_s = laws.law_constants(row, V, params)
        assert code_s == code == laws.LAW_CASCADE and np.array_equal(c_s, c) and K_s.shape == K.shape == (0, 0)
    codes = {laws.law_constants(row, V, params)[0] for row in laws.TORQUE_LAWS}
    assert codes == {laws.LAW_SMC, laws.LAW_CASCADE, laws.LAW_SWING_FEEDBACK, laws.LAW_LQR}
    assert laws.law_memory(laws.LAW_SWING_FEEDBACK, laws.law_constants("swing-feedback", V, params)[1]).shape == (12,)
    with pytest.raises(ValueError, match="not a pair"):
        laws.law_memory(laws.LAW_SWING_FEEDBACK, c)


def test_swing_feedback_offsets_stop_beyond_the_applets_distance() -> None:
    """With the load beyond SLUP_DIST_MAX (a swing of 60 rad on the 0.3 m cable: 18 m) the applet's velocity and
    acceleration offsets are zero, its position offset held, as in the scalar law."""
    params = registry.smc_params(V)
    code, c, K = laws.law_constants("swing-feedback", V, params)
    scalar = registry.make("swing-feedback", V)
    mem, u = laws.law_memory(code, c), np.zeros(4)
    sample = make_scenario("rest-to-rest").reference.sample(1.0)
    ref = _ref_row(sample.fx, sample.fy, sample.z, sample.psi)
    for tick, swing in enumerate((0.1, 0.1, 60.0, 60.0, 0.1)):
        est = np.zeros(EST_SIZE)
        est[EST_Z], est[EST_ALPHA_Y], est[EST_FX + 3] = 2.0, swing, 1.5
        sat = laws.law_step(code, c, K, mem, tick * DT, DT, est, ref, u)
        cmd = scalar.step(tick * DT, _control_state(est), sample.fx, sample.fy, sample.z, sample.psi)
        np.testing.assert_allclose(u, [cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi], rtol=0, atol=ATOL)
        assert sat == cmd.saturated
        if swing > 1.0:
            assert mem[laws.B_VEL_X] == mem[laws.B_VEL_Y] == 0.0
    assert mem[laws.B_VEL_X] != 0.0  # back within the distance: the offsets grow again


@numba.njit
def _tick_loop(
    code: int, c: np.ndarray, K: np.ndarray, mem: np.ndarray, ests: np.ndarray, ref: np.ndarray, reps: int
) -> float:
    """``law_step`` over the estimates ``ests`` (ticks, EST_SIZE) ``reps`` times (the timing's loop)."""
    u = np.zeros(4)
    acc = 0.0
    n = ests.shape[0]
    for r in range(reps):
        for i in range(n):
            laws.law_step(code, c, K, mem, (r * n + i) * 0.01, 0.01, ests[i], ref, u)
            acc += u[0]
    return acc


def test_law_step_time_per_call(flight: Any) -> None:
    """The time of one ``law_step`` per law, called from compiled code over the flight's estimates (printed; bound
    loosely, 20 us, against a fall back to slow code)."""
    ests, samples = flight
    run0 = np.ascontiguousarray(ests[:, 0])
    s = samples[120]
    ref = _ref_row(s.fx, s.fy, s.z, s.psi)
    params = registry.smc_params(V)
    for row in ("smc", "cascade", "swing-feedback", "lqr"):
        code, c, K = laws.law_constants(row, V, params)
        _tick_loop(code, c, K, laws.law_memory(code, c), run0, ref, 1)  # compiled before the clock starts
        reps = 100
        t0 = time.perf_counter()
        total = _tick_loop(code, c, K, laws.law_memory(code, c), run0, ref, reps)
        ns = (time.perf_counter() - t0) / (reps * run0.shape[0]) * 1e9
        print(f"law_step {row}: {ns:.0f} ns per call")
        assert math.isfinite(total)
        assert ns < 20_000
