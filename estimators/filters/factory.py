"""Build an estimator by name; the :class:`Estimator` protocol every driver (sim, live link, replay) uses."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from estimators.errors import UserError
from estimators.model.control_state import ControlState
from estimators.model.measurements import Measurement
from estimators.model.vehicle import Vehicle

#: "truth" is handled by the simulator itself (the controller reads the plant state); "kf" (the filter fed by the
#: measured attitude and accelerometer, ``estimators.filters.measured_kf``) and "kf-torque" (the earlier filter that
#: predicts from the commanded torques, ``estimators.filters.kf``; in-process simulation only) are built here.
ESTIMATOR_KINDS: tuple[str, ...] = ("truth", "kf", "kf-torque")

#: the quantities whose standard deviations :meth:`Estimator.sigmas` returns, in its order (model frame, SI / rad):
#: the load's position F_x, F_y (m), the height z (m), roll, pitch, heading (rad), the swing angles alpha_x,
#: alpha_y (rad) and the vehicle's position p_x, p_y (m)
SIGMA_NAMES: tuple[str, ...] = ("fx0", "fy0", "z", "phi", "theta", "psi", "alpha_x", "alpha_y", "p_x", "p_y")
#: the update streams of :meth:`Estimator.innovations`: horizontal position / velocity, height / vertical velocity,
#: tilt and its rate, heading and its rate, accelerometer (the swing's measurement), cable-angle sensor
INNOVATION_STREAMS: tuple[str, ...] = ("pos", "z", "tilt", "psi", "acc", "load")


class Estimator(Protocol):
    """Measurements and commands in, :class:`ControlState` out (model frame, SI, rad)."""

    def initialize(self, t: float, guess: ControlState) -> None: ...

    def push(self, m: Measurement) -> None: ...

    def push_command(self, t: float, thrust: float, torque: tuple[float, float, float]) -> None: ...

    def estimate(self, t: float, lead_s: float = 0.0) -> ControlState:
        """The state at ``t + lead_s`` (s, vehicle time): records sampled before the fusion horizon fused, then
        predicted forward. ``lead_s`` >= 0 is the measured delay to act over (a setpoint's way to the vehicle);
        the filter's own time stays ``t``."""
        ...

    def covariance(self) -> np.ndarray:
        """The covariance of the filter's state at the last output time (a copy: reading it changes nothing)."""
        ...

    def sigmas(self) -> tuple[float, ...]:
        """Standard deviations of :data:`SIGMA_NAMES` at the last output time (NaN: not estimated), read without
        changing the filter (the live loop logs them every tick; the replay must stay bit-identical)."""
        ...

    def innovations(self) -> tuple[float, ...]:
        """Per stream of :data:`INNOVATION_STREAMS`: the newest record's normalized innovation (innovation over the
        square root of its predicted variance, RMS over the record's channels; NaN before the first), then the
        cumulative count of that stream's updates refused by the gate. A read without side effects."""
        ...

    def nees(self, t: float, truth: ControlState) -> float: ...

    def stats(self) -> dict[str, int]: ...


def default_tuning(kind: str) -> Any:
    """The noise assumptions filter ``kind`` starts from (a frozen dataclass with ``sigma_*`` fields), e.g. for
    replay to set the measurement noise fitted to a log."""
    if kind == "kf-torque":
        from estimators.filters.kf import Tuning

        return Tuning()
    from estimators.filters.measured_kf import MeasuredTuning

    return MeasuredTuning()


def make_estimator(
    kind: str, vehicle: Vehicle, *, load_sensor: bool, rate_hz: float, delay_s: float = 0.012, tuning: Any = None
) -> Estimator:
    """The estimator ``kind`` for the controller's nominal ``vehicle`` at control rate ``rate_hz`` (Hz).

    load_sensor: whether a cable-angle sensor is fitted; delay_s: fusion horizon behind the output, s (must
    exceed the sensors' latency); tuning: the filter's noise assumptions (:func:`default_tuning` of the kind;
    None: its defaults). ``"kf"`` and ``"kf-torque"`` are built here; ``"truth"`` and unknown kinds are UserErrors.
    """
    if kind == "kf":
        from estimators.filters.measured_kf import MeasuredKalmanEstimator

        if tuning is not None:
            return MeasuredKalmanEstimator(
                vehicle, load_sensor=load_sensor, rate_hz=rate_hz, delay_s=delay_s, tuning=tuning
            )
        return MeasuredKalmanEstimator(vehicle, load_sensor=load_sensor, rate_hz=rate_hz, delay_s=delay_s)
    if kind == "kf-torque":
        from estimators.filters.kf import KalmanEstimator

        if tuning is not None:  # noise assumptions other than the sensor preset's (e.g. fitted to a log)
            return KalmanEstimator(vehicle, load_sensor=load_sensor, rate_hz=rate_hz, delay_s=delay_s, tuning=tuning)
        return KalmanEstimator(vehicle, load_sensor=load_sensor, rate_hz=rate_hz, delay_s=delay_s)
    if kind == "truth":
        raise UserError("estimator 'truth' has no filter: the simulator feeds the true state to the controller")
    raise UserError(f"unknown estimator {kind!r} (known: {', '.join(ESTIMATOR_KINDS)})")


__all__ = ["ESTIMATOR_KINDS", "INNOVATION_STREAMS", "SIGMA_NAMES", "Estimator", "default_tuning", "make_estimator"]
