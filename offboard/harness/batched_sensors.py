"""The sensors, the filter's record timing and the mixer of the batched sweep path, over many runs at once.

What a run's sensors sample, when, with which noise, when each record is delivered and when the Kalman filter
fuses it (or drops it as late) does not depend on the plant's state: it follows from the run's generator, the
stream rates, latencies and jitter, and the filter's fusion horizon. :func:`schedule` works it out per run
beforehand, with the scalar path's own :class:`sim_bridge.plant.sensors.SensorSuite` (its ``_measure`` replaced by one
that draws the same noise and returns no values, so that the generator's calls are the scalar path's, in its
order) and a replica of ``estimators.filters.measured_kf``'s queues that tracks only times. The batched loop then
computes the records' values from the plant's state at their sampling steps (:func:`measure`) and hands the
filter (``estimators.filters.batched_kf``) the records due at each tick in each run's own order.

Left out, as only a diverged run meets them: the filter's skip of an attitude record at a tilt of 90 degrees
and its re-initialization on a non-finite estimate.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.filters.batched_kf import ATT, GYRO, IMU, LOAD, POS
from sim_bridge.plant.sensors import SensorSuite

Array = np.ndarray
_KIND_CODE = {"position": POS, "attitude": ATT, "imu": IMU, "load": LOAD}
#: fields of a record of each kind after its time (``estimators.model.measurements``)
FIELDS = {POS: 6, ATT: 6, IMU: 6, LOAD: 2}
#: records kept per run and kind between sampling and fusion (a record waits a few samples at most: 30 Hz
#: positions fused 12 ms + latency after sampling, 100 Hz attitude at once)
RING = 32
#: the first code of a block advance (``code - ADVANCE`` is the block, ``estimators.filters.batched_kf.BLOCKS``)
ADVANCE = 4


class _DrySuite(SensorSuite):
    """The scalar sensors with the values left out: ``_measure`` draws the same noise and records it."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.step = 0
        self.records: list[tuple[int, int, float, list[float]]] = []  # (code, plant step, sample time, noise)
        self.count = [0, 0, 0, 0]

    def _measure(self, s: Any, t: float, x: Any, u: Any) -> Any:
        kind, sig = s.kind, s.spec.noise
        if kind == "position":
            sxy, sz, svxy, svz = sig
            e = self._noise((sxy, sxy, sz, svxy, svxy, svz), 6)
        elif kind == "attitude":
            sa, sy, sr = sig
            e = self._noise((sa, sa, sy, sr, sr, sr), 6)
        elif kind == "imu":
            sa, sg = sig
            e = self._noise((sa, sa, sa, sg, sg, sg), 6)
        else:
            e = self._noise((sig[0], sig[0]), 2)
        code = _KIND_CODE[kind]
        rec = (code, self.count[code], t)
        self.count[code] += 1
        self.records.append((code, self.step, t, e))
        return rec


class _DryFilter:
    """``estimators.filters.measured_kf.MeasuredKalmanEstimator``'s queues and block times, without the values."""

    def __init__(self, delay_s: float, load_sensor: bool, fuse_gyro: bool) -> None:
        self.delay = delay_s
        self.load_sensor = load_sensor
        self.fuse_gyro = fuse_gyro
        self.bt = [0.0] * 8
        self.t_out = 0.0
        self.pending: list[tuple[float, int, tuple[int, int]]] = []
        self.pending_att: list[tuple[float, int, tuple[int, int]]] = []
        self.seq = 0
        self.events: list[tuple[int, float]] = []  # (code, record number or advance time) of this estimate

    def push(self, code: int, rec: int, t: float) -> None:
        bt = self.bt
        if code == LOAD and not self.load_sensor:
            return
        if code == ATT:
            if t < bt[5]:
                return
            heapq.heappush(self.pending_att, (t, self.seq, (code, rec)))
            self.seq += 1
            return
        if code == IMU and self.fuse_gyro and t >= bt[5]:  # its gyro goes with the attitude records (its own event)
            heapq.heappush(self.pending_att, (t, self.seq, (GYRO, rec)))
            self.seq += 1
        if t < min(bt[0], bt[1], bt[2], bt[6], bt[7]):
            return
        heapq.heappush(self.pending, (t, self.seq, (code, rec)))
        self.seq += 1

    def _advance(self, bi: int, t: float) -> None:
        if t - self.bt[bi] > 0.0:
            self.bt[bi] = t

    def _fuse(self, t: float, code: int, rec: int) -> None:
        self.events.append((code, float(rec)))
        adv = self._advance
        if code == POS:
            adv(0, t), adv(1, t), adv(2, t)
        elif code in (ATT, GYRO):
            adv(3, t), adv(4, t), adv(5, t)
        elif code == IMU:
            for bi in (0, 1, 2, 6, 7, 3, 4, 5):
                adv(bi, t)
        else:
            adv(6, t), adv(7, t)

    def estimate(self, t: float) -> list[tuple[int, float]]:
        if t > self.t_out:
            self.t_out = t
        horizon = min(t - self.delay, self.t_out)
        pa, pe = self.pending_att, self.pending
        if not ((pa and pa[0][0] <= self.t_out) or (pe and pe[0][0] <= horizon) or horizon - min(self.bt) > 0.05):
            return []  # nothing to fuse or advance at this tick (most ticks of most runs)
        self.events = []
        while pa and pa[0][0] <= self.t_out:
            tt, _, (code, rec) = heapq.heappop(pa)
            self._fuse(tt, code, rec)
        while pe and pe[0][0] <= horizon:
            tt, _, (code, rec) = heapq.heappop(pe)
            self._fuse(tt, code, rec)
        for bi in range(8):
            if horizon - self.bt[bi] > 0.05:
                self.bt[bi] = horizon
                self.events.append((ADVANCE + bi, horizon))
        return self.events


@dataclass
class RunSchedule:
    """One run's records: per kind the sampling plant steps (int), times (s) and noise (n, fields); the filter's
    events ``(tick, slot, code, payload)`` (payload: the record's number of its kind, or an advance's time);
    the accelerometer bias (3,)."""

    steps: list[Array]
    times: list[Array]
    noise: list[Array]
    events: Array
    payload: Array
    bias: Array


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
    """The records of one run of ``offboard.harness.sim.run`` (same generator seed, preset, true vehicle and steps)."""
    suite = _DrySuite(preset, vehicle, np.random.default_rng(seed), load_sensor=load_sensor)
    filt = _DryFilter(delay_s, load_sensor, fuse_gyro)
    ev: list[tuple[int, int, int]] = []
    pay: list[float] = []
    step = 0
    streams, pending = suite._streams, suite._pending
    next_due = -math.inf  # the first call draws the streams' phases
    for tick in range(n_ticks):
        t = tick * control_dt
        for slot, (code, p) in enumerate(filt.estimate(t)):
            ev.append((tick, slot, code))
            pay.append(p)
        if tick == n_ticks - 1:
            break
        for i in range(substeps):
            ts = t + (i + 1) * plant_dt
            # a call with no stream due and nothing to deliver changes nothing: skipped
            if ts + 1e-9 >= next_due or (pending and pending[0][0] <= ts + 1e-9):
                suite.step = step
                for code, rec, tr in suite.sample(ts, None, None):
                    filt.push(code, rec, tr)
                next_due = min(st.next_t for st in streams)
            step += 1
    recs = suite.records
    steps, times, noise = [], [], []
    for code in (POS, ATT, IMU, LOAD):
        mine = [r for r in recs if r[0] == code]
        steps.append(np.array([r[1] for r in mine], dtype=int))
        times.append(np.array([r[2] for r in mine], dtype=float))
        noise.append(np.array([r[3] for r in mine], dtype=float).reshape(len(mine), FIELDS[code]))
    return RunSchedule(
        steps, times, noise, np.array(ev, dtype=int).reshape(-1, 3), np.array(pay), np.array(suite.accel_bias)
    )


class Records:
    """The runs' records over the batch: values (fields, B, R) and times (B, R) per kind, filled as the plant
    reaches each record's sampling step; and the per-step / per-tick groups the batched loop walks."""

    def __init__(self, runs: list[RunSchedule], n_steps: int, n_ticks: int) -> None:
        B = len(runs)
        self.B = B
        self.bias = np.array([r.bias for r in runs]).T  # (3, B)
        self.values: list[Array] = []  # per kind (fields, B, RING): a record's values at (run, number % RING)
        self.times: list[Array] = []  # per kind, flat over the runs' records (offset of the run + number)
        self.noise: list[Array] = []  # per kind (fields, records of all runs), the same flat index
        self.offset: list[Array] = []
        self.sample_groups: list[tuple[Array, Array, Array]] = []  # per kind: bounds per step, runs, record numbers
        for code in (POS, ATT, IMU, LOAD):
            f = FIELDS[code]
            self.values.append(np.full((f, B, RING), np.nan))
            counts = np.array([len(r.steps[code]) for r in runs], dtype=int)
            self.offset.append(np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int))
            self.times.append(np.concatenate([r.times[code] for r in runs]) if runs else np.zeros(0))
            self.noise.append(np.concatenate([r.noise[code] for r in runs]).T.copy() if runs else np.zeros((f, 0)))
            st = np.concatenate([r.steps[code] for r in runs]) if runs else np.zeros(0, dtype=int)
            rb = np.concatenate([np.full(len(r.steps[code]), b) for b, r in enumerate(runs)]).astype(int)
            rn = np.concatenate([np.arange(len(r.steps[code])) for r in runs]).astype(int)
            order = np.argsort(st, kind="stable")
            st, rb, rn = st[order], rb[order], rn[order]
            self.sample_groups.append((np.searchsorted(st, np.arange(n_steps + 1)), rb, rn))
        # the filter's events: grouped by (tick, slot, code); each group one kind of event for distinct runs
        ev = np.concatenate([r.events for r in runs]) if runs else np.zeros((0, 3), dtype=int)
        pay = np.concatenate([r.payload for r in runs]) if runs else np.zeros(0)
        run_of = np.concatenate([np.full(len(r.events), b) for b, r in enumerate(runs)]).astype(int)
        order = np.lexsort((ev[:, 2], ev[:, 1], ev[:, 0]))
        ev, pay, run_of = ev[order], pay[order], run_of[order]
        key = (ev[:, 0] * 64 + ev[:, 1]) * 16 + ev[:, 2]
        cut = np.flatnonzero(np.diff(key)) + 1
        starts = np.concatenate([[0], cut]) if len(key) else np.zeros(0, dtype=int)
        ends = np.concatenate([cut, [len(key)]]) if len(key) else np.zeros(0, dtype=int)
        self.tick_groups: list[list[tuple[int, Array, Array]]] = [[] for _ in range(n_ticks)]
        for s, e in zip(starts.tolist(), ends.tolist()):
            tick, code = int(ev[s, 0]), int(ev[s, 2])
            self.tick_groups[tick].append((code, run_of[s:e], pay[s:e]))

    def sampled(self, code: int, step: int) -> tuple[Array, Array] | None:
        """(runs, record numbers) of the runs whose sensor ``code`` samples at plant step ``step``."""
        bounds, rb, rn = self.sample_groups[code]
        a, b = bounds[step], bounds[step + 1]
        if a == b:
            return None
        return rb[a:b], rn[a:b]


def measure(code: int, x: Array, u: Array, deriv: Array | None, g: Array, bias: Array, e: Array) -> Array:
    """``SensorSuite._measure`` over runs: the record's fields (n, k) from the state ``x`` (18, k), the input ``u``
    (13, k), the plant derivative ``deriv`` (18, k; the accelerometer), gravity ``g`` (k,), the accelerometer bias
    (3, k) and the noise ``e`` (n, k)."""
    if code == POS:
        return x[0:6] + e
    if code == LOAD:
        r1, r2, r3 = x[12], x[13], x[14]
        ay, ax = np.arctan2(r1, -r3), np.arctan2(r2, -r3)
        return np.stack([ax + e[0], ay + e[1]])
    phi, theta = x[6], x[7]
    sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    p = x[9] - st * x[11]  # sim_bridge.plant.sensors.body_rates
    q = cf * x[10] + sf * ct * x[11]
    r = -sf * x[10] + cf * ct * x[11]
    if code == ATT:
        two_pi = 2.0 * math.pi
        w = np.fmod(x[8] + e[2] + math.pi, two_pi)
        psi = np.where(w <= 0.0, w + two_pi, w) - math.pi
        return np.stack([x[6] + e[0], x[7] + e[1], psi, p + e[3], q + e[4], r + e[5]])
    assert deriv is not None
    fx, fy, fz = deriv[3], deriv[4], deriv[5] + g  # sim_bridge.plant.sensors.specific_force_body
    sp, cp = np.sin(x[8]), np.cos(x[8])
    bx = cp * ct * fx + sp * ct * fy - st * fz
    by = (cp * st * sf - sp * cf) * fx + (sp * st * sf + cp * cf) * fy + ct * sf * fz
    bz = (cp * st * cf + sp * sf) * fx + (sp * st * cf - cp * sf) * fy + ct * cf * fz
    return np.stack([bx + bias[0] + e[0], by + bias[1] + e[1], bz + bias[2] + e[2], p + e[3], q + e[4], r + e[5]])


class BatchMixer:
    """``sim_bridge.inner.airframe.Mixer`` over runs (each its own arm, yaw coefficient, motor limit and lag)."""

    def __init__(self, vehicles: list[Any], dt: float) -> None:
        self.a = np.array([v.arm_length / math.sqrt(2.0) for v in vehicles])
        self.c = np.array([v.yaw_moment_coefficient for v in vehicles])
        self.fmax = np.array([v.motor_thrust_max for v in vehicles])
        taus = [v.motor_time_constant for v in vehicles]
        self.alpha = np.array([1.0 if tau <= 0.0 else 1.0 - math.exp(-dt / tau) for tau in taus])
        B = len(vehicles)
        self.f = np.zeros((4, B))
        self.cmd = np.zeros((4, B))

    def reset(self, thrust_each: Array) -> None:
        self.f = np.array([thrust_each] * 4, dtype=float)
        self.cmd = self.f.copy()

    def allocate(self, thrust: Array, tx: Array, ty: Array, tz: Array) -> None:
        fmax = self.fmax
        base = 0.25 * np.where(thrust < 4.0 * fmax, thrust, 4.0 * fmax)
        base = np.where(base < 0.0, 0.0, base)
        kx = tx / (4.0 * self.a)
        ky = ty / (4.0 * self.a)
        kz = tz / (4.0 * self.c)
        r = [kx - ky, -kx - ky, -kx + ky, kx + ky]
        lo = np.minimum(np.minimum(r[0], r[1]), np.minimum(r[2], r[3]))
        hi = np.maximum(np.maximum(r[0], r[1]), np.maximum(r[2], r[3]))
        span = hi - lo
        big = span > fmax
        s = np.where(big, fmax / np.where(big, span, 1.0), 1.0)
        r = [np.where(big, ri * s, ri) for ri in r]
        lo, hi = np.where(big, lo * s, lo), np.where(big, hi * s, hi)
        base = np.where(base + hi > fmax, fmax - hi, base)
        low = base + lo < 0.0
        s = np.where(low, base / np.where(low, -lo, 1.0), 1.0)
        r = [np.where(low, ri * s, ri) for ri in r]
        f0, f1, f2, f3 = base + r[0], base + r[1], base + r[2], base + r[3]
        pos, neg = kz > 0.0, kz < 0.0
        kzp = np.where(pos, kz, 1.0)
        kzn = np.where(neg, -kz, 1.0)
        k_pos = np.minimum(np.minimum(1.0, (fmax - f0) / kzp), np.minimum((fmax - f2) / kzp, f1 / kzp))
        k_pos = np.minimum(k_pos, f3 / kzp)
        k_neg = np.minimum(np.minimum(1.0, f0 / kzn), np.minimum(f2 / kzn, (fmax - f1) / kzn))
        k_neg = np.minimum(k_neg, (fmax - f3) / kzn)
        k = np.where(pos, k_pos, np.where(neg, k_neg, 1.0))
        k = np.where(k < 0.0, 0.0, k)
        y = k * kz
        out = np.stack([f0 + y, f1 - y, f2 + y, f3 - y])
        self.cmd = np.where(out < 0.0, 0.0, np.where(out > fmax, fmax, out))

    def _wrench(self, f: Array) -> Array:
        f0, f1, f2, f3 = f
        a = self.a
        return np.stack(
            [f0 + f1 + f2 + f3, a * (f0 - f1 - f2 + f3), a * (-f0 - f1 + f2 + f3), self.c * (f0 - f1 + f2 - f3)]
        )

    def step(self) -> Array:
        """Advance the lag one plant step; the actual (thrust, tau_x, tau_y, tau_z) (4, B)."""
        self.f = self.f + (self.cmd - self.f) * self.alpha
        return self._wrench(self.f)

    def wrench(self) -> Array:
        return self._wrench(self.f)


__all__ = ["ADVANCE", "FIELDS", "BatchMixer", "Records", "RunSchedule", "measure", "schedule"]
