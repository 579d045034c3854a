"""Build an estimator by name; the :class:`Estimator` protocol every driver (sim, live link, replay) uses."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from estimators.control_state import ControlState
from estimators.errors import UserError
from estimators.measurements import Measurement
from estimators.vehicle import Vehicle

#: "truth" is handled by the simulator itself (the controller reads the plant state); "kf" is built here.
ESTIMATOR_KINDS: tuple[str, ...] = ("truth", "kf")


class Estimator(Protocol):
    """Measurements and commands in, :class:`ControlState` out (model frame, SI, rad)."""

    def initialize(self, t: float, guess: ControlState) -> None: ...

    def push(self, m: Measurement) -> None: ...

    def push_command(self, t: float, thrust: float, torque: tuple[float, float, float]) -> None: ...

    def estimate(self, t: float) -> ControlState: ...

    def covariance(self) -> np.ndarray: ...

    def nees(self, t: float, truth: ControlState) -> float: ...

    def stats(self) -> dict[str, int]: ...


def make_estimator(
    kind: str, vehicle: Vehicle, *, load_sensor: bool, rate_hz: float, delay_s: float = 0.012
) -> Estimator:
    """The estimator ``kind`` for the controller's nominal ``vehicle`` at control rate ``rate_hz`` (Hz).

    load_sensor: whether a cable-angle sensor is fitted; delay_s: fusion horizon behind the output, s (must
    exceed the sensors' latency). Only ``"kf"`` is built here; ``"truth"`` and unknown kinds are UserErrors.
    """
    if kind == "kf":
        from estimators.kf import KalmanEstimator

        return KalmanEstimator(vehicle, load_sensor=load_sensor, rate_hz=rate_hz, delay_s=delay_s)
    if kind == "truth":
        raise UserError("estimator 'truth' has no filter: the simulator feeds the true state to the controller")
    raise UserError(f"unknown estimator {kind!r} (known: {', '.join(ESTIMATOR_KINDS)})")


__all__ = ["ESTIMATOR_KINDS", "Estimator", "make_estimator"]
