"""The live loop's configuration and records (``offboard.flight.loop``): its rate limits, the columns of its tick
log (``timeseries_live.csv``), ``LoopConfig``, the events and statistics it keeps and the ``FlightResult`` it
returns. SI units and radians, model frame; times in s (vehicle clock unless named otherwise)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from offboard.control.options import EndAction, values
from offboard.flight.latency import DEFAULT_LIMIT_S, LIMIT_RANGE_S
from offboard.flight.staleness import STALE_CEILING_S, STALE_FLOOR_S
from offboard.logs.estimate_columns import EST_NAMES, INNOVATION_COLUMNS, SIGMA_COLUMNS

RATE_MIN_HZ = 20.0


RATE_MAX_HZ = 1000.0


DEFAULT_RATE_HZ = 250.0


#: Columns of the flight log (``timeseries_live.csv``), all SI / rad, model frame, full float precision.
#: t_vehicle: tick time on the vehicle clock (s); t_ref: reference time (s); t_local: local monotonic time (s);
#: n_meas: measurements pushed to the estimator before this tick (cumulative, in tlog order); est_*: the estimate
#: the controller used; sd_*, nu_*, gated_*: the filter's standard deviations, normalized innovations and refused
#: updates after the tick (``offboard.logs.estimate_columns``; read after the setpoint is sent); ref_*: reference jets
#: (already shifted by the origin: horizontally to where the vehicle was, vertically to the take-off point's local
#: z); int_*: controller integrals after
#: the step; cmd_*: controller output; sp0..sp8: the setpoint's wire fields (attitude: q w,x,y,z NED->FRD,
#: roll/pitch/yaw rate FRD, thrust, type_mask; actuator: roll, pitch, yaw, thrust, NaN x5); fallback: 1 when the
#: mapper replaced the command; compute_s, latency_s: tick timing; truth_*: the plant state (18 floats) when a
#: truth probe is attached (the demo), NaN otherwise, sampled before the tick's setpoint is sent (in lockstep the
#: plant is then exactly at t_vehicle); truth_tension: cable tension (N); truth_dist_*: the external disturbance
#: the plant receives from t_vehicle on (force on the vehicle, world N; yaw torque, N m), NaN if not told.
LIVE_COLUMNS: tuple[str, ...] = (
    "t_vehicle",
    "t_ref",
    "t_local",
    "n_meas",
    *("est_" + n for n in EST_NAMES),
    *SIGMA_COLUMNS,
    *INNOVATION_COLUMNS,
    *(f"ref_fx{i}" for i in range(7)),
    *(f"ref_fy{i}" for i in range(7)),
    "ref_z0",
    "ref_z1",
    "ref_z2",
    "ref_psi0",
    "ref_psi1",
    "ref_psi2",
    "int_z",
    "int_psi",
    "int_fx",
    "int_fy",
    "cmd_thrust",
    "cmd_tau_phi",
    "cmd_tau_theta",
    "cmd_tau_psi",
    "cmd_s_z",
    "cmd_s_psi",
    "cmd_sigma_x",
    "cmd_sigma_y",
    "cmd_saturated",
    "cmd_valid",
    *(f"sp{i}" for i in range(9)),
    "fallback",
    "compute_s",
    "latency_s",
    *(f"truth_x{i}" for i in range(18)),
    "truth_tension",
    "truth_dist_fx",
    "truth_dist_fy",
    "truth_dist_fz",
    "truth_dist_tpsi",
)


LIVE_COL = {n: i for i, n in enumerate(LIVE_COLUMNS)}


#: truth_probe(t_vehicle) -> (18-float plant state, cable tension N[, (dist_fx, dist_fy, dist_fz, dist_tpsi)]) or None
TruthProbe = Callable[[float], "tuple[Any, ...] | None"]


@dataclass(frozen=True)
class LoopConfig:
    """Loop settings (SI). See the module docstring for each watchdog."""

    rate_hz: float = DEFAULT_RATE_HZ
    lockstep: bool = False
    lockstep_wait_s: float = 0.02
    #: the staleness limit's floor and ceiling, s: the limit itself is derived from the link's gaps measured in
    #: the hold before control (``offboard.flight.staleness``); equal, they fix it
    stale_s: float = STALE_FLOOR_S
    stale_ceiling_s: float = STALE_CEILING_S
    divergence_m: float = 1.0
    swing_limit_rad: float = 0.8
    #: after the reference's end, the longest the loop keeps flying it (a reference that ends at rest holds its end
    #: point) while the load's estimated swing amplitude is above ``settle_swing_rad``, s (0: end at once)
    settle_s: float = 5.0
    #: the swing amplitude (rad, both axes, angle and rate over the pendulum frequency) below which the loop ends
    settle_swing_rad: float = 0.05
    end_action: str = "hold"
    signal_action: str = "hold"
    exit_timeout_s: float = 2.0
    prime_s: float = 1.0
    takeoff: bool = True
    #: how long the pre-flight waits for attitude and position telemetry, s (ArduPilot SITL streams local
    #: position only ~40 s after boot)
    telemetry_timeout_s: float = 10.0
    #: the longest hold at the reference's start before control starts anyway (with the offset reported), s
    start_timeout_s: float = 10.0
    #: the load's position error (estimate vs reference, m) that ends the flight (``offboard.flight.supervisor``)
    tracking_limit_m: float = 2.0
    #: learn the hover throttle in flight and map thrust with it once trusted (``hover_thrust_learning``)
    learn_hover: bool = True
    #: the identification hover's length, s (0: no identification; at most 10 s: ``load_identification``)
    identify_load_s: float = 0.0
    #: latency watchdog: one-way delay (telemetry age or setpoint way, s) that ends the flight (offboard.flight.latency)
    latency_limit_s: float = DEFAULT_LIMIT_S
    #: the filter's fusion horizon without link delay (s): the sensors' own latency budget
    base_filter_delay_s: float = 0.012
    #: (stage, t_ref_start, t_ref_end): inject NaN into "measurement", "estimate", "reference", "command" or
    #: "setpoint" (the mapped setpoint itself, as a mapper bug would: the encoder's check is the last guard) during
    #: that window (tests of the no-NaN-on-the-wire guarantee)
    inject_nan: tuple[tuple[str, float, float], ...] = ()

    def validate(self) -> None:
        """ValueError for settings out of their documented range."""
        if not (RATE_MIN_HZ <= self.rate_hz <= RATE_MAX_HZ):
            raise ValueError(f"rate must be within {RATE_MIN_HZ:g}..{RATE_MAX_HZ:g} Hz, got {self.rate_hz:g}")
        if not (0.0 <= self.identify_load_s <= 10.0):
            raise ValueError(f"the identification hover must be within 0..10 s, got {self.identify_load_s:g}")
        if not (0.01 <= self.stale_s <= 5.0):
            raise ValueError(f"staleness limit must be within 0.01..5 s, got {self.stale_s:g}")
        if not (self.stale_s <= self.stale_ceiling_s <= 5.0):
            raise ValueError(
                f"staleness ceiling must be within the floor ({self.stale_s:g} s)..5 s, got {self.stale_ceiling_s:g}"
            )
        if not (0.05 <= self.swing_limit_rad <= 1.2):  # 1.2 rad: 69 degrees, beyond it the load is lost anyway
            raise ValueError(f"swing limit must be within 0.05..1.2 rad, got {self.swing_limit_rad:g}")
        if not (0.0 <= self.settle_s <= 600.0):
            raise ValueError(f"settle time must be within 0..600 s, got {self.settle_s:g}")
        if not (0.005 <= self.settle_swing_rad <= self.swing_limit_rad):
            raise ValueError(
                f"settle swing must be within 0.005 rad..the swing limit ({self.swing_limit_rad:g}), "
                f"got {self.settle_swing_rad:g}"
            )
        if not (0.05 <= self.divergence_m <= 10.0):
            raise ValueError(f"divergence limit must be within 0.05..10 m, got {self.divergence_m:g}")
        for a in (self.end_action, self.signal_action):
            if a not in values(EndAction):
                raise ValueError(f"end action must be hold or land, got {a!r}")
        if self.prime_s < 1.0:
            raise ValueError("the setpoint stream must be primed for at least 1 s before the mode switch")
        lo, hi = LIMIT_RANGE_S
        if not (lo <= self.latency_limit_s <= hi):
            raise ValueError(f"latency limit must be within {lo:g}..{hi:g} s, got {self.latency_limit_s:g}")
        if not (0.0 < self.telemetry_timeout_s <= 600.0):
            raise ValueError(f"telemetry timeout must be within 0..600 s, got {self.telemetry_timeout_s:g}")
        if not (0.5 <= self.start_timeout_s <= 600.0):
            raise ValueError(f"start timeout must be within 0.5..600 s, got {self.start_timeout_s:g}")
        if not (0.05 <= self.tracking_limit_m <= 100.0):
            raise ValueError(f"tracking-error limit must be within 0.05..100 m, got {self.tracking_limit_m:g}")


@dataclass
class LoopEvent:
    """Something the loop did or saw: vehicle time and local time (s), kind, reason."""

    t_vehicle: float
    t_local: float
    kind: str
    reason: str


@dataclass
class LoopStats:
    """Timing figures of the flight phase (s unless stated)."""

    ticks: int = 0
    elapsed_s: float = 0.0
    compute: list[float] = field(default_factory=list)
    estimator: list[float] = field(default_factory=list)
    latency: list[float] = field(default_factory=list)
    gaps: list[float] = field(default_factory=list)
    deadline_ticks: int = 0
    missed: int = 0
    sent_bytes: int = 0

    def summary(self, rate_hz: float) -> dict[str, Any]:
        """The ``loop`` block of metrics.json (times in microseconds)."""

        def pct(v: list[float], q: float) -> float | None:
            return float(np.percentile(np.asarray(v) * 1e6, q)) if v else None

        return {
            "rate_hz_requested": rate_hz,
            "rate_hz_achieved": self.ticks / self.elapsed_s if self.elapsed_s > 0 else None,
            "ticks": self.ticks,
            "elapsed_s": self.elapsed_s,
            "compute_us_p50": pct(self.compute, 50),
            "compute_us_p99": pct(self.compute, 99),
            "compute_us_max": pct(self.compute, 100),
            "estimator_us_p50": pct(self.estimator, 50),
            "estimator_us_p99": pct(self.estimator, 99),
            "latency_us_p50": pct(self.latency, 50),
            "latency_us_p99": pct(self.latency, 99),
            "latency_samples": len(self.latency),
            "gap_us_p50": pct(self.gaps, 50),
            "gap_us_p99": pct(self.gaps, 99),
            "gap_us_max": pct(self.gaps, 100),
            "deadline_ticks": self.deadline_ticks,
            "missed_deadlines": self.missed,
            "missed_fraction": self.missed / self.ticks if self.ticks else None,
        }


@dataclass
class FlightResult:
    """What a flight produced (the caller writes the files)."""

    rows: list[tuple[float, ...]]
    events: list[LoopEvent]
    stats: LoopStats
    ended_by: str
    end_state: str
    origin: tuple[float, float]
    estimator_stats: dict[str, int]
    mapper_events: list[Any]
    management_events: list[Any]
    warnings: list[str]
    autopilot: dict[str, Any]
    load_sensor: bool
    telemetry_counts: dict[str, int]
    #: local z of the take-off point (model frame, m): the reference's heights were flown above it
    ground_z: float = 0.0
    #: the supervisor's summary (``offboard.flight.supervisor.Supervisor.summary``)
    supervision: dict[str, Any] = field(default_factory=dict)
    #: measured link delays and the prediction horizon (``offboard.flight.latency.LinkLatency.summary``)
    latency: dict[str, Any] = field(default_factory=dict)
    #: the fusion horizon the flight's filter was built with (s; replay rebuilds the same filter)
    filter_delay_s: float | None = None
    #: the pole scale of the torque-level law's gains for the measured loop delay (``offboard.control.delay_margin``;
    #: 1: the paper's gains; replay applies the same)
    gain_scale: float = 1.0
    #: the reference's duration (s): rows with a later ``t_ref`` were flown after its end while the load settled
    #: (``LoopConfig.settle_s``)
    reference_duration_s: float = math.inf
    #: the staleness limit and the link's gaps it was derived from (``offboard.flight.staleness.Staleness.summary``)
    staleness: dict[str, Any] = field(default_factory=dict)
    #: the hover throttle learned in flight (``offboard.flight.hover_thrust_learning``; None before the take-off ended)
    hover_learning: dict[str, Any] | None = None
    #: the load identified in flight (``offboard.flight.load_identification.decide``; None when not asked)
    load_identification: dict[str, Any] | None = None
