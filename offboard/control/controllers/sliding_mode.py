"""The paper's sliding-mode laws (the torque-level :func:`offboard.control.smc.step` and the attitude-level
:func:`offboard.control.smc_attitude.step`) behind the :class:`~offboard.control.controllers.protocol.Controller`
protocol.

Each law stays a pure step (``step(t, est, ref_fx, ref_fy, ref_z, ref_psi, memory, params) -> (command,
memory)``); this object only carries its memory (the four error integrals) between ticks, so that every driver
calls it the same way.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from estimators.model.control_state import ControlState
from offboard.control import smc, smc_attitude


class PureStepController:
    """A pure-step law with its memory: ``smc`` (torque level) or ``smc-attitude`` (attitude level)."""

    __slots__ = ("_step", "level", "memory", "name", "params")

    def __init__(self, step: Callable[..., Any], params: Any, name: str) -> None:
        #: the level it commands at (``protocol.level_of``): the attitude-level law's command carries its setpoint
        self.level = "attitude" if isinstance(params, smc_attitude.AttitudeParams) else "torque"
        self._step = step
        self.params = params
        self.name = name
        self.memory = smc.ControllerMemory()

    def reset(self) -> None:
        self.memory = smc.ControllerMemory()

    def step(
        self, t: float, est: ControlState, ref_fx: smc.Ref, ref_fy: smc.Ref, ref_z: smc.Ref, ref_psi: smc.Ref
    ) -> smc.Command:
        cmd, self.memory = self._step(t, est, ref_fx, ref_fy, ref_z, ref_psi, self.memory, self.params)
        return cmd

    def memory_fields(self) -> tuple[float, float, float, float]:
        m = self.memory
        return m.int_z, m.int_psi, m.int_fx, m.int_fy


def SlidingModeController(params: smc.ControllerParams, name: str = "smc") -> PureStepController:
    """``smc``: the paper's torque-level law (thrust N, body torques N m)."""
    return PureStepController(smc.step, params, name)


def AttitudeSlidingModeController(
    params: smc_attitude.AttitudeParams, name: str = "smc-attitude"
) -> PureStepController:
    """``smc-attitude``: the attitude-level law (attitude setpoint and thrust; ``offboard.control.smc_attitude``)."""
    return PureStepController(smc_attitude.step, params, name)


def law_for(params: Any) -> PureStepController:
    """The sliding-mode law that ``params`` configure (``AttitudeParams``: attitude level, else torque level)."""
    if isinstance(params, smc_attitude.AttitudeParams):
        return AttitudeSlidingModeController(params)
    return SlidingModeController(params)
