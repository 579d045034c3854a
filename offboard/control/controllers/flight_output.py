"""What a controller sends over MAVLink, by the level it commands at (``protocol.level_of``): the one place that
decides it for ``slung fly`` / ``slung demo``, ``slung replay`` and ``slung compare --mavlink``.

- ``torque`` (``smc``, ``lqr``): its thrust and torques, mapped by ``offboard.flight.command_mapping.CommandMapper``
  to the chosen setpoint (actuator controls, or the attitude that gives those torques);
- ``attitude`` (``smc-attitude``): its attitude setpoint and thrust (``AttitudeLawMapper``), ``--output attitude``
  only;
- ``position`` (the stock cascade, ``zv``, ``zvd``, ``swing-feedback``): over ``--output attitude`` what a stock
  autopilot's position controller hands its attitude controller, the attitude setpoint and thrust of its own
  position / velocity loops (:class:`AttitudeSetpointOutput`), the autopilot's attitude and rate loops doing the
  rest; over ``--output actuator`` its own rate loop's torques.
"""

from __future__ import annotations

import math

from estimators.errors import UserError
from estimators.model.control_state import ControlState
from estimators.model.vehicle import Vehicle
from offboard.control.controllers.protocol import Controller, level_of
from offboard.control.smc import Ref
from offboard.control.smc_attitude import AttitudeCommand


class AttitudeSetpointOutput:
    """A position-level controller whose output is its attitude setpoint and thrust (an
    :class:`~offboard.control.smc_attitude.AttitudeCommand`, for ``AttitudeLawMapper``) instead of its own rate loop's
    torques: the torques stay in the command (logged), the setpoint carries roll, pitch and heading (rad) and, as
    feed-forward, the reference's yaw rate (rad/s)."""

    level = "attitude"

    def __init__(self, base: Controller) -> None:
        self.base = base
        self.name = base.name

    def reset(self) -> None:
        self.base.reset()

    def step(self, t: float, est: ControlState, ref_fx: Ref, ref_fy: Ref, ref_z: Ref, ref_psi: Ref) -> AttitudeCommand:
        cmd = self.base.step(t, est, ref_fx, ref_fy, ref_z, ref_psi)
        sp = getattr(self.base, "attitude_sp", None)
        valid = cmd.valid and sp is not None
        phi, theta, psi = sp if valid else (0.0, 0.0, ref_psi[0] if math.isfinite(ref_psi[0]) else 0.0)
        r_ff = ref_psi[1] if valid and len(ref_psi) > 1 else 0.0
        return AttitudeCommand(*cmd[:9], valid, phi, theta, psi, 0.0, 0.0, r_ff)

    def memory_fields(self) -> tuple[float, float, float, float]:
        return self.base.memory_fields()


def as_flown(controller: Controller, output: str) -> tuple[Controller, str]:
    """``controller`` as it flies over ``output`` (``attitude`` or ``actuator``), and the law level whose mapping
    takes its commands (``attitude``: ``AttitudeLawMapper``; ``torque``: ``CommandMapper``). UserError for an
    attitude-level controller on ``--output actuator`` (it has no torques an autopilot could take)."""
    level = level_of(controller)
    if level == "attitude":
        if output != "attitude":
            raise UserError(
                f"controller {controller.name!r} commands attitude and thrust: use --output attitude "
                f"(--output {output} takes torques)"
            )
        return controller, "attitude"
    if level == "position" and output == "attitude":
        return AttitudeSetpointOutput(controller), "attitude"
    return controller, "torque"


def registered_as_flown(
    name: str, vehicle: Vehicle, output: str, *, switching: str, epsilon: float, drag_feedforward: bool
) -> tuple[Controller, str]:
    """Controller ``name`` of the registry, fresh for the nominal ``vehicle``, as it flies over ``output``
    (:func:`as_flown`): what ``slung fly --controller NAME`` flies and ``slung replay`` re-runs on its log. The
    sliding-mode laws' options (``switching``, ``epsilon``; ``drag_feedforward``: the vehicle's drag in the law's
    model) go to every factory, which uses those it has."""
    from offboard.control.controllers import registry

    built = registry.make(name, vehicle, switching=switching, epsilon=epsilon, drag_feedforward=drag_feedforward)
    return as_flown(built, output)
