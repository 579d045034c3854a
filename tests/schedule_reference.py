"""The tests' oracle for ``offboard.harness.compiled.schedule``: a run's sensor records and the Kalman filter's events
worked out in Python with the scalar path's own :class:`sim_bridge.plant.sensors.SensorSuite` (its ``_measure``
replaced by one that draws the same noise and returns no values, so that the generator's calls are the scalar
path's, in its order) and a replica of ``estimators.filters.measured_kf``'s queues that tracks only times.
``tests/test_compiled_schedule.py`` holds the compiled schedule to it array for array.
"""

from __future__ import annotations

import heapq
import math
from typing import Any

import numpy as np

from estimators.kernels import ADVANCE, ATT, FIELDS, GYRO, IMU, LOAD, POS
from offboard.harness.compiled.schedule import RunSchedule
from sim_bridge.plant.sensors import SensorSuite

_KIND_CODE = {"position": POS, "attitude": ATT, "imu": IMU, "load": LOAD}


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
