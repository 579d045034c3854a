"""At what precision the run folder's tick log (``timeseries_live.slts``) keeps each column
(``offboard.logs.timeseries_file`` storage kinds), by what the column is for. One rule per kind of column, so that a
column added to ``offboard.flight.loop_records.LIVE_COLUMNS`` falls under its prefix's rule (an unknown name is
kept float64, whole).

- **float64, as computed, delta-coded**: the times (``t_vehicle``, ``t_ref``, ``t_local``) and ``n_meas``: the
  replay finds its ticks and measurements by them.
- **float32**: the estimate (``est_*``), the controller's output (``cmd_thrust``, ``cmd_tau_*``, the saturation
  and validity flags), the reference (``ref_*``), the setpoint's wire fields (``sp*``: MAVLink carries them as
  float32, so float32 keeps exactly what went on the wire), the emulator's truth (``truth_*``) and the counters.
  Seven significant digits: ``slung replay`` checks that it reproduces the estimates and setpoints identically at
  this precision (its ``live_agreement`` says ``compared_at``). The smooth ones (reference, truth) are delta-coded.
- **float16**: what is read as plots and statistics: the filter's own account (``sd_*`` standard deviations,
  ``nu_*`` normalized innovations), the law's internals (its sliding variables ``cmd_s_*``, ``cmd_sigma_*`` and
  error integrals ``int_*``, which the replay recomputes and does not read) and the tick's timing
  (``compute_s``, ``latency_s``): three significant digits (a microsecond in a millisecond).

Measured on the 10-minute demo's tick log (152 000 ticks, blocks of 16384 rows, 7 Dec 2026): 579 bytes a tick
all float64, 199 stored like this (30 MB).
"""

from __future__ import annotations

from collections.abc import Sequence

#: (name prefix, storage kind), the first match wins; the names not matched are kept float64
_RULES: tuple[tuple[str, str], ...] = (
    ("t_vehicle", "f8 delta"),
    ("t_ref", "f8 delta"),
    ("t_local", "f8 delta"),
    ("n_meas", "f8 delta"),
    ("sd_", "f2"),
    ("nu_", "f2"),
    ("compute_s", "f2"),
    ("latency_s", "f2"),
    ("int_", "f2 delta"),
    ("cmd_s_", "f2"),
    ("cmd_sigma_", "f2"),
    ("ref_", "f4 delta"),
    ("truth_", "f4 delta"),
    ("est_", "f4"),
    ("cmd_", "f4"),
    ("sp", "f4"),
    ("gated_", "f4"),
    ("fallback", "f4"),
)


def live_storage(columns: Sequence[str]) -> tuple[str, ...]:
    """The storage kind of each of ``columns`` (a tick log's names)."""
    return tuple(next((kind for prefix, kind in _RULES if name.startswith(prefix)), "f8") for name in columns)


__all__ = ["live_storage"]
