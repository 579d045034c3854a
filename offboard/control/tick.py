"""The controller tick, written once: estimate -> reference -> controller step -> map -> actuator lag ->
``push_command``. Every driver (``offboard.harness.sim``, the live loop ``offboard.flight.loop``,
``offboard.logs.replay``) calls :class:`ControlTick`; a driver only feeds measurements to the estimator before the tick
and applies what comes out (integrates the plant, sends the setpoint, compares it with a log).

Units and frames: SI, rad, model frame (world NWU z up, body FLU); times in s. ``t_v`` is the vehicle's clock
(the estimator's time base), ``t_ref`` the reference's clock (0 where the flight's reference starts).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

from estimators.filters.factory import Estimator
from estimators.model.control_state import ControlState
from offboard.control.controllers.protocol import Controller
from offboard.control.smc import Command

__all__ = ["ActuatorLag", "ControlTick", "Mapper", "TickFaults", "TickOutput"]


class Mapper(Protocol):
    """Command -> autopilot setpoint (``offboard.flight.command_mapping.CommandMapper``)."""

    def map(self, t: float, cmd: Command, est: ControlState) -> Any: ...


#: fault injection for tests of the safety net: ``faults(stage, t_ref, value) -> value`` with stage ``"estimate"``
#: (a ControlState), ``"reference"`` (the shifted ``F_x`` tuple) or ``"command"`` (a Command)
TickFaults = Callable[[str, float, Any], Any]


class TickOutput(NamedTuple):
    """What one tick computed. est: the estimate used; ref: the reference sample (unshifted); rfx, rfy: the flat
    output references as given to the controller (shifted by the origin); rz: the height reference as given (raised
    by the origin's height); cmd: the controller's command;
    setpoint: the mapped setpoint (None without a mapper); estimate_s: wall time of the estimate (s)."""

    est: ControlState
    ref: Any
    rfx: tuple[float, ...]
    rfy: tuple[float, ...]
    rz: tuple[float, ...]
    cmd: Command
    setpoint: Any
    estimate_s: float


class ControlTick:
    """One controller tick (see the module docstring).

    controller: the law (:class:`~offboard.control.controllers.protocol.Controller`); reference: ``sample(t_ref)`` with
    ``fx``, ``fy`` (orders 0..6), ``z``, ``psi``; estimator: the :class:`~estimators.filters.factory.Estimator` asked
    for ``estimate(t_v)`` and given the delivered command (None: the driver passes the estimate, e.g. the true state);
    mapper: command -> setpoint (None: no setpoint, the simulated plant takes the command); lag: what the motors
    deliver of the command, fed to the estimator (None: the command itself); origin: shift (m) added to the
    reference's ``F_x``, ``F_y`` and, when a third value is given and non-zero, to its height (the take-off
    point's local height: a reference's heights are above it); None: unshifted; faults: test hook (:data:`TickFaults`);
    predict: ``predict(estimator, t_v)`` instead of ``estimator.estimate(t_v)`` (the live loop's
    ``estimate_ahead``, where a filter's own forward prediction plugs in).
    """

    __slots__ = ("controller", "estimator", "faults", "lag", "mapper", "origin", "predict", "reference")

    def __init__(
        self,
        controller: Controller,
        reference: Any,
        *,
        estimator: Estimator | None = None,
        mapper: Mapper | None = None,
        lag: ActuatorLag | None = None,
        origin: tuple[float, float] | tuple[float, float, float] | None = None,
        faults: TickFaults | None = None,
        predict: Callable[[Any, float], ControlState] | None = None,
    ) -> None:
        self.controller = controller
        self.predict = predict
        self.reference = reference
        self.estimator = estimator
        self.mapper = mapper
        self.lag = lag
        self.origin = origin
        self.faults = faults

    def __call__(self, t_v: float, t_ref: float, est: ControlState | None = None) -> TickOutput:
        """Run the tick at vehicle time ``t_v`` and reference time ``t_ref``; ``est`` replaces the estimator's
        estimate when given (the driver's true state)."""
        faults = self.faults
        estimator = self.estimator
        te = 0.0
        if est is None:
            assert estimator is not None, "a tick without an estimator needs the estimate"
            pe = time.perf_counter()
            est = estimator.estimate(t_v) if self.predict is None else self.predict(estimator, t_v)
            te = time.perf_counter() - pe
        if faults is not None:
            est = faults("estimate", t_ref, est)
        ref = self.reference.sample(t_ref)
        rz = ref.z
        if self.origin is None:
            rfx, rfy = ref.fx, ref.fy
        else:
            origin = self.origin
            rfx = (ref.fx[0] + origin[0], *ref.fx[1:])
            rfy = (ref.fy[0] + origin[1], *ref.fy[1:])
            if len(origin) > 2 and origin[2]:
                rz = (ref.z[0] + origin[2], *ref.z[1:])
        if faults is not None:
            rfx = faults("reference", t_ref, rfx)
        cmd = self.controller.step(t_ref, est, rfx, rfy, rz, ref.psi)
        if faults is not None:
            cmd = faults("command", t_ref, cmd)
        sp = None if self.mapper is None else self.mapper.map(t_ref, cmd, est)
        if estimator is not None:
            thrust, tau = cmd.thrust, (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)
            if math.isfinite(thrust + tau[0] + tau[1] + tau[2]):  # a non-finite command never reaches the filter
                if self.lag is not None:
                    thrust, tau = self.lag(t_v, thrust, tau)
                estimator.push_command(t_v, thrust, tau)
        return TickOutput(est, ref, rfx, rfy, rz, cmd, sp, te)


class ActuatorLag:
    """The thrust and torques the motors deliver for a stream of commands: a first-order lag with the vehicle
    file's ``motor_time_constant`` (s), discretized exactly between calls (``a = 1 - exp(-dt / tau)``). This is
    the command the filter is given (``push_command``), in the live loop and in ``slung replay``: with the
    setpoint itself, the filter's vertical model runs 20 ms ahead of the motors, and under the sliding-mode
    thrust switching (+-1.5 N from tick to tick) the accelerometer then disagrees with it by more than its gate
    on one update in ten, which lets the height estimate drift by centimetres (measured over the paper scenario
    with px4-typical sensors: 3629 vertical accelerometer updates gated, height tracking 5.7 mm RMS; with the
    lag 8 gated, 2.9 mm; ``slung sim``, whose plant applies the command without lag, 3.2 mm). The first call
    returns its command unchanged (the state starts there); N, N m, model frame."""

    __slots__ = ("_a", "_dt", "_s", "_t", "_tau")

    def __init__(self, time_constant_s: float) -> None:
        if not (math.isfinite(time_constant_s) and time_constant_s >= 0.0):
            raise ValueError(f"motor time constant must be a finite number >= 0 s, got {time_constant_s!r}")
        self._tau = time_constant_s
        self._t: float | None = None
        self._s = [0.0, 0.0, 0.0, 0.0]
        self._dt = -1.0
        self._a = 1.0

    def __call__(
        self, t: float, thrust: float, tau: tuple[float, float, float]
    ) -> tuple[float, tuple[float, float, float]]:
        """Delivered (thrust N, (tau_phi, tau_theta, tau_psi) N m) at time ``t`` (s) after commanding these
        finite values from ``t`` on."""
        s = self._s
        if self._t is None or self._tau == 0.0:
            s[0], s[1], s[2], s[3] = thrust, tau[0], tau[1], tau[2]
        else:
            dt = t - self._t
            if dt != self._dt:
                self._dt = dt
                self._a = 1.0 - math.exp(-dt / self._tau) if dt > 0.0 else 0.0
            a = self._a
            s[0] += a * (thrust - s[0])
            s[1] += a * (tau[0] - s[1])
            s[2] += a * (tau[1] - s[2])
            s[3] += a * (tau[2] - s[3])
        self._t = t
        return s[0], (s[1], s[2], s[3])
