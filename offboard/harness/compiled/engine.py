"""One compiled run, and the sweep's rows for a chunk of runs (``engine = "compiled"``).

:func:`fly_run` is ``offboard.harness.sim.run``'s loop for one run, as machine code: at each control tick
the true state, the filter's records due and its estimate, the reference, the law, the command through the nominal
motor lag into the filter, the gust, the sweep's figures, the mixer or PX4's attitude setpoint; then the plant's
steps with the motors' lag (behind PX4's attitude P, rate PID and allocator for the attitude-level law), the drag,
RK4, the cable's tension and the sensors sampling. The same order as the scalar path
(``offboard.harness.sim.run``), so they agree (``tests/test_compiled_engine.py``, ``tests/test_compiled_attitude.py``).

:func:`simulate` is the Python side: it builds each run's constants (:mod:`.inputs`), its sensor schedule
(``offboard.harness.compiled.schedule``) and the shared reference rows, then flies the runs one after another.
:func:`run_batch` gives the sweep's rows, as ``sweep.run_one`` does: every row, ``smc-attitude`` included.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from estimators.filters.compiled import kf as ckf
from estimators.kernels import (
    ADVANCE,
    EST_ALPHA_X,
    EST_ALPHA_Y,
    EST_FX,
    EST_FY,
    EST_SIZE,
    GYRO,
    IMU,
    minimum,
    pure_kernel,
)
from offboard.control.compiled import attitude_law as cal
from offboard.control.compiled import laws as claws
from offboard.control.compiled.reference_row import REF_FX, REF_FY, REF_Z
from offboard.harness.compiled import inputs as cin
from offboard.harness.compiled.inputs import ACT_IDEAL, ACT_MIXER, ACT_PX4_ATTITUDE
from sim_bridge.inner.compiled import px4_loops as cpx
from sim_bridge.plant.compiled import plant as cp

# ---- a run's figures (as offboard.harness.sweep.evaluate computes them from a logged run) --------------------
FIG_PEAK, FIG_RESIDUAL, FIG_SQ, FIG_N, FIG_FINAL, FIG_EST_ERR, FIG_SLACK, FIG_FINITE, FIG_SATURATED, FIG_MIN_TENSION = (
    range(10)
)
FIG_SIZE = 10
#: rows of a run's scratch (``fly_run``'s ``ws``: RK4's stages, the derivative, the input, the command (the attitude
#: law's 7 floats), the gust, the true state and the estimate, the lagged command, the motors' thrusts and commands,
#: the sines and cosines of the state's attitude)
WS_ROWS = 15
#: the logged columns besides the state (``simulate``'s names)
LOG_NAMES = ("alpha", "e_Fx", "e_Fy", "e_z", "est_Fx0", "est_Fy0")


@pure_kernel
def _fmax(a: float, b: float) -> float:
    """``np.fmax``: the larger, a NaN ignored."""
    if b != b:
        return a
    if a != a:
        return b
    return a if a >= b else b


@pure_kernel
def _fuse_due(
    tick: int,
    ev_i: int,
    ev: np.ndarray,
    pay: np.ndarray,
    rec_start: np.ndarray,
    rec_time: np.ndarray,
    rec_val: np.ndarray,
    kf_c: np.ndarray,
    kf_f: np.ndarray,
    kf_n: np.ndarray,
) -> int:
    """The filter's events of this tick, in the run's order (``offboard.harness.compiled.schedule``): a
    record's fusion, its gyro's, or a block's advance; returns the index of the next tick's first event."""
    n_ev = ev.shape[0]
    while ev_i < n_ev and ev[ev_i, 0] == tick:
        code = ev[ev_i, 2]
        if code == GYRO:
            j = rec_start[IMU] + int(pay[ev_i])
            ckf.kf_fuse_gyro(kf_c, kf_f, kf_n, rec_time[j], rec_val[j, 3:6])
        elif code >= ADVANCE:
            ckf.kf_advance(kf_c, kf_f, kf_n, code - ADVANCE, pay[ev_i])
        else:
            j = rec_start[code] + int(pay[ev_i])
            ckf.kf_fuse(kf_c, kf_f, kf_n, code, rec_time[j], rec_val[j])
        ev_i += 1
    return ev_i


@pure_kernel
def _sample_due(
    step: int,
    next_rec: np.ndarray,
    rec_start: np.ndarray,
    rec_step: np.ndarray,
    rec_noise: np.ndarray,
    rec_val: np.ndarray,
    bias: np.ndarray,
    x: np.ndarray,
    trig: np.ndarray,
    u: np.ndarray,
    p: np.ndarray,
    deriv: np.ndarray,
) -> None:
    """The records the sensors sample at plant step ``step`` (after it), their values from the state reached
    (``trig``: its attitude's sines and cosines, ``plant.angle_trig``)."""
    have_deriv = False
    for kind in range(4):
        j = next_rec[kind]
        if j >= rec_start[kind + 1] or rec_step[j] != step:
            continue
        if kind == IMU and not have_deriv:
            cp.derivative_at(x, u, p, cp.trig_of(trig), deriv)
            have_deriv = True
        cp.measure_at(kind, x, cp.trig_of(trig), deriv, p[cp.P_G], bias, rec_noise[j], rec_val[j])
        next_rec[kind] = j + 1


@pure_kernel
def fly_run(
    ref: np.ndarray,
    law_ref: np.ndarray,
    dt: float,
    plant_dt: float,
    substeps: int,
    residual_from: float,
    law_code: int,
    law_c: np.ndarray,
    law_K: np.ndarray,
    law_mem: np.ndarray,
    flat: np.ndarray,
    lag_tau: float,
    use_kf: bool,
    kf_c: np.ndarray,
    kf_f: np.ndarray,
    kf_n: np.ndarray,
    actuators: int,
    mix_c: np.ndarray,
    px_c: np.ndarray,
    px_s: np.ndarray,
    hover: float,
    p: np.ndarray,
    x: np.ndarray,
    gust_c: np.ndarray,
    rec_start: np.ndarray,
    rec_step: np.ndarray,
    rec_time: np.ndarray,
    rec_noise: np.ndarray,
    rec_val: np.ndarray,
    bias: np.ndarray,
    ev: np.ndarray,
    pay: np.ndarray,
    log_every: int,
    log_x: np.ndarray,
    log_e: np.ndarray,
    fig: np.ndarray,
    ws: np.ndarray,
    next_rec: np.ndarray,
) -> None:
    """Fly one run (``sim.run``'s loop, torque-level or attitude-level law): ``ref`` / ``law_ref`` (ticks, 28) the
    reference rows for the figures and for the law (a shaped reference for ``zv`` / ``zvd``, else the same array),
    ``law_code`` a ``laws.LAW_*`` or ``attitude_law.LAW_SMC_ATTITUDE``,
    ``flat`` the controller's nominal flat constants (l, g, c), ``lag_tau`` the nominal motor time constant (s),
    ``actuators`` an ``inputs.ACT_*`` (the mixer's constants ``mix_c``; PX4's attitude path's ``px_c`` and its
    state ``px_s``, flown in place), the state ``x`` (18,) flown in place, the records (``rec_*``: per kind from
    ``rec_start[kind]``, sampling steps, times, noise, values filled as sampled) and the filter's events ``ev``
    (tick, slot, code) with ``pay``; the figures into ``fig`` (``FIG_*``), every ``log_every``-th tick (and the
    last) into ``log_x`` / ``log_e`` (0: none). ``ws`` (``WS_ROWS``, 24) and ``next_rec`` (4,) are the caller's
    scratch (this kernel allocates nothing: it runs without numba's reference counting, ``layout.pure_kernel``)."""
    n_ticks = ref.shape[0]
    kl, kg, kc = flat[0], flat[1], flat[2]
    for r in range(ws.shape[0]):
        for i in range(ws.shape[1]):
            ws[r, i] = 0.0
    work = ws[0:5, 0:18]  # RK4's stages
    deriv = ws[5, 0:18]
    u = ws[6, 0:13]
    uc = ws[7, 0 : cal.COMMAND_SIZE]
    dist = ws[8, 0:9]
    truth = ws[9, 0:EST_SIZE]
    est = ws[10, 0:EST_SIZE]
    lagged = ws[11, 0:3]
    f_mot = ws[12, 0:4]
    cmd = ws[13, 0:4]
    trig = ws[14, 0 : cp.TRIG_SIZE]  # the sines and cosines of x's attitude, kept by rk4_step_trig
    cp.angle_trig(x, trig)
    for i in range(4):
        f_mot[i] = cmd[i] = 0.25 * hover
        next_rec[i] = rec_start[i]
    peak, residual, sq_sum, sq_last, est_err = -np.inf, -np.inf, 0.0, 0.0, 0.0
    saturated, min_tension, slack = 0.0, np.inf, 0
    finite = True
    t_prev = 0.0
    lag_dt, lag_a = math.nan, 0.0  # the command lag's last step (s) and its factor
    top_angle, top_tan2 = math.nan, -1.0  # the largest swing the figures hold (rad) and its tangent squared
    alpha = 0.0
    ev_i = 0
    step = 0
    li = 0
    for tick in range(n_ticks):
        t = tick * dt
        cp.truth_state_at(x, trig[4], trig[5], kl, kg, kc, truth)
        if use_kf:
            if tick == 0:
                ckf.kf_initialize(kf_c, kf_f, kf_n, 0.0, truth)
            ev_i = _fuse_due(tick, ev_i, ev, pay, rec_start, rec_time, rec_val, kf_c, kf_f, kf_n)
            ckf.kf_estimate(kf_c, kf_f, kf_n, t, est)
        else:
            for i in range(EST_SIZE):
                est[i] = truth[i]
        if law_code == cal.LAW_SMC_ATTITUDE:  # the attitude setpoint besides the torques it expects
            sat = cal.attitude_step(law_c, law_mem, t, est, law_ref[tick], uc)
        else:
            sat = claws.law_step(law_code, law_c, law_K, law_mem, t, 0.0 if tick == 0 else dt, est, law_ref[tick], uc)
        if use_kf:  # offboard.harness.sim.run(command_lag=True): the command through the nominal motor lag
            if actuators == ACT_IDEAL or tick == 0 or lag_tau == 0.0:
                lagged[0], lagged[1], lagged[2] = uc[0], uc[1], uc[2]
            else:
                step_dt = t - t_prev
                if step_dt != lag_dt:  # (tick * dt differences take a few values: exp is not called every tick)
                    lag_dt, lag_a = step_dt, 1.0 - math.exp(-step_dt / lag_tau) if step_dt > 0.0 else 0.0
                a_lag = lag_a
                for i in range(3):
                    lagged[i] = lagged[i] + a_lag * (uc[i] - lagged[i])
            t_prev = t
            ckf.kf_push_command(kf_c, kf_f, kf_n, lagged[1], lagged[2], lagged[0])
        u[0], u[1], u[2], u[3] = uc[0], uc[1], uc[2], uc[3]
        cp.gust_at(gust_c, t, dist)
        for i in range(9):
            u[4 + i] = dist[i]
        if sat:
            saturated += 1.0
        # the figures of the tick (offboard.harness.sweep.evaluate's, accumulated)
        r1, r2, r3 = x[12], x[13], x[14]
        # the swing angle where it is logged or may be a new largest of the figures that take it (peak, then the
        # residual from residual_from): below 90 deg, tan^2 alpha = (r1^2 + r2^2) / r3^2 short of the largest's by
        # far more than rounding means it is not (a NaN or a swing past 90 deg is always taken)
        after = t >= residual_from
        top = residual if after else peak
        if top != top_angle:
            # (-1: nothing is below it for sure; no largest yet, or one too near 90 deg for the tangent)
            top_angle, top_tan2 = top, (math.tan(top) ** 2 if 0.0 <= top < 1.5 else -1.0)
        s2, c2 = r1 * r1 + r2 * r2, r3 * r3
        if log_every > 0 or not (r3 < 0.0 and s2 < c2 * top_tan2 * (1.0 - 1e-9)):
            alpha = math.atan2(math.sqrt(s2), -r3)
            peak = _fmax(peak, alpha)
            if after:
                residual = _fmax(residual, alpha)
        # truth's swing angles are atan2(r1, -r3) and atan2(r2, -r3) of this x: the figures' too, not computed twice
        e0 = x[0] + p[cp.P_L] * truth[EST_ALPHA_Y] - ref[tick, REF_FX]
        e1 = x[1] + p[cp.P_L] * truth[EST_ALPHA_X] - ref[tick, REF_FY]
        e2 = x[2] - ref[tick, REF_Z]
        ex, ey = est[EST_FX] - truth[EST_FX], est[EST_FY] - truth[EST_FY]
        sq = e0 * e0 + e1 * e1 + e2 * e2
        if math.isfinite(sq):
            sq_sum = sq_sum + sq
        sq_last = sq
        # the estimate's error only where it may be a new largest: a norm squared short of the largest squared by
        # far more than rounding cannot be (strict, so a zero or underflowing largest still asks hypot)
        if not ex * ex + ey * ey < est_err * est_err * (1.0 - 1e-9):
            est_err = _fmax(est_err, math.hypot(ex, ey))
        if log_every > 0 and (tick % log_every == 0 or tick == n_ticks - 1):
            for i in range(18):
                log_x[li, i] = x[i]
            log_e[li, 0], log_e[li, 1], log_e[li, 2], log_e[li, 3] = alpha, e0, e1, e2
            log_e[li, 4], log_e[li, 5] = ex, ey
            li += 1
        if actuators == ACT_MIXER:
            cp.mixer_allocate(mix_c, u[0], u[1], u[2], u[3], cmd)
            cp.mixer_wrench(mix_c, f_mot, u)
        elif actuators == ACT_PX4_ATTITUDE:  # (the motors' wrench now would only feed sim.run's logged tension)
            cpx.px4_set_setpoint(px_c, px_s, uc[cal.CMD_PHI_SP], uc[cal.CMD_THETA_SP], uc[cal.CMD_PSI_SP], uc[0])
        if tick == n_ticks - 1:
            break
        for _ in range(substeps):
            if actuators == ACT_MIXER:
                cp.mixer_step(mix_c, f_mot, cmd, u)
            elif actuators == ACT_PX4_ATTITUDE:  # from the state before the step, as Px4AttitudePath.step(x)
                cpx.px4_step(px_c, px_s, x, u)
            cp.apply_drag(u, x, dist[0:3], dist[6:9], p)
            cp.rk4_step_trig(x, u, p, plant_dt, work, trig)
            tens = cp.tension_at(x, u, p, cp.trig_of(trig))
            if tens <= 0.0:
                slack += 1
            min_tension = minimum(min_tension, tens)
            if use_kf:
                _sample_due(step, next_rec, rec_start, rec_step, rec_noise, rec_val, bias, x, trig, u, p, deriv)
            step += 1
        for i in range(18):
            if not math.isfinite(x[i]):
                finite = False
    fig[FIG_PEAK], fig[FIG_RESIDUAL], fig[FIG_SQ], fig[FIG_N] = peak, residual, sq_sum, n_ticks
    fig[FIG_FINAL], fig[FIG_EST_ERR], fig[FIG_SLACK] = math.sqrt(sq_last), est_err, slack
    fig[FIG_FINITE] = 1.0 if finite else 0.0
    fig[FIG_SATURATED], fig[FIG_MIN_TENSION] = saturated * dt, min_tension


# ---- the Python side -----------------------------------------------------------------------------------------------
def _sensor_arrays(
    sched: Any, kf_c: np.ndarray
) -> tuple[tuple[np.ndarray, ...], np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """A run's records and events (``inputs.records``; none without a schedule), the accelerometer's bias (3,) and
    a fresh filter state for the filter's constants ``kf_c`` (placeholders without a schedule)."""
    if sched is None:
        no_i, no_f = np.zeros(5, dtype=np.int64), np.zeros((0, 6))
        recs = (no_i, no_i[:0], np.zeros(0), no_f, no_f.copy(), np.zeros((0, 3), dtype=np.int64), np.zeros(0))
        return recs, np.zeros(3), (np.zeros(1), np.zeros(1, dtype=np.int64))
    return cin.records(sched), np.asarray(sched.bias, dtype=float), ckf.kf_new_state(kf_c)


def simulate(
    scenarios: list[Any],
    vehicles: list[Any],
    params: Any,
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
    rows: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, Any]:
    """Runs of ``offboard.harness.sim.run`` with the compiled kernels, many scenarios with their true vehicles (one
    reference for all: the first's; each its own gust and initial state). The log: ``t``, ``x``
    (ticks, 18, B), the ``LOG_NAMES`` columns (ticks, B), ``saturated`` (s), ``slack_steps``, ``min_tension``, the
    figures ``fig`` (B, ``FIG_SIZE``) and ``n_ticks``; the runs are flown one after another. ``law``: a row of
    ``inputs.COMPILED_LAWS``; ``smc-attitude`` flies with ``actuators = "px4-attitude"`` (``sim.run``'s PX4 attitude
    path), designed as the sweep designs it, and the log adds ``allocator_saturated`` (s: PX4's allocator left some
    torque unallocated; 0 with other actuators). ``rows``: the reference rows of ``inputs.reference_rows`` when the
    caller has them (a sweep samples its one reference once)."""
    from estimators.filters.measured_kf import MeasuredTuning
    from estimators.model.flatness import flat_constants
    from offboard.harness.compiled.schedule import schedule
    from offboard.harness.sim import plant_scenario
    from sim_bridge.plant import dynamics

    if estimator not in ("truth", "kf") or actuators not in cin.ACTUATORS:
        raise ValueError(f"the compiled path flies estimator truth or kf, actuators {', '.join(cin.ACTUATORS)}")
    cin.check_law(law, actuators)
    scs = [plant_scenario(s) for s in scenarios]
    B = len(scs)
    k = flat_constants(params.vehicle)
    flat = np.array([k.l, k.g, k.c])
    substeps = round(1.0 / (control_rate * plant_dt))
    dt = substeps * plant_dt
    n_ticks = math.floor(scs[0].duration / dt + 1e-9) + 1
    if rows is None:
        rows = cin.reference_rows(scs[0].reference, cin.law_shaper(law, params.vehicle), n_ticks, dt)
    ref, law_ref = rows
    if ref.shape[0] != n_ticks:
        raise ValueError(f"reference rows for {ref.shape[0]} ticks, the runs have {n_ticks}")
    code, law_c, law_K, memory = cin.law_arrays(law, params, estimator, tuning)
    arrival = getattr(scs[0], "arrival_time", None)
    residual_from = math.inf if arrival is None else arrival + 2.0
    keep = list(range(0, n_ticks, log_every)) if log_every > 0 else []
    if keep and keep[-1] != n_ticks - 1:
        keep.append(n_ticks - 1)
    nk = len(keep)
    log: dict[str, Any] = {"t": np.array(keep, dtype=float) * dt, "x": np.empty((nk, 18, B))}
    log.update({n: np.empty((nk, B)) for n in LOG_NAMES})
    figs, allocator_saturated = np.empty((B, FIG_SIZE)), np.zeros(B)
    use_kf, act = estimator == "kf", cin.ACTUATORS[actuators]
    tuning = MeasuredTuning() if tuning is None else tuning
    delay = 0.012  # the filter's fusion horizon behind the tick (MeasuredKalmanEstimator's default)
    kf_c = ckf.kf_constants(params.vehicle, tuning, load_sensor=load_sensor, delay_s=delay, rate_hz=1.0 / dt)
    sched = None
    for b in range(B):
        v = vehicles[b]
        if use_kf:
            assert sensors is not None and seeds is not None
            sched = schedule(
                sensors[b],
                v,
                seeds[b],
                n_ticks,
                dt,
                plant_dt,
                substeps,
                load_sensor=load_sensor,
                delay_s=delay,
                fuse_gyro=tuning.fuse_gyro,
            )
        recs, bias, (kf_f, kf_n) = _sensor_arrays(sched, kf_c)
        hover = dynamics.hover_input(dynamics.plant_params(v, "paper"))[0]
        mix_c, px_c, px_s = cin.actuator_arrays(act, v, plant_dt, hover)
        x = np.array(scs[b].initial_state, dtype=float)
        log_x, log_e = np.empty((max(nk, 1), 18)), np.empty((max(nk, 1), 6))
        ws, next_rec = np.empty((WS_ROWS, EST_SIZE)), np.empty(4, dtype=np.int64)
        start, steps, times, noise, vals, ev, pay = recs
        fly_run(
            ref,
            law_ref,
            dt,
            plant_dt,
            substeps,
            residual_from,
            code,
            law_c,
            law_K,
            memory.copy(),
            flat,
            params.vehicle.motor_time_constant,
            use_kf,
            kf_c,
            kf_f,
            kf_n,
            act,
            mix_c,
            px_c,
            px_s,
            hover,
            cp.plant_constants(v),
            x,
            cp.gust_constants(scs[b].disturbance),
            start,
            steps,
            times,
            noise,
            vals,
            bias,
            ev,
            pay,
            log_every,
            log_x,
            log_e,
            figs[b],
            ws,
            next_rec,
        )
        if act == ACT_PX4_ATTITUDE:  # rate-loop periods, two plant steps each
            allocator_saturated[b] = px_s[cpx.PS_N_SATURATED] * px_c[cpx.PX_RATE_DT]
        if nk:
            log["x"][:, :, b] = log_x[:nk]
            for i, n in enumerate(LOG_NAMES):
                log[n][:, b] = log_e[:nk, i]
    log.update(
        saturated=figs[:, FIG_SATURATED].copy(),
        min_tension=figs[:, FIG_MIN_TENSION].copy(),
        slack_steps=figs[:, FIG_SLACK].astype(int),
        allocator_saturated=allocator_saturated,
        fig=figs,
        n_ticks=n_ticks,
    )
    return log


def _flown_actuators(controller: str, nominal: Any, actuators: str) -> str:
    """The actuators ``controller`` flies with in the sweep (``compare.controller_as_flown``: ``smc-attitude``
    through PX4's attitude loops in place of the file's motors)."""
    if controller != "smc-attitude":
        return actuators
    from offboard.harness.compare import controller_as_flown
    from offboard.logs.runlog import SimConfig

    return controller_as_flown(controller, nominal, SimConfig(actuators=actuators))[0].actuators


def run_batch(config: Any, controller: str, runs: list[int]) -> list[dict[str, Any]]:
    """The sweep's rows for ``runs`` with the compiled engine: the rows ``offboard.harness.sweep.run_one`` gives."""
    from offboard.harness import sweep_runs

    drawn = sweep_runs.drawn_runs(config, controller, runs)
    kw = dict(drawn.simulate_kw, actuators=_flown_actuators(controller, drawn.params.vehicle, config.actuators))
    wall0 = time.perf_counter()
    rows = cin.sweep_reference(config, controller, drawn.scenarios[0], drawn.params)
    log = simulate(drawn.scenarios, drawn.vehicles, drawn.params, log_every=0, law=controller, rows=rows, **kw)
    wall = time.perf_counter() - wall0
    fig = log["fig"]
    figures = [
        {
            "peak_swing_rad": float(fig[b, FIG_PEAK]),
            "residual_swing_rad": float(fig[b, FIG_RESIDUAL]) if fig[b, FIG_RESIDUAL] > -math.inf else math.nan,
            "tracking_rms_m": float(math.sqrt(fig[b, FIG_SQ] / fig[b, FIG_N])),
            "final_error_m": float(fig[b, FIG_FINAL]),
            "max_estimate_error_m": float(fig[b, FIG_EST_ERR]),
            "slack_steps": int(fig[b, FIG_SLACK]),
            "completed": bool(fig[b, FIG_FINITE]),
        }
        for b in range(len(runs))
    ]
    sim_s = (log["n_ticks"] - 1) * 0.001  # the scalar log's last time, tick * control_dt
    return sweep_runs.batch_rows(config, controller, drawn, figures, sim_s, wall)
