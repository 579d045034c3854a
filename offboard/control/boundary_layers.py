"""The torque-level law's per-loop boundary layers (docs/model.md C-12): the width of each loop's smooth switching
``s / (|s| + eps)`` scaled to its own sliding variable, for ``offboard.control.smc``."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from offboard.control.smc import Gains

#: the tracking errors (height m, heading rad, horizontal m) whose sliding variables are the flight's boundary layers
FLIGHT_LAYER_ERRORS = (0.02, 0.02, 0.02)


def error_boundary_layers(
    gains: Gains, errors: tuple[float, float, float] = FLIGHT_LAYER_ERRORS
) -> tuple[float, float, float]:
    """Each loop's boundary layer (height m/s, heading rad/s, horizontal m/s^5) scaled to its own sliding variable:
    the value that variable takes for a height / heading / horizontal error of ``errors`` alone, through its surface's
    error term (``lambda1``, ``gamma1``, ``K1``). One width for all (the paper's epsilon = 1) is a sign function for
    the sixth-order horizontal surface, whose variable is about 400 per centimetre of error, and a wide layer for
    the height surface (about 0.2 per centimetre): scaled, each loop's switching term turns linear once its error is
    of the order of ``errors``, adding the in-layer gain ``rho / eps`` to the surface (height 2.8, heading 0.9,
    horizontal 1.2 1/s with the paper's gains), instead of chattering at ``+-rho`` on the estimate's noise
    (``docs/model.md`` C-12)."""
    ez, epsi, ef = errors
    return (gains.lambda1 * ez, gains.gamma1 * epsi, gains.K[1] * ef)
