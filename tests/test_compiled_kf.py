"""The compiled measured-input filter (``offboard.harness.compiled.kf``) replays the numpy batched filter
(``estimators.filters.batched_kf.BatchedMeasuredKalman``, itself the scalar filter to 1e-9): every call the batched
sweep makes on the numpy filter in a real flight (drawn runs of the default sweep file, their drawn sensors with
noise and latency, the mixer, the sliding-mode law) is recorded run by run and replayed into the kernels, and every
estimate agrees with the numpy one to 1e-12 (relative to the value, absolute below 1), the gates refusing and
reopening as often.

The one expected difference: ``np.tan`` (numpy's own float64 tangent) and ``math.tan`` (libm, the kernels' and the
scalar filter's) differ in the last bit for about 0.5 % of arguments; everything else is the same arithmetic in the
same order (with ``math.tan`` swapped into the numpy filter, its state equals the kernels' bit for bit).
"""

from __future__ import annotations

import functools
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pytest
from sweep_helpers import short_file

from estimators.filters.batched_kf import BatchedMeasuredKalman
from estimators.filters.measured_kf import MeasuredTuning
from estimators.model.vehicle import Vehicle
from offboard.control.controllers import registry
from offboard.harness import batched, sweep
from offboard.harness.compiled.kf import (
    C_EXTERNAL_FF,
    N_GATED_RUN,
    N_REFUSED,
    N_REOPENED,
    STREAMS,
    kf_advance,
    kf_constants,
    kf_estimate,
    kf_fuse,
    kf_fuse_gyro,
    kf_initialize,
    kf_new_state,
    kf_push_command,
)
from offboard.harness.compiled.layout import (
    ATT,
    EST_FX,
    EST_FY,
    EST_PSI,
    EST_PSI_RATE,
    EST_SIZE,
    EST_Z,
    EST_Z_RATE,
    IMU,
    LOAD,
    POS,
)
from sim_bridge.plant.sensors import Preset, preset_spec

V = Vehicle()
#: the estimate dictionary's scalars in the order of the estimate vector after the chains (layout.EST_Z on)
_SCALARS = (
    "z",
    "z_rate",
    "phi",
    "theta",
    "psi",
    "phi_rate",
    "theta_rate",
    "psi_rate",
    "alpha_x",
    "alpha_y",
    "alpha_x_rate",
    "alpha_y_rate",
)


def _fast(p: Preset) -> Preset:
    """The drawn suite at ``px4-fast``'s rates (position 100 Hz, attitude, IMU and cable angle 250 Hz)."""
    fast = preset_spec("px4-fast")
    streams = ("position", "attitude", "imu", "load")
    return p._replace(**{k: getattr(p, k)._replace(rate_hz=getattr(fast, k).rate_hz) for k in streams})


def _slow(p: Preset) -> Preset:
    """The drawn suite with 10 Hz position and IMU telemetry: blocks left behind for more than 0.05 s (the schedule's
    block advances), an acceleration input that goes stale between samples."""
    return p._replace(position=p.position._replace(rate_hz=10.0), imu=p.imu._replace(rate_hz=10.0))


#: the flights replayed: (cable-angle sensor, the filter's tuning, what becomes of the drawn sensor suite)
CASES: dict[str, tuple[bool, MeasuredTuning, Callable[[Preset], Preset] | None]] = {
    "default": (True, MeasuredTuning(), None),
    "gyro, no cable sensor": (False, MeasuredTuning(fuse_gyro=True), None),
    # the smc row's tuning (registry.filter_tuning) at 250 Hz, without the thrust window that keeps the height law's
    # thrust steps from being refused as the acceleration input, with a tight gate quick to reopen: refusals in a row
    "feed-forward, tight gates, fast": (
        True,
        MeasuredTuning(external_feedforward=True, thrust_explains_jumps=False, gate_probability=0.99, gate_reopen=1),
        _fast,
    ),
    "slow telemetry": (False, MeasuredTuning(), _slow),
}


class RecordingKalman(BatchedMeasuredKalman):
    """The numpy filter, recording per run every call the batched simulation makes on it (with its arguments, and
    the estimates it returns), and per run and stream the updates its gates refuse and reopen."""

    def __init__(self, vehicle: Vehicle, B: int, **kw: Any) -> None:
        super().__init__(vehicle, B, **kw)
        self.calls: list[list[tuple[Any, ...]]] = [[] for _ in range(B)]
        self.refused = np.zeros((B, len(STREAMS)), dtype=int)
        self.reopened = np.zeros(B, dtype=int)
        self._inside = 0  # > 0: within a fuse, whose own block advances are not the caller's

    def initialize(self, t: float, fx: Any, fy: Any, z: Any, z_rate: Any, psi: Any, psi_rate: Any) -> None:
        for b in range(self.B):
            guess = np.full(EST_SIZE, np.nan)  # the entries the filter must not read stay NaN
            guess[EST_FX : EST_FX + 6], guess[EST_FY : EST_FY + 6] = fx[:, b], fy[:, b]
            guess[EST_Z], guess[EST_Z_RATE], guess[EST_PSI], guess[EST_PSI_RATE] = z[b], z_rate[b], psi[b], psi_rate[b]
            self.calls[b].append(("init", float(t), guess))
        super().initialize(t, fx, fy, z, z_rate, psi, psi_rate)

    def push_command(self, tau_phi: Any, tau_theta: Any, thrust: Any = None) -> None:
        for b in range(self.B):
            self.calls[b].append(("command", float(tau_phi[b]), float(tau_theta[b]), float(thrust[b])))
        super().push_command(tau_phi, tau_theta, thrust)

    def fuse(self, kind: int, idx: Any, t: Any, z: Any) -> None:
        for j, b in enumerate(idx):
            self.calls[b].append(("fuse", kind, float(t[j]), np.array(z[:, j], dtype=float)))
        self._inside += 1
        super().fuse(kind, idx, t, z)
        self._inside -= 1

    def fuse_gyro(self, idx: Any, t: Any, gyro: Any) -> None:
        for j, b in enumerate(idx):
            self.calls[b].append(("gyro", float(t[j]), np.array(gyro[:, j], dtype=float)))
        self._inside += 1
        super().fuse_gyro(idx, t, gyro)
        self._inside -= 1

    def advance(self, bi: int, idx: Any, t: Any) -> None:
        if not self._inside:  # the schedule's advance of a block a silent stream leaves behind
            for j, b in enumerate(idx):
                self.calls[b].append(("advance", bi, float(t[j])))
        super().advance(bi, idx, t)

    def estimate_arrays(self, t: float) -> dict[str, Any]:
        est = super().estimate_arrays(t)
        for b in range(self.B):
            vec = np.concatenate([est["fx"][:, b], est["fy"][:, b], [est[k][b] for k in _SCALARS]])
            self.calls[b].append(("estimate", float(t), vec))
        return est

    def _gated(self, name: str, idx: Any, refused: Any) -> Any:
        reopen = super()._gated(name, idx, refused)
        self.refused[idx, STREAMS.index(name)] += refused
        self.reopened[idx] += reopen
        return reopen


def _short_file(tmp: Path) -> Path:
    """The default sweep file with a 1 s move and a 0.5 s hold, the filter in the loop (as tests/test_sweep.py)."""
    return short_file(tmp, "compiled", "kf", move=1.0, hold=0.5, gust_start=(0.5, 3.0))


@functools.cache
def _flown(case: str) -> tuple[RecordingKalman, list[dict[str, float]]]:
    """Runs 0-2 of the short default file flown by the batched path with the recording filter of ``case``: the
    filter (its calls per run) and the runs' draws."""
    load_sensor, tuning, suite = CASES[case]
    with tempfile.TemporaryDirectory() as tmp:
        cfg = sweep.load_config(_short_file(Path(tmp)))
    draws = [sweep.draw(cfg, r, V) for r in range(3)]
    vehicles = [sweep.plant_vehicle(V, d) for d in draws]
    scs = [sweep.scenario(cfg, d) for d in draws]
    presets = [sweep.sensor_preset(cfg, d) for d in draws]
    if suite is not None:
        presets = [suite(p) for p in presets]
    made: list[RecordingKalman] = []

    def factory(*args: Any, **kw: Any) -> RecordingKalman:
        made.append(RecordingKalman(*args, **kw))
        return made[-1]

    batched.simulate(
        scs,
        vehicles,
        registry.smc_params(V),
        estimator="kf",
        actuators="mixer",
        sensors=presets,
        seeds=[int(d["sensor_seed"]) for d in draws],
        load_sensor=load_sensor,
        tuning=tuning,
        kf_factory=factory,
    )
    return made[0], draws


def _replay(c: np.ndarray, calls: list[tuple[Any, ...]]) -> tuple[float, int, int, np.ndarray, np.ndarray]:
    """One run's recorded calls into the kernels: the worst error of an estimate (relative to the numpy value, or
    absolute where it is below 1), how many estimates were compared and how many equal bit for bit, and the final
    state ``f``, ``n``."""
    f, n = kf_new_state(c)
    out = np.empty(EST_SIZE)
    worst, count, same = 0.0, 0, 0
    for call in calls:
        op = call[0]
        if op == "init":
            kf_initialize(c, f, n, call[1], call[2])
        elif op == "command":
            kf_push_command(c, f, n, call[1], call[2], call[3])
        elif op == "fuse":
            kf_fuse(c, f, n, call[1], call[2], call[3])
        elif op == "gyro":
            kf_fuse_gyro(c, f, n, call[1], call[2])
        elif op == "advance":
            kf_advance(c, f, n, call[1], call[2])
        else:
            kf_estimate(c, f, n, call[1], out)
            ref = call[2]
            assert np.isfinite(ref).all()  # the runs fly: a NaN would compare nothing
            worst = max(worst, float((np.abs(out - ref) / np.maximum(1.0, np.abs(ref))).max()))
            count += 1
            same += bool(np.array_equal(out, ref))
    return worst, count, same, f, n


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_kernels_replay_the_numpy_filter(case: str) -> None:
    """Three drawn runs' calls replayed into the kernels: every estimate (one per control tick) equals the numpy
    filter's to 1e-12 (relative, absolute below 1); the gates refused (and reopened) as many updates of each stream
    and end with the same counters; the flights had what each case is for (late records dropped, the cable sensor
    or the gyro, block advances, reopened gates, the external acceleration fed forward)."""
    load_sensor, tuning, suite = CASES[case]
    kf, draws = _flown(case)
    c = kf_constants(V, tuning, load_sensor=load_sensor, rate_hz=1000.0)
    for b in range(kf.B):
        calls = kf.calls[b]
        worst, count, same, _, n = _replay(c, calls)
        assert count > 1000  # every control tick's estimate
        assert worst <= 1e-12, f"run {b}: {worst:.3g} ({same} of {count} estimates bit-identical)"
        assert same >= count // 2  # most are bit-identical: only np.tan's last bits differ (module docstring)
        np.testing.assert_array_equal(n[N_REFUSED : N_REFUSED + len(STREAMS)], kf.refused[b])
        assert n[N_REOPENED] == kf.reopened[b]
        gated_run = [kf.gated_run[s][b] for s in STREAMS]
        np.testing.assert_array_equal(n[N_GATED_RUN : N_GATED_RUN + len(STREAMS)], gated_run)
        fused = {call[1] for call in calls if call[0] == "fuse"}
        assert fused == ({POS, ATT, IMU, LOAD} if load_sensor else {POS, ATT, IMU})
        assert any(call[0] == "gyro" for call in calls) == tuning.fuse_gyro
    # a run's position records came past the 12 ms horizon (latency above it) and were dropped: it fused fewer
    # (not at 10 Hz: the kinematic blocks, moved by nothing else, are then older than any record)
    assert max(d["sensor_latency_s"] for d in draws) > 0.006
    positions = [sum(call[:2] == ("fuse", POS) for call in kf.calls[b]) for b in range(kf.B)]
    assert suite is _slow or min(positions) < 0.9 * max(positions), positions
    assert kf.refused.sum() > 0  # the gates refused updates: the refusal branches were replayed
    if tuning.gate_reopen <= 1:
        assert kf.reopened.sum() > 0  # and reopened
    if suite is _slow:  # blocks left behind by the slow streams were advanced by the schedule
        assert sum(call[0] == "advance" for b in range(kf.B) for call in kf.calls[b]) > 100
    if tuning.external_feedforward:  # the feed-forward moved the estimate (the kernels' branch was taken)
        c[C_EXTERNAL_FF] = 0.0
        assert max(_replay(c, kf.calls[b])[0] for b in range(kf.B)) > 1e-6


def test_constants_follow_the_tuning_and_refuse_a_vehicle_without_a_load() -> None:
    """Every constant slot is filled (NaN-free), the thrust window follows the control rate, a nominal vehicle
    without a load is refused as the numpy filter refuses it, and so is a tuning without the commanded tilt input
    (the kernels always take it)."""
    from dataclasses import replace

    from offboard.harness.compiled.kf import C_GATE_REOPEN, C_N_THRUST

    c = kf_constants(V, MeasuredTuning(gate_reopen=7), load_sensor=True, rate_hz=250.0)
    assert np.isfinite(c).all()
    assert c[C_N_THRUST] == 25 and c[C_GATE_REOPEN] == 7
    f, n = kf_new_state(c)
    assert f.dtype == np.float64 and n.dtype == np.int64 and f.size > 25
    with pytest.raises(ValueError, match="load"):
        kf_constants(replace(V, mass_load=0.0), MeasuredTuning(), load_sensor=False)
    # a tuning the kernels cannot fly (no commanded tilt input) is refused, not flown as another filter
    with pytest.raises(ValueError, match="tilt_command"):
        kf_constants(V, MeasuredTuning(tilt_command=False), load_sensor=True)
    from estimators.filters.batched_kf import BatchedMeasuredKalman

    with pytest.raises(ValueError, match="tilt_command"):  # nor does the numpy batched filter, whose twin they are
        BatchedMeasuredKalman(V, 4, load_sensor=True, tuning=MeasuredTuning(tilt_command=False))
    BatchedMeasuredKalman(V, 4, load_sensor=True, tuning=MeasuredTuning())


#: the codes of the recorded calls in :func:`_encoded` (the order of ``_replay``'s branches)
_OPS = ("init", "command", "fuse", "gyro", "advance", "estimate")


def _encoded(calls: list[tuple[Any, ...]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A run's recorded calls as arrays for :func:`_replay_compiled`: the call's code (``_OPS``), its kind or block,
    its time (s) and its floats (the guess, the command's torques and thrust, the record's fields)."""
    m = len(calls)
    op, kind, t, val = np.zeros(m, np.int64), np.zeros(m, np.int64), np.zeros(m), np.zeros((m, EST_SIZE))
    for i, call in enumerate(calls):
        op[i] = _OPS.index(call[0])
        if call[0] == "command":
            val[i, :3] = call[1:4]
            continue
        if call[0] in ("fuse", "advance"):
            kind[i], call = call[1], call[1:]
        t[i] = call[1]
        if len(call) > 2 and call[0] != "estimate":
            val[i, : call[2].size] = call[2]
    return op, kind, t, val


@numba.njit
def _replay_compiled(
    c: np.ndarray, f: np.ndarray, n: np.ndarray, calls: tuple[np.ndarray, ...], out: np.ndarray
) -> None:
    op, kind, t, val = calls
    for i in range(op.size):
        code = op[i]
        if code == 0:
            kf_initialize(c, f, n, t[i], val[i])
        elif code == 1:
            kf_push_command(c, f, n, val[i, 0], val[i, 1], val[i, 2])
        elif code == 2:
            kf_fuse(c, f, n, kind[i], t[i], val[i])
        elif code == 3:
            kf_fuse_gyro(c, f, n, t[i], val[i])
        elif code == 4:
            kf_advance(c, f, n, kind[i], t[i])
        else:
            kf_estimate(c, f, n, t[i], out)


@numba.njit
def _fuse_records(
    c: np.ndarray, f: np.ndarray, n: np.ndarray, kind: int, times: np.ndarray, z: np.ndarray, i0: int
) -> None:
    for i in range(i0, times.size):
        kf_fuse(c, f, n, kind, times[i], z[i])


@numba.njit
def _estimates(c: np.ndarray, f: np.ndarray, n: np.ndarray, t0: float, count: int, out: np.ndarray) -> None:
    for i in range(count):
        kf_estimate(c, f, n, t0 + 1e-6 * i, out)


def _best(fn: Callable[[], Any], repeats: int = 5) -> float:
    """The shortest wall time of ``repeats`` calls of ``fn`` (s): the least disturbed by the machine's other load."""
    best = math.inf
    for _ in range(repeats):
        w0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - w0)
    return best


@pytest.mark.slow
def test_kernel_timings() -> None:
    """ns per control tick of a recorded run's whole call sequence, and per call of ``kf_fuse`` (per record kind, the
    run's records of that kind fused in order from the initial state) and ``kf_estimate`` (the state after the run,
    output times just ahead of the blocks), all called from compiled code as the engine calls them; printed
    (``pytest -s``) and bounded loosely (a kernel that fell off the compiled path would take tens of microseconds).
    The estimates of the compiled replay are the Python-driven replay's (the same kernels, called from numba)."""
    kf, _ = _flown("default")
    c = kf_constants(V, MeasuredTuning(), load_sensor=True, rate_hz=1000.0)
    calls = kf.calls[0]
    encoded = _encoded(calls)
    ticks = int((encoded[0] == _OPS.index("estimate")).sum())
    f, n = kf_new_state(c)
    out = np.empty(EST_SIZE)
    _replay_compiled(c, f, n, encoded, out)  # compiled before the clock starts
    _, _, _, f_ref, n_ref = _replay(c, calls)
    np.testing.assert_array_equal(f, f_ref)
    np.testing.assert_array_equal(n, n_ref)
    report = {"per tick": _best(lambda: _replay_compiled(c, f, n, encoded, out)) / ticks * 1e9}
    for kind, name in ((POS, "pos"), (ATT, "att"), (IMU, "imu"), (LOAD, "load")):
        recs = [call for call in calls if call[:2] == ("fuse", kind)]
        times = np.array([r[2] for r in recs])
        z = np.zeros((len(recs), 6))
        for i, r in enumerate(recs):
            z[i, : r[3].size] = r[3]

        def fuse_all(times: np.ndarray = times, z: np.ndarray = z, kind: int = kind) -> None:
            kf_initialize(c, f, n, 0.0, calls[0][2])
            _fuse_records(c, f, n, kind, times, z, 0)

        fuse_all()
        init = _best(lambda: kf_initialize(c, f, n, 0.0, calls[0][2]))
        report[f"kf_fuse {name}"] = (_best(fuse_all) - init) / len(recs) * 1e9
    count = 100_000
    _estimates(c, f_ref, n_ref, calls[-1][1], 1, out)
    report["kf_estimate"] = _best(lambda: _estimates(c, f_ref, n_ref, calls[-1][1], count, out)) / count * 1e9
    print({k: round(v) for k, v in report.items()})
    assert all(v < 20_000 for v in report.values()), report
