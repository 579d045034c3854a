"""The estimate columns of the live tick log (``est_<name>`` in ``timeseries_live.slts``): one list for the loop
that writes them and the replay that reads them back. Model frame, SI / rad: flat outputs F_x, F_y and their
derivatives of orders 0..5 (m ... m/s^5), height and its rate, Euler angles and their rates, swing angles and rates.

Beside them, the filter's own account of the estimate, read every tick without changing the filter:

- ``sd_<name>`` (:data:`SIGMA_COLUMNS`): standard deviations from the filter's covariance at the tick
  (``Estimator.sigmas``: load position F_x, F_y, height, roll, pitch, heading, swing angles, vehicle position; m /
  rad; NaN where not estimated);
- ``nu_<stream>`` (:data:`INNOVATION_COLUMNS`): the newest record's normalized innovation per update stream (RMS
  over its channels, dimensionless: about 1 on average for a consistent filter) and ``gated_<stream>`` the
  cumulative count of updates the gate refused.
"""

from __future__ import annotations

from estimators.filters.factory import INNOVATION_STREAMS, SIGMA_NAMES
from estimators.model.control_state import ControlState

#: the chains ``fx0`` ... ``fx5``, ``fy0`` ... ``fy5``, then the remaining fields of ``ControlState`` in its order
EST_NAMES: tuple[str, ...] = (
    *(f"fx{i}" for i in range(6)),
    *(f"fy{i}" for i in range(6)),
    *ControlState._fields[2:],
)

#: ``Estimator.sigmas()``, in its order
SIGMA_COLUMNS: tuple[str, ...] = tuple("sd_" + n for n in SIGMA_NAMES)
#: ``Estimator.innovations()``, in its order
INNOVATION_COLUMNS: tuple[str, ...] = (
    *("nu_" + s for s in INNOVATION_STREAMS),
    *("gated_" + s for s in INNOVATION_STREAMS),
)

__all__ = ["EST_NAMES", "INNOVATION_COLUMNS", "SIGMA_COLUMNS"]
