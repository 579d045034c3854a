"""The batched simulation path of ``slung sweep`` (``engine = "batched"``): many runs advanced together, every
quantity a numpy array over the runs, the same equations as the scalar path.

- plant: ``sim_bridge.plant.dynamics.derivative`` (paper attitude model, eq. (13)) and ``rk4_step`` with the cable
  projection, written once more over arrays (:func:`derivative`, :func:`rk4_step`), each run with its own masses,
  cable length, inertia and still-air drag (:func:`apply_drag`);
- controller: the sliding-mode law ``offboard.control.smc.step`` over arrays
  (``offboard.harness.batched_controllers.smc_step``: the same height, yaw and horizontal laws, saturation and
  anti-windup) or the stock cascade (``batched_controllers.CascadeStep``: the ``cascade`` row, and the ``zv`` /
  ``zvd`` rows behind the reference shaper, shared by all runs; ``SwingFeedbackStep``: ``swing-feedback``;
  ``LqrStep``: ``lqr``), on the estimator's state (below) with the controller's nominal vehicle;
- one reference for all runs (sampled once per tick), a 1 - cos gust and an initial swing per run.

Estimation and actuation, as in the scalar path: ``estimator = "truth"`` (the true state) or ``"kf"``, the
measured-input Kalman filter over arrays (``estimators.filters.batched_kf``) fed by each run's sensors, whose record
timing is worked out per run beforehand (``offboard.harness.batched_sensors``); ``actuators = "ideal"`` or
``"mixer"`` (four motors with each vehicle's lag). ``tests/test_sweep.py`` checks the batched sweep's table against
the scalar engine's on the same runs.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from estimators.model.flatness import flat_constants
from estimators.model.rotations import thrust_direction_trig
from offboard.control import smc

Array = np.ndarray


class BatchPlant:
    """Per-run plant constants (arrays over the runs, SI): M, m, l, g, inertia."""

    def __init__(self, vehicles: list[Any]) -> None:
        self.M = np.array([v.mass_vehicle for v in vehicles])
        self.m = np.array([v.mass_load for v in vehicles])
        self.l = np.array([v.cable_length for v in vehicles])
        self.g = np.array([v.gravity for v in vehicles])
        self.Ip = np.array([v.inertia[0] for v in vehicles])
        self.It = np.array([v.inertia[1] for v in vehicles])
        self.Is = np.array([v.inertia[2] for v in vehicles])
        self.Mt = self.M + self.m
        self.inv_l = 1.0 / self.l
        #: still-air drag (``sim_bridge.plant.dynamics.apply_drag``): N per m/s on the vehicle, N m per rad/s
        self.linear_drag = np.array([v.linear_drag for v in vehicles])
        self.angular_drag = np.array([v.angular_drag for v in vehicles])
        self.has_drag = bool(np.any(self.linear_drag > 0.0) or np.any(self.angular_drag > 0.0))


def apply_drag(u: Array, x: Array, force: Array, torque: Array, p: BatchPlant) -> None:
    """``sim_bridge.plant.dynamics.apply_drag`` over runs, in place: u (13, B), x (18, B), the disturbance's force
    on the vehicle and torque alone (3, B) each; a run with a zero coefficient gets the disturbance's, as the
    scalar path leaves it."""
    u[4:7] = force - p.linear_drag * x[3:6]
    phi, theta = x[6], x[7]
    sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    pr, tr, yr = x[9], x[10], x[11]
    kdw = p.angular_drag
    u[10] = torque[0] - kdw * (pr - st * yr)
    u[11] = torque[1] - kdw * (cf * tr + sf * ct * yr)
    u[12] = torque[2] - kdw * (-sf * tr + cf * ct * yr)


def derivative(x: Array, u: Array, p: BatchPlant) -> Array:
    """``sim_bridge.plant.dynamics.derivative`` over runs: x (18, B), u (13, B) -> (18, B). Loads of mass 0 are not
    supported here (the sweep draws m > 0)."""
    phi, theta, psi = x[6], x[7], x[8]
    r1, r2, r3 = x[12], x[13], x[14]
    d1, d2, d3 = x[15], x[16], x[17]
    M, m, l = p.M, p.m, p.l
    thrust = u[0]
    sf, cf = np.sin(phi), np.cos(phi)
    st, ct = np.sin(theta), np.cos(theta)
    sp, cp = np.sin(psi), np.cos(psi)
    n1, n2, n3 = thrust_direction_trig(sf, cf, st, ct, sp, cp)
    q1 = thrust * n1 + u[4]
    q2 = thrust * n2 + u[5]
    q3 = thrust * n3 + u[6]
    rd2 = d1 * d1 + d2 * d2 + d3 * d3
    rq = r1 * q1 + r2 * q2 + r3 * q3
    rl = r1 * u[7] + r2 * u[8] + r3 * u[9]
    T = (m * M * l * rd2 + M * rl - m * rq) / (M + m)
    out = np.empty_like(x)
    out[0:3] = x[3:6]
    out[3] = (q1 + T * r1) / M
    out[4] = (q2 + T * r2) / M
    out[5] = (q3 + T * r3) / M - p.g
    w1 = u[7] / m - q1 / M
    w2 = u[8] / m - q2 / M
    w3 = u[9] / m - q3 / M
    wr = w1 * r1 + w2 * r2 + w3 * r3
    inv_l = 1.0 / l
    out[6:9] = x[9:12]
    out[9] = (u[1] + u[10]) / p.Ip
    out[10] = (u[2] + u[11]) / p.It
    out[11] = (u[3] + u[12]) / p.Is
    out[12:15] = x[15:18]
    out[15] = (w1 - wr * r1) * inv_l - rd2 * r1
    out[16] = (w2 - wr * r2) * inv_l - rd2 * r2
    out[17] = (w3 - wr * r3) * inv_l - rd2 * r3
    return out


def rk4_step(x: Array, u: Array, p: BatchPlant, h: float) -> Array:
    """``sim_bridge.plant.dynamics.rk4_step`` over runs (input held, cable projected onto ``|r| = 1``, ``r . r' =
    0``)."""
    k1 = derivative(x, u, p)
    hh = 0.5 * h
    k2 = derivative(x + hh * k1, u, p)
    k3 = derivative(x + hh * k2, u, p)
    k4 = derivative(x + h * k3, u, p)
    h6 = h / 6.0
    y = x + h6 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    inv = 1.0 / np.sqrt(y[12] * y[12] + y[13] * y[13] + y[14] * y[14])
    y[12:15] *= inv
    dot = y[12] * y[15] + y[13] * y[16] + y[14] * y[17]
    y[15:18] -= dot * y[12:15]
    return y


def tension(x: Array, u: Array, p: BatchPlant) -> Array:
    """``sim_bridge.plant.dynamics.tension`` over runs (N; <= 0: slack)."""
    phi, theta, psi = x[6], x[7], x[8]
    sf, cf, st, ct, sp, cp = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta), np.sin(psi), np.cos(psi)
    n1, n2, n3 = sf * sp + cf * cp * st, cf * sp * st - cp * sf, cf * ct
    r1, r2, r3 = x[12], x[13], x[14]
    rq = r1 * (u[0] * n1 + u[4]) + r2 * (u[0] * n2 + u[5]) + r3 * (u[0] * n3 + u[6])
    rl = r1 * u[7] + r2 * u[8] + r3 * u[9]
    rd2 = x[15] * x[15] + x[16] * x[16] + x[17] * x[17]
    return (p.m * p.M * p.l * rd2 + p.M * rl - p.m * rq) / (p.M + p.m)


class BatchState(dict):  # type: ignore[type-arg]
    """The controller's input over runs: ``fx``, ``fy`` (6, B) flat chains and the named scalars (B,) of
    ``estimators.model.control_state.ControlState``."""


def truth_state(x: Array, k: Any) -> BatchState:
    """``offboard.harness.sim.truth_control_state`` over runs (nominal flat constants ``k``)."""
    r1, r2, r3, d1, d2, d3 = x[12], x[13], x[14], x[15], x[16], x[17]
    qy = r1 * r1 + r3 * r3
    qx = r2 * r2 + r3 * r3
    ay, ax = np.arctan2(r1, -r3), np.arctan2(r2, -r3)
    ayd = np.where(qy > 0.0, (r1 * d3 - r3 * d1) / np.where(qy > 0.0, qy, 1.0), 0.0)
    axd = np.where(qx > 0.0, (r2 * d3 - r3 * d2) / np.where(qx > 0.0, qx, 1.0), 0.0)
    phi, theta, psi, dphi, dtheta, dpsi = x[6], x[7], x[8], x[9], x[10], x[11]
    cp, sp = np.cos(psi), np.sin(psi)
    nx = theta * cp + phi * sp
    ny = theta * sp - phi * cp
    nxd = dtheta * cp + dphi * sp - dpsi * ny
    nyd = dtheta * sp - dphi * cp + dpsi * nx
    fx = np.stack([x[0] + k.l * ay, x[3] + k.l * ayd, -k.g * ay, -k.g * ayd, k.c * (ay + nx), k.c * (ayd + nxd)])
    fy = np.stack([x[1] + k.l * ax, x[4] + k.l * axd, -k.g * ax, -k.g * axd, k.c * (ax + ny), k.c * (axd + nyd)])
    s = BatchState()
    s.update(
        fx=fx,
        fy=fy,
        z=x[2],
        z_rate=x[5],
        phi=phi,
        theta=theta,
        psi=psi,
        phi_rate=dphi,
        theta_rate=dtheta,
        psi_rate=dpsi,
        alpha_x=ax,
        alpha_y=ay,
        alpha_x_rate=axd,
        alpha_y_rate=ayd,
    )
    return s


class Figures:
    """The sweep's figures of each run, accumulated every tick as ``offboard.harness.sweep.evaluate`` computes them
    from a scalar run's log: peak swing, residual swing (from ``arrival + 2`` s), the load's tracking error
    (sum of squares, final), the estimate's largest flat-output error; the cable's slack steps."""

    def __init__(self, B: int, residual_from: float) -> None:
        self.residual_from = residual_from
        self.peak = np.full(B, -np.inf)
        self.residual = np.full(B, -np.inf)
        self.sq = np.zeros(B)
        self.n = 0
        self.final = np.zeros(B)
        self.est_err = np.zeros(B)
        self.slack = np.zeros(B, dtype=int)
        self.finite = np.ones(B, dtype=bool)

    def tick(self, t: float, alpha: Array, e: Array, est_err: Array) -> None:
        self.peak = np.fmax(self.peak, alpha)
        if t >= self.residual_from:
            self.residual = np.fmax(self.residual, alpha)
        sq = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
        self.sq = self.sq + np.where(np.isfinite(sq), sq, 0.0)
        self.n += 1
        self.final = np.sqrt(sq)
        self.est_err = np.fmax(self.est_err, est_err)


#: the sweep's controllers the batched path flies (the others fly the scalar path)
BATCHED_LAWS = ("smc", "cascade", "zv", "zvd", "swing-feedback", "lqr")


def batched_law(law: str, vehicle: Any, runs: int) -> tuple[Any, Any]:
    """(the law over runs, the reference shaper in front of it) for a row of ``BATCHED_LAWS`` other than ``smc``
    on the nominal ``vehicle``; (None, None) for ``smc``. The registry's own controller gives the parameters (gains,
    the shaper's impulses, the applet's constants), so the two paths cannot drift apart."""
    from offboard.control.controllers import registry
    from offboard.control.controllers.lqr import LqrController
    from offboard.control.controllers.shaping import ShapedCascade
    from offboard.control.controllers.swing_feedback import SwingFeedbackCascade
    from offboard.harness.batched_controllers import CascadeStep, LqrStep, SwingFeedbackStep

    if law == "smc":
        return None, None
    scalar = registry.make(law, vehicle)
    if isinstance(scalar, LqrController):
        return LqrStep(scalar, runs), None
    if isinstance(scalar, SwingFeedbackCascade):
        return SwingFeedbackStep(vehicle, scalar.gains, runs, scalar), None
    if isinstance(scalar, ShapedCascade):
        return CascadeStep(vehicle, scalar.cascade.gains, runs), scalar.shaper
    return CascadeStep(vehicle, scalar.gains, runs), None


def simulate(
    scenarios: list[Any],
    vehicles: list[Any],
    params: smc.ControllerParams,
    control_rate: float = 1000.0,
    log_every: int = 1,
    *,
    estimator: str = "truth",
    actuators: str = "ideal",
    sensors: list[Any] | None = None,
    seeds: list[int] | None = None,
    load_sensor: bool = True,
    plant_dt: float = 0.001,
    tuning: Any = None,
    law: str = "smc",
    kf_factory: Any = None,
) -> dict[str, Any]:
    """Run the scenarios (one reference for all: the first's; each its own gust and initial state) with their
    true vehicles together, as ``offboard.harness.sim.run`` runs each: returns arrays (ticks, B) of ``t`` (ticks,),
    ``x`` (ticks, 18, B), ``alpha``, ``e_Fx``, ``e_Fy``, ``e_z``, ``est_Fx0``, ``est_Fy0`` every ``log_every``
    ticks (``log_every = 0``: no time series), ``saturated`` (s), ``slack_steps``, ``min_tension`` and the per-run
    figures (``figures``: :class:`Figures`). ``estimator``: ``truth`` or ``kf`` (the measured-input filter on
    ``sensors``, one ``sim_bridge.plant.sensors.Preset`` per run, generator seeds ``seeds``); ``actuators``: ``ideal``
    or ``mixer`` (four motors with each vehicle's lag); ``tuning``: the filter's (``MeasuredTuning``; None: the
    defaults); ``law``: ``smc`` (the sliding-mode law of ``params``) or another row of ``BATCHED_LAWS``
    (the registry's controller of that name on ``params.vehicle``, the nominal vehicle: :func:`batched_law`);
    ``kf_factory``: what builds the filter, called as ``BatchedMeasuredKalman`` is (None: that class; a test passes
    a subclass that records the filter's calls, ``tests/test_compiled_kf.py``)."""
    from estimators.filters.batched_kf import GYRO, IMU, BatchedMeasuredKalman
    from offboard.harness.batched_controllers import smc_step
    from offboard.harness.batched_sensors import RING, BatchMixer, Records, measure, schedule
    from offboard.harness.sim import plant_scenario
    from sim_bridge.plant import dynamics

    if estimator not in ("truth", "kf") or actuators not in ("ideal", "mixer"):
        raise ValueError("the batched path flies estimator truth or kf, actuators ideal or mixer")
    if law not in BATCHED_LAWS:
        raise ValueError(f"the batched path flies the laws {', '.join(BATCHED_LAWS)}, not {law!r}")
    scs = [plant_scenario(s) for s in scenarios]
    B = len(scs)
    p = BatchPlant(vehicles)
    k = flat_constants(params.vehicle)
    substeps = round(1.0 / (control_rate * plant_dt))
    dt = substeps * plant_dt
    T = scs[0].duration
    n_ticks = math.floor(T / dt + 1e-9) + 1
    x = np.array([s.initial_state for s in scs], dtype=float).T  # (18, B)
    mem = np.zeros((8, B))
    baseline, shaper = batched_law(law, params.vehicle, B)
    reference = scs[0].reference
    gust = _Gusts([s.disturbance for s in scs])
    keep = list(range(0, n_ticks, log_every)) if log_every > 0 else []
    if keep and keep[-1] != n_ticks - 1:
        keep.append(n_ticks - 1)
    nk = len(keep)
    names = ("alpha", "e_Fx", "e_Fy", "e_z", "est_Fx0", "est_Fy0")
    log: dict[str, Any] = {"t": np.empty(nk), "x": np.empty((nk, 18, B)), **{n: np.empty((nk, B)) for n in names}}
    log.update(saturated=np.zeros(B), min_tension=np.full(B, np.inf), slack_steps=np.zeros(B, dtype=int))
    arrival = getattr(scs[0], "arrival_time", None)
    fig = Figures(B, math.inf if arrival is None else arrival + 2.0)
    kf = recs = None
    if estimator == "kf":
        assert sensors is not None and seeds is not None
        kw_kf: dict[str, Any] = {} if tuning is None else {"tuning": tuning}
        kf = (kf_factory or BatchedMeasuredKalman)(params.vehicle, B, load_sensor=load_sensor, rate_hz=1 / dt, **kw_kf)
        runs = [
            schedule(
                sensors[b],
                vehicles[b],
                seeds[b],
                n_ticks,
                dt,
                plant_dt,
                substeps,
                load_sensor=load_sensor,
                delay_s=kf.delay,
                fuse_gyro=kf.tuning.fuse_gyro,
            )
            for b in range(B)
        ]
        recs = Records(runs, (n_ticks - 1) * substeps, n_ticks)
        t0 = truth_state(x, k)
        kf.initialize(0.0, t0["fx"], t0["fy"], t0["z"], t0["z_rate"], t0["psi"], t0["psi_rate"])
    mixer = None
    hover = np.array([dynamics.hover_input(dynamics.plant_params(v, "paper"))[0] for v in vehicles])
    if actuators == "mixer":
        mixer = BatchMixer(vehicles, plant_dt)
        mixer.reset(0.25 * hover)
    u = np.zeros((13, B))
    lag_tau = params.vehicle.motor_time_constant
    lagged = np.zeros((3, B))
    t_prev = 0.0
    li = 0
    step = 0
    for tick in range(n_ticks):
        t = tick * dt
        truth = truth_state(x, k)
        if kf is not None:
            assert recs is not None
            for code, idx, pay in recs.tick_groups[tick]:
                if code == GYRO:
                    rn = pay.astype(int)
                    tr = recs.times[IMU][recs.offset[IMU][idx] + rn]
                    kf.fuse_gyro(idx, tr, recs.values[IMU][3:6, idx, rn % RING])
                elif code >= 4:
                    kf.advance(code - 4, idx, pay)
                else:
                    rn = pay.astype(int)
                    tr = recs.times[code][recs.offset[code][idx] + rn]
                    kf.fuse(code, idx, tr, recs.values[code][:, idx, rn % RING])
            est: Any = kf.estimate_arrays(t)
        else:
            est = truth
        ref = reference.sample(t)
        if baseline is not None:
            rfx, rfy, rz, rpsi = ref.fx, ref.fy, ref.z, ref.psi
            if shaper is not None:  # one reference for all runs: shaped once
                rfx, rfy, rz, rpsi = shaper(t, rfx, rfy, rz, rpsi)
            uc, sat = baseline(t, est, rfx, rfy, rz, rpsi)
        else:
            uc, sat, mem = smc_step(0.0 if tick == 0 else dt, est, ref.fx, ref.fy, ref.z, ref.psi, mem, params)
        if kf is not None:  # offboard.harness.sim.run(command_lag=True): through the nominal motor lag with motors
            if mixer is None or tick == 0 or lag_tau == 0.0:
                lagged = uc[0:3].copy()
            else:
                step_dt = t - t_prev
                a_lag = 1.0 - math.exp(-step_dt / lag_tau) if step_dt > 0.0 else 0.0
                lagged = lagged + a_lag * (uc[0:3] - lagged)
            t_prev = t
            kf.push_command(lagged[1], lagged[2], lagged[0])
        u[0:4] = uc
        dist = gust(t)
        u[4:13] = dist
        log["saturated"] += sat
        r1, r2, r3 = x[12], x[13], x[14]
        alpha = np.arctan2(np.sqrt(r1 * r1 + r2 * r2), -r3)
        e = (
            x[0] + p.l * np.arctan2(r1, -r3) - ref.fx[0],
            x[1] + p.l * np.arctan2(r2, -r3) - ref.fy[0],
            x[2] - ref.z[0],
        )
        ex, ey = est["fx"][0] - truth["fx"][0], est["fy"][0] - truth["fy"][0]
        fig.tick(t, alpha, e, np.hypot(ex, ey))
        if li < nk and keep[li] == tick:
            log["t"][li] = t
            log["x"][li] = x
            for n, v in zip(names, (alpha, *e, ex, ey)):
                log[n][li] = v
            li += 1
        if mixer is not None:
            mixer.allocate(u[0], u[1], u[2], u[3])
            u[0:4] = mixer.wrench()
        if tick == n_ticks - 1:
            break
        dist_force, dist_torque = dist[0:3], dist[6:9]
        for _ in range(substeps):
            if mixer is not None:
                u[0:4] = mixer.step()
            if p.has_drag:
                apply_drag(u, x, dist_force, dist_torque, p)
            x = rk4_step(x, u, p, plant_dt)
            tens = tension(x, u, p)
            fig.slack += tens <= 0.0
            log["min_tension"] = np.minimum(log["min_tension"], tens)
            if recs is not None:
                deriv = None
                for code in range(4):
                    got = recs.sampled(code, step)
                    if got is None:
                        continue
                    idx, rn = got
                    xi, ui = x[:, idx], u[:, idx]
                    if code == 2 and deriv is None:
                        deriv = derivative(x, u, p)
                    vals = measure(
                        code,
                        xi,
                        ui,
                        None if deriv is None else deriv[:, idx],
                        p.g[idx],
                        recs.bias[:, idx],
                        recs.noise[code][:, recs.offset[code][idx] + rn],
                    )
                    recs.values[code][:, idx, rn % RING] = vals
            step += 1
        fig.finite &= np.isfinite(x).all(axis=0)
    log["saturated"] *= dt
    log["slack_steps"] = fig.slack
    log["figures"] = fig
    log["n_ticks"] = n_ticks
    return log


class _Gusts:
    """The runs' disturbances at time t, (9, B): the sweep's 1 - cos gusts over arrays
    (``offboard.harness.sweep._Gust``, the same expression), any other disturbance callable run by run."""

    def __init__(self, gusts: list[Any]) -> None:
        self.B = len(gusts)
        self.gusts = gusts
        self.vector = all(g is None or hasattr(g, "direction") for g in gusts)
        if self.vector:
            z = [g is None for g in gusts]
            self.start = np.array([0.0 if n else g.start for n, g in zip(z, gusts)])
            self.length = np.array([1.0 if n else g.length for n, g in zip(z, gusts)])
            self.force = np.array([0.0 if n else g.force for n, g in zip(z, gusts)])
            d = np.array([0.0 if n else g.direction for n, g in zip(z, gusts)])
            self.c, self.s = np.cos(d), np.sin(d)
            self.t_end = float((self.start + self.length).max()) if self.B else 0.0
            self.t_begin = float(self.start.min()) if self.B else 0.0
        self.zero = np.zeros((9, self.B))

    def __call__(self, t: float) -> Array:
        if not self.vector:
            cols = [np.zeros(9) if g is None else np.asarray(g(t), dtype=float) for g in self.gusts]
            return np.stack(cols, axis=1)
        if t < self.t_begin or t > self.t_end:
            return self.zero
        sv = (t - self.start) / self.length
        on = (sv >= 0.0) & (sv <= 1.0) & (self.force != 0.0)
        w = np.where(on, 0.5 * (1.0 - np.cos(2.0 * math.pi * sv)) * self.force, 0.0)
        out = np.zeros((9, self.B))
        out[0], out[1] = w * self.c, w * self.s
        out[3], out[4] = 0.3 * w * self.c, 0.3 * w * self.s
        return out


def run_batch(config: Any, controller: str, runs: list[int]) -> list[dict[str, Any]]:
    """The sweep's rows for ``runs`` with the batched path (see the module docstring): the same rows as
    ``offboard.harness.sweep.run_one`` gives run by run."""
    from offboard.harness import sweep_runs

    if controller not in BATCHED_LAWS:
        raise ValueError(f"the batched engine flies {', '.join(BATCHED_LAWS)} only, not {controller!r}")
    drawn = sweep_runs.drawn_runs(config, controller, runs)
    wall0 = time.perf_counter()
    log = simulate(
        drawn.scenarios,
        drawn.vehicles,
        drawn.params,
        log_every=0,
        law=controller,
        actuators=config.actuators,
        **drawn.simulate_kw,
    )
    wall = time.perf_counter() - wall0
    fig: Figures = log["figures"]
    figures = [
        {
            "peak_swing_rad": float(fig.peak[b]),
            "residual_swing_rad": float(fig.residual[b]) if fig.residual[b] > -math.inf else math.nan,
            "tracking_rms_m": float(math.sqrt(fig.sq[b] / fig.n)),
            "final_error_m": float(fig.final[b]),
            "max_estimate_error_m": float(fig.est_err[b]),
            "slack_steps": int(fig.slack[b]),
            "completed": bool(fig.finite[b]),
        }
        for b in range(len(runs))
    ]
    sim_s = (log["n_ticks"] - 1) * 0.001  # the scalar log's last time, tick * control_dt
    return sweep_runs.batch_rows(config, controller, drawn, figures, sim_s, wall)
