"""The inputs and outputs of ``slung replay`` (``offboard.logs.replay``): the reference a flight used, the live
loop's own per-tick log (``timeseries_live.slts``) read back, the replay's configuration, its table's columns and
its result, and the filter's first guess. Model frame (world NWU z up, body FLU), SI units, radians; times in s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimators.errors import UserError
from estimators.model.control_state import ControlState
from estimators.model.measurements import Attitude, LoadAngle, PositionVelocity
from estimators.model.vehicle import Vehicle
from offboard.logs.estimate_columns import EST_NAMES, INNOVATION_COLUMNS, SIGMA_COLUMNS
from offboard.logs.timeseries_file import read_table


@dataclass(frozen=True)
class ReferenceSpec:
    """The reference a logged flight used: the scenario's name (or a trajectory file). ``start``: the vehicle time
    (s) at which the reference's t = 0 fell, NaN = at the first replayed tick (ignored with the live run's tick log,
    whose controller time ``t_ref`` is used). ``origin``: the horizontal shift (m, world NWU) the live loop added
    to the reference's F_x, F_y, or None to recompute it as the loop does (vehicle position at the start minus
    the reference's start). ``ground_z``: the local z (model frame, m) of the take-off point the live loop added to
    the reference's heights (``metrics.json`` ``config.ground_z``; 0 for logs from before it was recorded).
    ``stop_after_s``: where the live loop's smooth stop to rest began (``config.stop_after_s``), None: none."""

    scenario: str
    start: float = math.nan
    origin: tuple[float, float] | None = None
    trajectory: str | None = None
    ground_z: float = 0.0
    stop_after_s: float | None = None

    def build(self) -> Any:
        """The reference object (``offboard.control.reference``): the named scenario's or the trajectory file's,
        with the live loop's smooth stop from ``stop_after_s`` (s) on when it flew one."""
        if self.trajectory is not None:
            from offboard.control.trajectory_file import load_trajectory_file

            reference = load_trajectory_file(self.trajectory)
        else:
            from offboard.control.scenarios import make_scenario

            reference = make_scenario(self.scenario).reference
        if self.stop_after_s is None:
            return reference
        from offboard.control.reference_stop import StoppingReference

        return StoppingReference(reference, self.stop_after_s)


class LiveLogMismatchError(ValueError):
    """The live tick log given to the replay does not belong to the tlog."""


_FLOAT64 = np.dtype("<f8")


@dataclass(frozen=True)
class LiveRun:
    """The live loop's own per-tick log (``timeseries_live.slts`` of ``slung fly`` / ``slung demo``; columns of
    ``offboard.flight.loop.LIVE_COLUMNS``): tick vehicle time ``t_vehicle`` (s), controller time ``t_ref`` (s),
    cumulative number of measurements pushed to the estimator ``n_meas``, the estimate the controller used (N x 24,
    order :data:`EST_COLUMNS`) and the setpoint's wire fields (N x 8 attitude / N x 4 actuator); ``est_stored`` /
    ``sp_stored``: the float type the tick log kept them at (float64 in the folders of the format's first version,
    float32 since: ``offboard.logs.live_storage``), the precision the replay compares at."""

    t_vehicle: np.ndarray
    t_ref: np.ndarray
    n_meas: np.ndarray
    est: np.ndarray
    sp: np.ndarray
    est_stored: np.dtype = _FLOAT64
    sp_stored: np.dtype = _FLOAT64


LIVE_EST_NAMES = EST_NAMES  # the loop's estimate columns, read back


def load_live_table(path: Any) -> LiveRun | None:
    """The :class:`LiveRun` in the tick log at ``path`` (``timeseries_live.slts``, or the ``timeseries_live.csv`` of
    a run folder written before that format: ``offboard.logs.timeseries_file.read_table`` reads both), or None when
    the file is missing, unreadable or lacks a needed column. A tick log cut short (a killed flight) gives its whole
    blocks."""
    try:
        table = read_table(path)
    except UserError:
        return None
    idx = table.index
    need = ["t_vehicle", "t_ref", "n_meas", *("est_" + n for n in LIVE_EST_NAMES), *(f"sp{i}" for i in range(4))]
    if any(n not in idx for n in need):
        return None
    sp_cols = [idx[f"sp{i}"] for i in range(8) if f"sp{i}" in idx]
    data = table.data
    est = data[:, [idx["est_" + n] for n in LIVE_EST_NAMES]]
    sp = data[:, sp_cols]
    if sp.shape[1] >= 8 and np.all(np.isnan(sp[:, 4:8])):
        sp = sp[:, :4]
    est_stored = max((table.stored_as("est_" + n) for n in LIVE_EST_NAMES), key=lambda d: d.itemsize)
    sp_stored = max((table.stored_as(f"sp{i}") for i in range(4)), key=lambda d: d.itemsize)
    return LiveRun(
        data[:, idx["t_vehicle"]],
        data[:, idx["t_ref"]],
        data[:, idx["n_meas"]].astype(int),
        est,
        sp,
        est_stored,
        sp_stored,
    )


@dataclass(frozen=True)
class ReplayConfig:
    """How to replay.

    vehicle: the controller's nominal vehicle; t_from / t_to: vehicle-time window (s, since boot) or None;
    rate_hz: tick rate where no setpoints are logged (and the estimator's step when the log does not say);
    estimator: estimator kind; load_sensor: None = use one when the log has it; delay_s: the estimator's fusion
    horizon (s); reference: see :class:`ReferenceSpec` (None: no controller); switching / epsilon: the
    controller's switching function; layer_errors: the torque-level law's per-loop boundary layers; actuation_lag_s:
    its model of the motors' lag (s; 0: the paper's law); law: ``"torque"`` (``offboard.control.smc``) or ``"attitude"``
    (``offboard.control.smc_attitude``), the live run's; gain_scale: the torque-level law's pole scale the live run
    chose for its measured loop delay (``offboard.control.delay_margin``; 1: the paper's gains); shared_roll_pitch:
    the live run's torque-level law limited its roll / pitch pair to an X frame's shared motor margin
    (``offboard.control.smc.ControllerParams``); external_feedforward: the live run's filter fed its estimate of the
    external acceleration forward (``--external-feedforward``, ``MeasuredTuning.external_feedforward``);
    output / mask: None = from the logged setpoints; mapping: extra ``MappingConfig`` fields (limits); autopilot:
    ``AutopilotModel`` fields (flavour, attitude_p, rate_bandwidth, hover_thrust_norm, angle_boost; flavour
    defaults to the HEARTBEAT's);
    live: the live run's tick log, for an exact replay; estimate_only: run the estimator on the grid over the whole
    log even where it holds an offboard flight (no controller); controller: a controller of the registry replayed
    instead of the sliding-mode law of ``law`` (None: that law), as ``slung fly --controller`` flew it.
    """

    vehicle: Vehicle = field(default_factory=Vehicle)
    t_from: float | None = None
    t_to: float | None = None
    rate_hz: float = 250.0
    estimator: str = "kf"
    load_sensor: bool | None = None
    delay_s: float = 0.012
    reference: ReferenceSpec | None = None
    switching: str = "smooth"
    epsilon: float = 1.0
    layer_errors: tuple[float, float, float] | None = None
    actuation_lag_s: float = 0.0
    law: str = "torque"
    gain_scale: float = 1.0
    shared_roll_pitch: bool = False
    external_feedforward: bool = False
    #: the attitude-level law models the vehicle's drag (None: as ``slung fly`` would now, ``registry.drag_in_law``;
    #: a slung flight recorded before the term existed flew without it: False)
    drag_feedforward: bool | None = None
    output: str | None = None
    mask: str | None = None
    mapping: dict[str, Any] | None = None
    autopilot: dict[str, Any] | None = None
    live: LiveRun | None = None
    estimate_only: bool = False
    controller: str | None = None


#: the replay's estimate columns: the flat-output chains ``Fx``, ``Fx_d1`` ... ``Fy_d5``, then the live log's names
EST_COLUMNS: tuple[str, ...] = (
    *(f"F{ax}" if i == 0 else f"F{ax}_d{i}" for ax in "xy" for i in range(6)),
    *EST_NAMES[12:],
)


SP_ATT = ("q_w", "q_x", "q_y", "q_z", "roll_rate", "pitch_rate", "yaw_rate", "thrust")


SP_ACT = ("roll", "pitch", "yaw", "thrust")


def columns_for(output: str) -> tuple[str, ...]:
    """The time-series columns for setpoint kind ``output`` ("attitude" or "actuator")."""
    sp = SP_ATT if output == "attitude" else SP_ACT
    return (
        "t",
        "t_ref",
        "logger_t",
        "tick_source",
        *EST_COLUMNS,
        "meas_alpha_x",
        "meas_alpha_y",
        "pos_x",
        "pos_y",
        "pos_z",
        "Fx_ref",
        "Fy_ref",
        "z_ref",
        "psi_ref",
        "cmd_thrust",
        "cmd_tau_phi",
        "cmd_tau_theta",
        "cmd_tau_psi",
        *("sp_" + c for c in sp),
        *("log_" + c for c in sp),
        "ap_q_w",
        "ap_q_x",
        "ap_q_y",
        "ap_q_z",
        "ap_thrust",
        "offboard",
        "live_est_diff",
        "live_sp_diff",
        "ap_phi",
        "ap_theta",
        "ap_psi",
        "segment",
        "diverged",
        "gated",
        *SIGMA_COLUMNS,
        *INNOVATION_COLUMNS,
    )


@dataclass
class ReplayResult:
    """The replayed run: ``data[k, col[name]]`` per tick, the column names and the metrics dictionary;
    ``swing_truth``: (n, 2) alpha_x, alpha_y of the payload's truth per tick (rad, NaN where unknown), when the log
    has one (DataFlash SLUP, a payload system's GLOBAL_POSITION_INT)."""

    data: np.ndarray
    columns: tuple[str, ...]
    metrics: dict[str, Any]
    output: str
    swing_truth: np.ndarray | None = None

    def column(self, name: str) -> np.ndarray:
        """One column over the ticks."""
        return self.data[:, self.columns.index(name)]


def initial_guess(
    vehicle: Vehicle, pv: PositionVelocity | None, att: Attitude | None, load: LoadAngle | None
) -> ControlState:
    """The estimator's prior as the live loop builds it: :func:`offboard.flight.loop.initial_guess` (position and
    velocity, attitude, swing from the cable-angle sensor, 0 without one; every rate not measured is 0)."""
    from offboard.flight.loop import initial_guess as live_initial_guess

    return live_initial_guess(vehicle, att, pv, load)
