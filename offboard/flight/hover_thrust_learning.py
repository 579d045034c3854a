"""The hover throttle of the vehicle being flown, learned in flight (issue 38): PX4's hover thrust estimator
(``estimators.identification.hover_thrust``) fed with what the autopilot reports.

- **The thrust**: the autopilot's own ATTITUDE_TARGET ``thrust``, in the units of its hover parameter: ArduPilot
  sends its ``throttle_in`` (CTUN.ThI, before angle boost, the units of MOT_THST_HOVER), PX4 the norm of its thrust
  setpoint (the units of MPC_THR_HOVER). It is the thrust whoever flies: the autopilot's position hold during the
  take-off and the approach, slung's own setpoints during control. The vertical part is what the filter wants:
  ArduPilot's throttle with angle boost is that already; otherwise times ``cos(roll) cos(pitch)``.
- **The vertical acceleration**: the accelerometer's specific force (an :class:`Imu` record, body FLU) rotated to
  the world with the latest attitude, gravity removed (m/s^2, up), averaged over the samples between two thrust
  samples (ATTITUDE_TARGET comes at 50 Hz, the IMU at up to the loop's rate).

One fusion per thrust sample, from the end of the take-off on (the loop calls :meth:`HoverThrustLearner.start`).
From the start of control it also watches for a load that drops off (:meth:`HoverThrustLearner.watch_load`): the
hover throttle of the vehicle alone is lower by about the load's share of the weight, and the filter, whose
innovations a sudden change refuses until its variance is bumped, follows it within seconds.
The learned value is trusted when the filter says so (variance below 0.001, test ratios passing, for 2 s); the loop
then maps thrust with it at the start of control (``FlightPhases._reread_hover_throttle``) and keeps learning for
the report (``metrics.json``'s ``config.hover_thrust_learning``).
"""

from __future__ import annotations

import math
from typing import Any

from estimators.identification.hover_thrust import HoverThrustEstimator
from estimators.model.measurements import Attitude, Imu, PositionVelocity
from offboard.flight.line_slack import LineSlackWatch

#: how long (vehicle s) the learned hover throttle stays low before the load counts as lost
LOST_AFTER_S = 1.0


def vertical_specific_force(imu: Imu, att: Attitude) -> float:
    """The world-vertical component (up, m/s^2) of the accelerometer's specific force: row 3 of the body -> world
    rotation ``Rz(psi) Ry(theta) Rx(phi)`` (model frame, ZYX Euler) times the body FLU vector."""
    sp, cp = math.sin(att.phi), math.cos(att.phi)
    st, ct = math.sin(att.theta), math.cos(att.theta)
    return -st * imu.ax + ct * sp * imu.ay + ct * cp * imu.az


class HoverThrustLearner:
    """The in-flight hover throttle of one flight.

    ``flavour``: "px4" or "ardupilot"; ``gravity`` m/s^2; ``prior``: the hover throttle believed before the flight
    (the autopilot's parameter, else the vehicle file's), normalized 0..1; ``angle_boost``: ArduPilot's
    ATC_ANGLE_BOOST (its reported throttle is then the vertical one)."""

    def __init__(self, flavour: str, gravity: float, prior: float, angle_boost: bool = True) -> None:
        self.flavour = flavour
        self.g = gravity
        self.prior = prior
        self.vertical_reported = flavour == "ardupilot" and angle_boost
        self.ekf = HoverThrustEstimator(gravity, prior)
        self.active = False
        self._acc_sum = 0.0
        self._acc_n = 0
        self._t_last: float | None = None
        self.fusions = 0
        self.refused = 0
        #: vehicle time (s) of the first fusion and of the moment the estimate was first trusted
        self.t_first: float | None = None
        self.t_valid: float | None = None
        #: the estimate when control started (:meth:`mark_control_start`)
        self.at_control_start: dict[str, Any] | None = None
        #: (hover throttle at the start of control, the load's share of it) while watching for a lost load
        self._watch: tuple[float, float] | None = None
        self._below_since: float | None = None
        #: what was said when the load seemed lost (once), else None
        self.load_lost: str | None = None
        #: vehicle time (s) when it was told
        self.t_lost: float | None = None
        self.load_lost_told = False
        #: the slack-line watch (from the start of control, with a load; ``offboard.flight.line_slack``) and the
        #: events it has to tell, ``(kind, reason)``, drained by the loop
        self.slack_watch: LineSlackWatch | None = None
        self.line_events: list[tuple[str, str]] = []

    def start(self) -> None:
        """In the air: fuse from now on (what came before, on the ground or in the climb, is dropped)."""
        self.active = True
        self._acc_sum, self._acc_n, self._t_last = 0.0, 0, None

    def watch_load(self, share: float) -> None:
        """From the start of control, a load whose share of the hover thrust is ``share`` (``m / (M + m)``): a learned
        hover throttle that falls below the one now by more than half of that share, or a vertical acceleration
        above what the thrust explains by more than half of ``share g`` (low-passed, 1 s), for :data:`LOST_AFTER_S`,
        is a load that dropped off (:attr:`load_lost`); the same residual over tenths of a second is a line gone slack
        (:attr:`slack_watch`, ``offboard.flight.line_slack``). Only with a trusted estimate to compare with."""
        if self.ekf.valid and 0.0 < share < 1.0:
            self._watch = (self.ekf.h, share)
            self._below_since = None
            self.slack_watch = LineSlackWatch(share, self.g)

    def stop(self) -> None:
        """The hand-over: no more fusions (a landing, with the load touching down first, breaks the model)."""
        self.active = False

    def mark_control_start(self) -> None:
        """Remember the estimate at the start of control (the one the mapping may take) for the report."""
        e = self.ekf
        self.at_control_start = {"hover_throttle": e.h, "sigma": e.sigma, "trusted": bool(e.valid)}

    def on_imu(self, imu: Imu, att: Attitude | None) -> None:
        """An accelerometer sample: its vertical acceleration joins the average until the next thrust sample."""
        if not self.active or att is None:
            return
        a = vertical_specific_force(imu, att) - self.g
        if math.isfinite(a):
            self._acc_sum += a
            self._acc_n += 1

    def on_thrust(self, t: float, thrust: float, att: Attitude | None, pos: PositionVelocity | None) -> None:
        """The autopilot's reported thrust ``thrust`` (normalized) at vehicle time ``t`` (s): one fusion with the
        mean vertical acceleration since the previous sample."""
        if not self.active or att is None or not math.isfinite(thrust):
            return
        t_prev, self._t_last = self._t_last, t
        n, acc = self._acc_n, self._acc_sum
        self._acc_sum, self._acc_n = 0.0, 0
        if t_prev is None or n == 0 or not t > t_prev:
            return
        vertical = thrust if self.vertical_reported else thrust * math.cos(att.phi) * math.cos(att.theta)
        speed_xy = math.hypot(pos.vx, pos.vy) if pos is not None else 0.0
        speed_z = pos.vz if pos is not None else 0.0
        ekf = self.ekf
        innovation, acc_var = ekf.model_residual(acc / n, vertical), ekf.acc_var  # before the update moves h
        ekf.update(t - t_prev, acc / n, vertical, speed_xy, speed_z)
        if self.slack_watch is not None:
            said = self.slack_watch.update(t, innovation, acc_var)
            if said is not None:
                self.line_events.append(said)
        self.fusions += 1
        self.refused += ekf.test_ratio >= 1.0
        if self.t_first is None:
            self.t_first = t
        if ekf.valid and self.t_valid is None:
            self.t_valid = t
        if self._watch is not None and self.load_lost is None:
            h0, share = self._watch
            # the estimate itself, or before it has moved (a trusted estimate follows a jump slowly: 10 s in
            # ArduPilot SITL) the vertical acceleration it does not explain, low-passed: the vehicle alone needs
            # about ``share`` less thrust, so the same thrust lifts it by about ``share g``
            if ekf.h < h0 * (1.0 - 0.5 * share) or ekf.residual_lpf > 0.5 * share * self.g:
                self._below_since = t if self._below_since is None else self._below_since
                if t - self._below_since >= LOST_AFTER_S:
                    self.t_lost = t
                    self.load_lost = (
                        f"the vehicle needs less thrust to hover: {ekf.residual_lpf:.2f} m/s^2 of climb the thrust "
                        f"does not explain, hover throttle {h0:.3f} -> {ekf.h:.3f} (the load's share {share:.0%}): "
                        "the load seems to have dropped off, or its line to have gone slack"
                    )
            else:
                self._below_since = None

    def learned(self) -> tuple[float, float] | None:
        """(hover throttle, its 1-sigma) once the filter trusts its estimate, else None."""
        if not self.ekf.valid:
            return None
        return self.ekf.h, self.ekf.sigma

    def summary(self) -> dict[str, Any]:
        """``metrics.json``'s ``config.hover_thrust_learning``: the prior, the estimate and its 1-sigma at the end of
        control, whether it is trusted, the fusions (and how many the gate refused), when it was first trusted (s
        after the first fusion), the estimate at the start of control."""
        e = self.ekf
        return {
            "prior": self.prior,
            "hover_throttle": e.h if self.fusions else None,
            "sigma": e.sigma if self.fusions else None,
            "trusted": bool(e.valid),
            "fusions": self.fusions,
            "refused": self.refused,
            "trusted_after_s": (
                None if self.t_valid is None or self.t_first is None else round(self.t_valid - self.t_first, 3)
            ),
            "accel_noise_var": e.acc_var if self.fusions else None,
            "at_control_start": self.at_control_start,
            "load_lost": self.load_lost,
            "line_slack": None if self.slack_watch is None else self.slack_watch.summary(),
        }


__all__ = ["HoverThrustLearner", "vertical_specific_force"]
