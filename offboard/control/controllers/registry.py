"""Controllers by name, as ``slung compare`` / ``slung sweep`` take them (``--controllers smc,cascade,...``) and
``slung sim`` / ``fly`` / ``demo`` / ``replay`` take one (``--controller NAME``).

Each entry builds a fresh :class:`~offboard.control.controllers.protocol.Controller` for the controller's nominal
vehicle; the baselines are imported only when asked for (LQR needs python-control). A new controller is its module
and one line in :data:`CONTROLLERS` (or, from outside the package, one call of :func:`register`):
docs/architecture.md walks through it.
"""

from __future__ import annotations

from collections.abc import Callable

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.controllers.protocol import Controller
from offboard.control.smc_attitude_design import InnerLoop

#: the attitude telemetry's age the ``smc`` row's law leads over besides the motors' lag (s): px4-typical's
#: 100 Hz ATTITUDE is 5 ms old on average when the next one arrives, plus 4 ms latency and 1.5 ms mean jitter,
#: plus the 0-20 ms the default sweep adds (docs/compare.md#the-smc-row-the-actuation-lag-designed-in)
TELEMETRY_AGE_S = 0.02
#: the ``smc`` row's switching amplitude, m/s^6: the paper's 1000 makes the sign switching chatter through the
#: lags into a residual swing above the sweep's bound (0.056 rad against 0.05 at 40 ms motors, noise x2)
RHO_F = 100.0
#: the ``smc`` row's pole scale (``smc.Gains.scaled``): every loop's poles at 0.9 of the paper's. With the paper's
#: poles the law, its lead designed for the nominal 20 ms motors, diverged in the sweep's runs that start with a
#: large swing on 33-39 ms motors and a light vehicle; the lower poles slow the late gusts' recovery, which the
#: external force fed forward (:func:`filter_tuning`) restores
#: (docs/compare.md#the-smc-row-robust-to-the-sweeps-motors-and-late-gusts)
GAIN_SCALE = 0.9


def smc_params(vehicle: Vehicle, switching: str = "sign", epsilon: float = 1.0) -> smc.ControllerParams:
    """The ``smc`` row's law: the paper's torque-level law with its actuation lag designed in (the nominal
    motor time constant plus :data:`TELEMETRY_AGE_S`), the switching amplitude :data:`RHO_F`, the poles scaled by
    :data:`GAIN_SCALE`, and on an X frame the roll / pitch pair limited to the motors' shared margin
    (``ControllerParams.shared_roll_pitch``, as ``slung fly`` flies it: the law's model of its delivered torque is
    then what the mixer gives)."""
    return smc.ControllerParams.for_vehicle(
        vehicle,
        gains=smc.Gains.from_poles(rho_F=RHO_F).scaled(GAIN_SCALE),
        switching=switching,
        epsilon=epsilon,
        actuation_lag_s=vehicle.motor_time_constant + TELEMETRY_AGE_S,
        shared_roll_pitch=vehicle.frame == "x",
    )


def filter_tuning(controller: str, estimator: str = "kf") -> object | None:
    """The measured-input filter's tuning a controller's row flies with (None: the defaults, and no filter to tune
    when ``estimator`` is not ``kf``): the sliding-mode rows ``smc`` and ``smc-attitude`` act on the external
    acceleration the filter estimates (``MeasuredTuning.external_feedforward``, ``--external-feedforward`` of
    ``slung fly``), which rejected the late gusts of the sweep
    (docs/compare.md#results-1000-runs-of-the-default-distribution-the-filter-in-the-loop; ``smc-attitude`` 39.8 ->
    73.2 % of its 1000 runs, 6 Dec 2026)."""
    if controller not in ("smc", "smc-attitude") or estimator != "kf":
        return None
    from estimators.filters.measured_model import FEEDFORWARD_TUNING

    return FEEDFORWARD_TUNING


def drag_in_law(tuning: object | None) -> bool:
    """Whether the attitude-level law models the vehicle file's drag (``AttitudeParams.drag_feedforward``) beside a
    filter built with ``tuning`` (None: the defaults, or no filter): not where the filter feeds its external
    acceleration forward, whose estimate carries the drag (both together counted it twice, docs/model.md §12.7).
    The one place fly, replay, compare and sweep (scalar and compiled) decide it."""
    return not bool(getattr(tuning, "external_feedforward", False))


def _smc(vehicle: Vehicle, switching: str = "sign", epsilon: float = 1.0, **_: object) -> Controller:
    from offboard.control.controllers.sliding_mode import SlidingModeController

    return SlidingModeController(smc_params(vehicle, switching, epsilon))


def _smc_attitude(
    vehicle: Vehicle,
    inner: InnerLoop | None = None,
    tilt_max: float | None = None,
    drag_feedforward: bool = True,
    **_: object,
) -> Controller:
    """The attitude-level law with its own default switching (smooth, as ``slung fly --law attitude``), designed for
    ``inner``, the autopilot loops it flies through (None: :class:`InnerLoop`'s generic defaults; ``slung fly``
    designs it for the loops it reads from the autopilot), within ``tilt_max`` (rad; None: the law's default);
    ``drag_feedforward``: the vehicle's drag in the law's model (``AttitudeParams.drag_feedforward``)."""
    from offboard.control import smc_attitude
    from offboard.control.controllers.sliding_mode import AttitudeSlidingModeController

    kw: dict[str, object] = {"drag_feedforward": drag_feedforward}
    if tilt_max is not None:
        kw["tilt_max"] = tilt_max
    params = smc_attitude.AttitudeParams.for_vehicle(
        vehicle, inner=inner, overrides=dict(vehicle.gains), switching="smooth", **kw
    )
    return AttitudeSlidingModeController(params)


def _cascade(vehicle: Vehicle, **_: object) -> Controller:
    from offboard.control.controllers.cascade import CascadeController

    return CascadeController(vehicle)


def _lqr(vehicle: Vehicle, **_: object) -> Controller:
    from offboard.control.controllers.lqr import LqrController

    return LqrController(vehicle)


def _zv(vehicle: Vehicle, **_: object) -> Controller:
    from offboard.control.controllers.shaping import ShapedCascade

    return ShapedCascade(vehicle, "zv")


def _zvd(vehicle: Vehicle, **_: object) -> Controller:
    from offboard.control.controllers.shaping import ShapedCascade

    return ShapedCascade(vehicle, "zvd")


def _swing_feedback(vehicle: Vehicle, **_: object) -> Controller:
    from offboard.control.controllers.swing_feedback import SwingFeedbackCascade

    return SwingFeedbackCascade(vehicle)


#: name -> factory(vehicle, switching=..., epsilon=..., inner=..., tilt_max=..., drag_feedforward=...) (the
#: sliding-mode laws' options, every one passed by keyword: a factory takes ``**_`` for those it ignores)
CONTROLLERS: dict[str, Callable[..., Controller]] = {
    "smc": _smc,
    "smc-attitude": _smc_attitude,
    "cascade": _cascade,
    "lqr": _lqr,
    "zv": _zv,
    "zvd": _zvd,
    "swing-feedback": _swing_feedback,
}


def register(name: str, factory: Callable[..., Controller]) -> None:
    """Add controller ``name`` built by ``factory`` (see :data:`CONTROLLERS`) for this process: the registry line of
    a controller kept outside this package (a plug-in, a test). ValueError for a name already taken or one that is
    not a plain word (it is a command-line value and a column of the sweep's table)."""
    if name in CONTROLLERS:
        raise ValueError(f"controller {name!r} is registered already")
    if not name or not all(c.isalnum() or c in "-_" for c in name):
        raise ValueError(f"controller name {name!r}: letters, digits, '-' and '_' only")
    CONTROLLERS[name] = factory


def make(
    name: str,
    vehicle: Vehicle,
    switching: str = "sign",
    epsilon: float = 1.0,
    inner: InnerLoop | None = None,
    tilt_max: float | None = None,
    drag_feedforward: bool = True,
) -> Controller:
    """A fresh controller ``name`` for the nominal ``vehicle``; UserError for an unknown name. ``inner`` and
    ``tilt_max``: the autopilot loops and tilt limit the attitude-level law (``smc-attitude``) flies behind, and
    ``drag_feedforward`` whether its model has the vehicle's drag (the others ignore them)."""
    factory = CONTROLLERS.get(name)
    if factory is None:
        raise UserError(f"unknown controller {name!r} (known: {', '.join(CONTROLLERS)})")
    return factory(
        vehicle,
        switching=switching,
        epsilon=epsilon,
        inner=inner,
        tilt_max=tilt_max,
        drag_feedforward=drag_feedforward,
    )


def not_designed_for(controller: str, vehicle: Vehicle, inner: InnerLoop | None = None) -> str | None:
    """Why ``controller`` is not designed for ``vehicle`` behind the autopilot loops ``inner`` (None: it is; inner
    None: :class:`InnerLoop`'s generic defaults). The attitude-level law (``smc-attitude``) has gains only where
    they stay stable with those loops 2x off (``smc_attitude.robust_gains_exist``): not for a load that swings
    faster than the loops follow, where ``slung fly --law auto`` flies the torque-level law instead."""
    if controller != "smc-attitude":
        return None
    from offboard.control import smc_attitude

    loops = inner if inner is not None else smc_attitude.InnerLoop()
    if smc_attitude.robust_gains_exist(vehicle, loops):
        return None
    return (
        f"no attitude-level gains stay stable for {vehicle.name} behind this autopilot's attitude loop "
        f"({loops.attitude_bandwidth:g} 1/s, rate loops {loops.rate_bandwidth[0]:.3g} 1/s; its load swings faster "
        "than that loop follows); slung fly --law auto flies the torque-level law (smc) there"
    )


def parse_list(text: str | None) -> list[str]:
    """``"smc,cascade"`` -> ``["smc", "cascade"]`` (None or empty: every controller); UserError for an unknown
    name or a repeated one."""
    if not text:
        return list(CONTROLLERS)
    names = [n.strip() for n in text.split(",") if n.strip()]
    for n in names:
        if n not in CONTROLLERS:
            raise UserError(f"unknown controller {n!r} (known: {', '.join(CONTROLLERS)})")
    if len(set(names)) != len(names):
        raise UserError(f"controller listed twice in {text!r}")
    return names
