"""A run's sensor records and the Kalman filter's events, compiled: before a run, from its generator alone, when the
scalar path's ``SensorSuite`` samples each record (plant steps and times, s), with which noise (units of its fields),
when it is delivered, and which records ``estimators.filters.measured_kf``'s queues fuse at each control tick, in which
order, with which block advances; the run's generator is left in the scalar path's state. Over 500 lines because it
is one replica of the sensors' timing and the filter's queues, whose parts share the same state arrays; much of it is
kernel signatures, one argument per line. ``tests/schedule_reference.py`` is its oracle (the same arrays to the bit).
The kernels mirror the scalar sensors and the filter's queues statement by statement:

- the generator is the run's ``np.random.Generator`` itself, passed into the kernels: numba draws ``uniform``,
  ``random``, ``standard_normal`` and ``normal`` with numpy's own algorithms on the same bit generator, so the
  draws, their order (bias; then per stream, at the first call, its phase; per record its noise, then its
  jitter) and the generator's final state are the scalar path's;
- the three queues (records in flight, the filter's attitude records and its other records) are binary heaps in
  arrays ordered by (time, sequence number) as ``heapq`` orders the Python path's tuples; the sequence numbers
  are unique, so the pop order is the same whatever the heap's layout;
- times are compared with the scalar code's ``+ 1e-9`` tolerances and accumulated (``next_t += period``) in the
  same order of operations.

A queue row holds its sequence number, record kind and record number as floats (exact: they stay far below 2**53)
so that one array carries a whole entry.

Speed: numba counts the references to the arrays a function is given with atomic operations (10-20 ns each here)
and drops the pairs it can prove useless, which it often cannot when a function's last use of an array is on some
of its paths only. Left in the per-tick loop, they made the schedule three times slower (about 4 ms a 13 s run
instead of 1.3 ms). Hence a few forms chosen for that reason: an empty heap's first time is +inf (a due test reads
it on every path, with no count test before it), a rejected entry is written to its queue's spare last row rather
than not at all, overflows are counted rather than raised (the wrapper raises), and the per-tick and per-step due
tests sit in the run's own loop, which calls the heavier kernels only when there is work. The heap operations,
``_fuse`` and ``_emit`` are kernels of their own rather than inlined at each call: that cut the compile time
(paid once per machine, ``cache=True``) from about 10 s to 6 s at no cost in speed. Every kernel but the two that
allocate (``schedule_kernel``, ``_draw_bias``) is a ``layout.pure_kernel``, without reference counting at all: the
remaining counts, on every call of ``_sensors_at`` and the heap operations, were still 6 % of a sweep's CPU time
(0.93 ms a run before, 0.52 ms after).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.kernels import ADVANCE, ATT, FIELDS, GYRO, IMU, LOAD, POS, inline_kernel, kernel, pure_kernel
from sim_bridge.plant.sensors import preset_spec


@dataclass
class RunSchedule:
    """One run's records: per kind (``layout.POS``, ``ATT``, ``IMU``, ``LOAD``) the sampling plant steps (int), times
    (s) and noise (n, fields); the filter's events ``(tick, slot, code)`` with their ``payload`` (the record's number
    of its kind, or a block advance's time); the accelerometer bias (3,)."""

    steps: list[np.ndarray]
    times: list[np.ndarray]
    noise: list[np.ndarray]
    events: np.ndarray
    payload: np.ndarray
    bias: np.ndarray


# ---- the stream table: one row per sensor stream, in SensorSuite's order (position, attitude, imu[, load]) ----
S_PERIOD = 0  # s, 1 / rate
S_LATENCY = 1  # s
S_JITTER = 2  # s, the delivery delay's uniform part is in [0, jitter)
S_NOISY = 3  # 1.0 when a sigma is non-zero (SensorSuite._noise draws), else 0.0 (zeros without a draw)
S_FIELDS = 4  # the record's fields after its time (layout.FIELDS)
S_SIGMA = 5  # the noise standard deviation of each of those fields (units of the fields)
S_SIZE = S_SIGMA + 6

# ---- a queue row (an entry of a heap) ----
Q_TIME = 0  # s: delivery time (records in flight) or sampling time (the filter's queues)
Q_SEQ = 1  # the queue owner's sequence number, which orders entries of equal time
Q_CODE = 2  # record kind (POS, ATT, IMU, LOAD, or GYRO in the filter's attitude queue)
Q_REC = 3  # the record's number of its kind
Q_SIZE = 4

# ---- the filter's clock: its block times and latest estimate time (s) ----
C_BT = 0  # 8 block times: kin x, y, z, tilt x, y, heading, swing x, y
C_T_OUT = 8
C_SIZE = 9
B_HEADING = 5
#: the blocks a record of each kind updates (bit i: block i); an IMU gyro: the attitude's
_POS_BLOCKS = 0b00000111
_ATT_BLOCKS = 0b00111000
_IMU_BLOCKS = 0b11111111
_LOAD_BLOCKS = 0b11000000
#: the blocks a non-attitude record must not be older than (kin x, y, z, swing x, y)
_NOT_ATT_BLOCKS = 0b11000111

# ---- counters; the first three are also the queues' index in the queues array ----
N_DELIVERY = 0  # entries of the records in flight (SensorSuite._pending)
N_ATT = 1  # entries of the filter's attitude records and IMU gyros (_DryFilter.pending_att)
N_PENDING = 2  # entries of the filter's other records (_DryFilter.pending)
N_SUITE_SEQ = 3  # SensorSuite._seq
N_FILTER_SEQ = 4  # _DryFilter.seq
N_EVENTS = 5  # events written
N_OVERFLOW = 6  # records or events left out for want of rows (0 unless capacities() is wrong)
N_RECORDS = 7  # 4 counters: records of each kind (POS, ATT, IMU, LOAD)
N_SIZE = N_RECORDS + 4

#: the scalar path's time tolerance (s) of sampling and delivery
_EPS = 1e-9
#: the filter's longest wait before a block is advanced without a record (s), ``measured_kf``'s
_MAX_GAP = 0.05


def _sigmas(code: int, noise: tuple[float, ...]) -> tuple[float, ...]:
    """The noise standard deviations of a record's fields from its ``SensorSpec.noise`` (``SensorSuite._measure``)."""
    if code == POS:
        sxy, sz, svxy, svz = noise
        return (sxy, sxy, sz, svxy, svxy, svz)
    if code == ATT:
        sa, sy, sr = noise
        return (sa, sa, sy, sr, sr, sr)
    if code == IMU:
        sa, sg = noise
        return (sa, sa, sa, sg, sg, sg)
    return (noise[0], noise[0])


def stream_table(preset: Any, load_sensor: bool) -> np.ndarray:
    """The streams of ``SensorSuite(preset, ..., load_sensor=load_sensor)`` (``preset``: a ``Preset``), one row each
    (``S_*`` columns); row i is the stream of record kind i (POS, ATT, IMU, LOAD)."""
    specs = [preset.position, preset.attitude, preset.imu] + ([preset.load] if load_sensor else [])
    table = np.zeros((len(specs), S_SIZE))
    for code, spec in enumerate(specs):
        sig = _sigmas(code, spec.noise)
        table[code, S_PERIOD] = 1.0 / spec.rate_hz  # as sim_bridge.plant.sensors._Stream
        table[code, S_LATENCY] = spec.latency_s
        table[code, S_JITTER] = spec.jitter_s
        table[code, S_NOISY] = 1.0 if any(sig) else 0.0
        table[code, S_FIELDS] = FIELDS[code]
        table[code, S_SIGMA : S_SIGMA + len(sig)] = sig
    return table


def capacities(streams: np.ndarray, n_steps: int, plant_dt: float) -> tuple[int, int]:
    """Rows to allocate: records per kind, and filter events, of a run of ``n_steps`` plant steps (``plant_dt``, s).

    A stream samples at most once per plant step, and its samples are a period apart (from a phase > 0) but for
    the 1e-9 s tolerance, hence ``span / period + 1`` (+2 for rounding). Each record is fused at most twice (an
    IMU record's gyro), and each block advance moves its block time (in [0, span]) on by more than 0.05 s."""
    span = n_steps * plant_dt
    per_kind = max([min(n_steps, int(span / p) + 3) for p in streams[:, S_PERIOD]] + [1])
    events = 2 * len(streams) * per_kind + 8 * (int(span / _MAX_GAP) + 2)
    return per_kind, events


# ---- heaps ---------------------------------------------------------------------------------------------------


@inline_kernel
def _before(t: float, seq: float, t2: float, seq2: float) -> bool:
    """(t, seq) < (t2, seq2): heapq's order of the Python path's (time, sequence number, record) tuples."""
    return t < t2 or (t == t2 and seq < seq2)


@inline_kernel
def _copy_row(q: np.ndarray, which: int, dst: int, src: int) -> None:
    """q[which, dst] = q[which, src]: a heap entry moved."""
    q[which, dst, Q_TIME] = q[which, src, Q_TIME]
    q[which, dst, Q_SEQ] = q[which, src, Q_SEQ]
    q[which, dst, Q_CODE] = q[which, src, Q_CODE]
    q[which, dst, Q_REC] = q[which, src, Q_REC]


@pure_kernel
def _heap_push(
    q: np.ndarray, cnt: np.ndarray, which: int, t: float, seq: int, code: int, rec: int, accept: bool
) -> None:
    """Add (t s, seq, code, rec) to the heap q[which, :cnt[which]] (heapq.heappush: sift the entry up) if
    ``accept``; else write it to q's last row, never a heap entry (a store on every path: module docstring)."""
    i = cnt[which] if accept else q.shape[1] - 1
    cnt[which] += accept
    while accept and i > 0:
        parent = (i - 1) >> 1
        if not _before(t, seq, q[which, parent, Q_TIME], q[which, parent, Q_SEQ]):
            break
        _copy_row(q, which, i, parent)
        i = parent
    q[which, i, Q_TIME] = t
    q[which, i, Q_SEQ] = seq
    q[which, i, Q_CODE] = code
    q[which, i, Q_REC] = rec


@pure_kernel
def _heap_pop(q: np.ndarray, cnt: np.ndarray, which: int) -> tuple[float, int, int]:
    """Remove the first entry of the heap q[which, :cnt[which]] (not empty); its (time s, code, record number).
    An emptied heap's first time becomes +inf."""
    t, code, rec = q[which, 0, Q_TIME], int(q[which, 0, Q_CODE]), int(q[which, 0, Q_REC])
    n = cnt[which] - 1
    cnt[which] = n
    # the last entry (row n) goes to the root and down to its place (heapq.heappop)
    lt, ls = q[which, n, Q_TIME], q[which, n, Q_SEQ]
    i = 0
    child = 1
    while child < n:
        c2 = child + 1
        if c2 < n and _before(
            q[which, c2, Q_TIME], q[which, c2, Q_SEQ], q[which, child, Q_TIME], q[which, child, Q_SEQ]
        ):
            child = c2
        if not _before(q[which, child, Q_TIME], q[which, child, Q_SEQ], lt, ls):
            break
        _copy_row(q, which, i, child)
        i = child
        child = 2 * i + 1
    _copy_row(q, which, i, n)
    q[which, 0, Q_TIME] = q[which, 0, Q_TIME] if n > 0 else np.inf
    return t, code, rec


# ---- the sensors (SensorSuite.sample) --------------------------------------------------------------------------


@kernel
def _draw_bias(rng: np.random.Generator, sigma: float) -> np.ndarray:
    """The accelerometer's constant bias (3,) m/s^2 body FLU: three normals of ``sigma``, no draw when it is 0."""
    bias = np.zeros(3)
    if sigma > 0.0:
        for k in range(3):
            bias[k] = rng.normal(0.0, sigma)
    return bias


@inline_kernel
def _record(
    rng: np.random.Generator,
    streams: np.ndarray,
    code: int,
    t: float,
    step: int,
    rec_step: np.ndarray,
    rec_time: np.ndarray,
    rec_noise: np.ndarray,
    cnt: np.ndarray,
) -> int:
    """Store a record of kind ``code`` sampled at plant step ``step`` (time ``t``, s) with its noise drawn as
    ``SensorSuite._noise`` draws it (z * sigma, field by field; no draw when all sigmas are 0); its number."""
    k = cnt[N_RECORDS + code]
    full = k == rec_step.shape[1]  # counted, not raised: a raise would keep the reference counting
    cnt[N_OVERFLOW] += full
    k -= full
    cnt[N_RECORDS + code] = k + 1
    rec_step[code, k] = step
    rec_time[code, k] = t
    noisy = streams[code, S_NOISY] != 0.0
    for j in range(int(streams[code, S_FIELDS])):
        rec_noise[code, k, j] = rng.standard_normal() * streams[code, S_SIGMA + j] if noisy else 0.0
    return k


@inline_kernel
def _sample(
    rng: np.random.Generator,
    streams: np.ndarray,
    random_phase: bool,
    t: float,
    step: int,
    next_t: np.ndarray,
    rec_step: np.ndarray,
    rec_time: np.ndarray,
    rec_noise: np.ndarray,
    queues: np.ndarray,
    cnt: np.ndarray,
) -> None:
    """``SensorSuite.sample``'s sampling at plant time ``t`` (s), plant step ``step``: each stream due records and
    queues its record for delivery after its latency and jitter. ``next_t``: each stream's next sampling time
    (s; NaN before the first call, which draws the stream's phase)."""
    for i in range(streams.shape[0]):
        period = streams[i, S_PERIOD]
        if math.isnan(next_t[i]):
            next_t[i] = t + (rng.uniform(0.0, period) if random_phase else 0.0)
        if t + _EPS < next_t[i]:
            continue
        rec = _record(rng, streams, i, t, step, rec_step, rec_time, rec_noise, cnt)
        jitter = streams[i, S_JITTER]
        delay = streams[i, S_LATENCY] + (jitter * rng.random() if jitter > 0.0 else 0.0)
        _heap_push(queues, cnt, N_DELIVERY, t + delay, cnt[N_SUITE_SEQ], i, rec, True)
        cnt[N_SUITE_SEQ] += 1
        while next_t[i] <= t + _EPS:
            next_t[i] += period


# ---- the filter's queues (measured_kf's, times only) -------------------------------------------------------------


@inline_kernel
def _filter_push(
    code: int,
    rec: int,
    t: float,
    clock: np.ndarray,
    queues: np.ndarray,
    cnt: np.ndarray,
    load_sensor: bool,
    fuse_gyro: bool,
) -> None:
    """Queue a delivered record (sampled at ``t``, s) for fusion, unless a block it updates is already past ``t``
    (a late record): an attitude record to the attitude queue, an IMU gyro to it too (with ``fuse_gyro``), any
    other record to the other queue; each queued one takes the next sequence number."""
    heading = clock[C_BT + B_HEADING]
    oldest = np.inf  # Python's min() of the blocks a non-attitude record must not be older than
    for bi in range(8):
        b = clock[C_BT + bi]
        if (_NOT_ATT_BLOCKS >> bi) & 1 and b < oldest:
            oldest = b
    wanted = load_sensor or code != LOAD
    gyro = wanted and code == IMU and fuse_gyro and t >= heading
    att = wanted and code == ATT and not t < heading
    other = wanted and code != ATT and not t < oldest
    seq = cnt[N_FILTER_SEQ]
    _heap_push(queues, cnt, N_ATT, t, seq, GYRO, rec, gyro)
    seq += gyro
    _heap_push(queues, cnt, N_ATT, t, seq, ATT, rec, att)
    seq += att
    _heap_push(queues, cnt, N_PENDING, t, seq, code, rec, other)
    cnt[N_FILTER_SEQ] = seq + other


@pure_kernel
def _fuse(clock: np.ndarray, code: int, t: float) -> None:
    """The block times after fusing a record of kind ``code`` sampled at ``t`` (s): each of its blocks moved on to
    ``t`` if it is later (each block on its own: the order of measured_kf's updates does not matter here)."""
    if code == POS:
        blocks = _POS_BLOCKS
    elif code == IMU:
        blocks = _IMU_BLOCKS
    elif code == LOAD:
        blocks = _LOAD_BLOCKS
    else:  # ATT, GYRO
        blocks = _ATT_BLOCKS
    for bi in range(8):
        b = clock[C_BT + bi]
        clock[C_BT + bi] = t if (blocks >> bi) & 1 and t - b > 0.0 else b


@pure_kernel
def _emit(events: np.ndarray, payload: np.ndarray, cnt: np.ndarray, tick: int, first: int, code: int, p: float) -> None:
    """Append the event (tick, slot, code) with its payload ``p``; ``first``: the row of the tick's first event."""
    n = cnt[N_EVENTS]
    full = n == events.shape[0]  # counted, not raised (see _record)
    cnt[N_OVERFLOW] += full
    n -= full
    cnt[N_EVENTS] = n + 1
    events[n, 0] = tick
    events[n, 1] = n - first
    events[n, 2] = code
    payload[n] = p


@inline_kernel
def _horizon(t: float, delay: float, t_out: float) -> float:
    """The filter's fusion horizon (s) at time ``t`` (s): ``min(t - delay, t_out)`` as Python's min() gives it."""
    return t_out if t_out < t - delay else t - delay


@inline_kernel
def _filter_due(t: float, delay: float, clock: np.ndarray, queues: np.ndarray) -> bool:
    """``_DryFilter.estimate``'s preamble at time ``t`` (s): the latest estimate time moved on to ``t``; whether a
    record is due or a block is more than 0.05 s behind the horizon (if not, the filter does nothing: most ticks)."""
    t_out = t if t > clock[C_T_OUT] else clock[C_T_OUT]
    clock[C_T_OUT] = t_out
    horizon = _horizon(t, delay, t_out)
    oldest = clock[C_BT]  # Python's min() of the block times
    for bi in range(1, 8):
        if clock[C_BT + bi] < oldest:
            oldest = clock[C_BT + bi]
    att_top, other_top = queues[N_ATT, 0, Q_TIME], queues[N_PENDING, 0, Q_TIME]  # on every path: module docstring
    return att_top <= t_out or other_top <= horizon or horizon - oldest > _MAX_GAP


@pure_kernel
def _estimate(
    tick: int,
    t: float,
    delay: float,
    clock: np.ndarray,
    queues: np.ndarray,
    cnt: np.ndarray,
    events: np.ndarray,
    payload: np.ndarray,
) -> None:
    """The filter's events at control tick ``tick`` (time ``t``, s; fusion horizon ``delay`` s behind it): the
    attitude records up to the latest estimate time, the others up to the horizon, each in (time, sequence)
    order, then the advances of the blocks left more than 0.05 s behind the horizon (after :func:`_filter_due`)."""
    t_out = clock[C_T_OUT]
    horizon = _horizon(t, delay, t_out)
    first = cnt[N_EVENTS]
    while queues[N_ATT, 0, Q_TIME] <= t_out:  # +inf when empty
        tt, code, rec = _heap_pop(queues, cnt, N_ATT)
        _emit(events, payload, cnt, tick, first, code, float(rec))
        _fuse(clock, code, tt)
    while queues[N_PENDING, 0, Q_TIME] <= horizon:
        tt, code, rec = _heap_pop(queues, cnt, N_PENDING)
        _emit(events, payload, cnt, tick, first, code, float(rec))
        _fuse(clock, code, tt)
    for bi in range(8):
        if horizon - clock[C_BT + bi] > _MAX_GAP:
            clock[C_BT + bi] = horizon
            _emit(events, payload, cnt, tick, first, ADVANCE + bi, horizon)


@inline_kernel
def _deliver(
    t: float,
    rec_time: np.ndarray,
    clock: np.ndarray,
    queues: np.ndarray,
    cnt: np.ndarray,
    load_sensor: bool,
    fuse_gyro: bool,
) -> None:
    """``SensorSuite.sample``'s delivery at plant time ``t`` (s): the records in flight due by then, in (delivery
    time, sequence) order, handed to the filter's queues with their sampling times."""
    while queues[N_DELIVERY, 0, Q_TIME] <= t + _EPS:  # +inf when empty
        _, code, rec = _heap_pop(queues, cnt, N_DELIVERY)
        _filter_push(code, rec, rec_time[code, rec], clock, queues, cnt, load_sensor, fuse_gyro)


@pure_kernel
def _sensors_at(
    rng: np.random.Generator,
    streams: np.ndarray,
    random_phase: bool,
    t: float,
    step: int,
    next_t: np.ndarray,
    rec_step: np.ndarray,
    rec_time: np.ndarray,
    rec_noise: np.ndarray,
    clock: np.ndarray,
    queues: np.ndarray,
    cnt: np.ndarray,
    load_sensor: bool,
    fuse_gyro: bool,
) -> float:
    """``SensorSuite.sample`` at plant time ``t`` (s), plant step ``step``, its delivered records handed to the
    filter's queues; the next time (s) a stream is due (Python's min() of ``next_t``)."""
    _sample(rng, streams, random_phase, t, step, next_t, rec_step, rec_time, rec_noise, queues, cnt)
    _deliver(t, rec_time, clock, queues, cnt, load_sensor, fuse_gyro)
    next_due = next_t[0]
    for j in range(1, next_t.shape[0]):
        if next_t[j] < next_due:
            next_due = next_t[j]
    return next_due


# ---- a run -----------------------------------------------------------------------------------------------------


@kernel
def schedule_kernel(
    rng: np.random.Generator,
    streams: np.ndarray,
    random_phase: bool,
    bias_sigma: float,
    n_ticks: int,
    control_dt: float,
    plant_dt: float,
    substeps: int,
    load_sensor: bool,
    delay_s: float,
    fuse_gyro: bool,
    rec_cap: int,
    ev_cap: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One run's records and filter events, drawing from ``rng`` as the scalar path does (module docstring).

    streams: :func:`stream_table`; random_phase: the preset's; bias_sigma: its accel_bias (m/s^2); n_ticks
    control ticks of ``control_dt`` s, each ``substeps`` plant steps of ``plant_dt`` s; delay_s: the filter's
    fusion horizon (s); rec_cap, ev_cap: :func:`capacities`. Returns per kind (rows POS, ATT, IMU, LOAD) the
    sampling plant steps (4, rec_cap), times (4, rec_cap; s) and noise (4, rec_cap, 6; FIELDS[kind] used), the
    counters (``N_*``: the record counts, the overflow), the events (n, 3: tick, slot, code) and their payloads
    (n,: record number or advance time, s), and the accelerometer bias (3,; m/s^2 body FLU)."""
    bias = _draw_bias(rng, bias_sigma)
    # np.empty, not zeros: rows are read only once written (zeroing would cost page faults)
    rec_step = np.empty((4, rec_cap), dtype=np.int64)
    rec_time = np.empty((4, rec_cap))
    rec_noise = np.empty((4, rec_cap, 6))
    # a queue holds each record once at most (+1: the row rejected entries are written to)
    queues = np.empty((3, streams.shape[0] * rec_cap + 1, Q_SIZE))
    queues[:, 0, Q_TIME] = np.inf  # the heaps are empty
    cnt = np.zeros(N_SIZE, dtype=np.int64)
    clock = np.zeros(C_SIZE)
    events = np.empty((ev_cap, 3), dtype=np.int64)
    payload = np.empty(ev_cap)
    next_t = np.full(streams.shape[0], np.nan)
    next_due = -np.inf  # the first call draws the streams' phases
    step = 0
    for tick in range(n_ticks):
        t = tick * control_dt
        if _filter_due(t, delay_s, clock, queues):
            _estimate(tick, t, delay_s, clock, queues, cnt, events, payload)
        if tick == n_ticks - 1:
            break
        for i in range(substeps):
            ts = t + (i + 1) * plant_dt
            # a call with no stream due and nothing to deliver changes nothing: skipped, as the Python path does
            if ts + _EPS >= next_due or queues[N_DELIVERY, 0, Q_TIME] <= ts + _EPS:
                next_due = _sensors_at(
                    rng,
                    streams,
                    random_phase,
                    ts,
                    step,
                    next_t,
                    rec_step,
                    rec_time,
                    rec_noise,
                    clock,
                    queues,
                    cnt,
                    load_sensor,
                    fuse_gyro,
                )
            step += 1
    n_events = cnt[N_EVENTS]
    return rec_step, rec_time, rec_noise, cnt, events[:n_events], payload[:n_events], bias


# ---- the Python side -----------------------------------------------------------------------------------------


def schedule(
    preset: Any,
    vehicle: Any,
    seed: int,
    n_ticks: int,
    control_dt: float,
    plant_dt: float,
    substeps: int,
    *,
    load_sensor: bool,
    delay_s: float,
    fuse_gyro: bool,
) -> RunSchedule:
    """The records and filter events of one run of ``offboard.harness.sim.run`` (same generator seed, preset, steps):
    which records the scalar path's sensors sample when, with which noise, and when its filter fuses or drops each.

    preset: a preset name or a ``sim_bridge.plant.sensors.Preset``; vehicle: unused (the Python path's
    ``SensorSuite`` needs it for the values, which the schedule leaves out); seed: the run's generator seed."""
    rng = np.random.default_rng(seed)
    flags = {"load_sensor": load_sensor, "delay_s": delay_s, "fuse_gyro": fuse_gyro}
    return schedule_rng(preset, rng, n_ticks, control_dt, plant_dt, substeps, **flags)


def schedule_rng(
    preset: Any,
    rng: np.random.Generator,
    n_ticks: int,
    control_dt: float,
    plant_dt: float,
    substeps: int,
    *,
    load_sensor: bool,
    delay_s: float,
    fuse_gyro: bool,
) -> RunSchedule:
    """:func:`schedule` drawing from ``rng``, which it leaves in the state the scalar path leaves its generator in."""
    pr = preset_spec(preset) if isinstance(preset, str) else preset
    streams = stream_table(pr, load_sensor)
    rec_cap, ev_cap = capacities(streams, (n_ticks - 1) * substeps, plant_dt)
    # plain Python scalars: one compiled signature whatever types the caller passes
    phase, sigma = bool(pr.random_phase), float(pr.accel_bias)
    timing = (int(n_ticks), float(control_dt), float(plant_dt), int(substeps))
    filt = (bool(load_sensor), float(delay_s), bool(fuse_gyro))
    out = schedule_kernel(rng, streams, phase, sigma, *timing, *filt, rec_cap, ev_cap)
    rec_step, rec_time, rec_noise, cnt, events, payload, bias = out
    if cnt[N_OVERFLOW]:
        raise RuntimeError(f"{cnt[N_OVERFLOW]} records or events beyond capacities() {rec_cap, ev_cap}")
    count = cnt[N_RECORDS : N_RECORDS + 4]
    kinds = (POS, ATT, IMU, LOAD)
    return RunSchedule(
        steps=[rec_step[k, : count[k]].copy() for k in kinds],
        times=[rec_time[k, : count[k]].copy() for k in kinds],
        noise=[rec_noise[k, : count[k], : FIELDS[k]].copy() for k in kinds],
        events=events.copy(),
        payload=payload.copy(),
        bias=bias,
    )


__all__ = ["RunSchedule", "capacities", "schedule", "schedule_kernel", "schedule_rng", "stream_table"]
