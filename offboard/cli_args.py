"""Argument types and options shared by the ``slung`` commands.

Kept apart from the command modules so that the flight commands (``fly``, ``demo``, ``replay``) can share them
without importing ``slung sim``'s module, which loads the plant and sensor models (``sim_bridge``).
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from estimators.errors import UserError
from offboard.control.options import Switching, values


def finite_float(text: str) -> float:
    """argparse type: a finite number."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return v


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    v = finite_float(text)
    if v <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    v = finite_float(text)
    if v < 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return v


def non_negative_int(text: str) -> int:
    """argparse type: a whole number >= 0."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return v


def positive_int(text: str) -> int:
    """argparse type: a whole number > 0."""
    v = non_negative_int(text)
    if v == 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def add_controller_arguments(p: argparse.ArgumentParser, flight: bool = False) -> None:
    """Controller options shared by ``sim``, ``fly``, ``demo`` and ``replay``; ``flight``: the defaults of ``fly``
    and ``demo`` (smooth switching, each loop's own boundary layer; resolved per law in
    ``flight_law.resolve_switching``) instead of the paper's."""
    p.add_argument(
        "--switching",
        choices=values(Switching),
        default=None if flight else "sign",
        help="switching function: the paper's sign(.) or v/(|v|+eps) of eq. (92) (default: "
        + ("smooth" if flight else "sign")
        + ")",
    )
    p.add_argument(
        "--epsilon",
        type=positive_float,
        default=None if flight else 1.0,
        metavar="E",
        help=(
            "one smoothing width of eq. (92) for every loop of the torque-level law (default: each loop's own "
            "boundary layer, the sliding variable of a 2 cm / 0.02 rad error; the paper used 1)"
            if flight
            else "smoothing width of eq. (92) for --switching smooth (default: 1, the paper's)"
        ),
    )
    add_vehicle_argument(p)


def add_vehicle_argument(p: argparse.ArgumentParser, default: str = "the paper's Table 1") -> None:
    """``--vehicle FILE|NAME`` of the commands that build a vehicle (``sim``, ``fly``, ``demo``, ``replay``,
    ``compare``); ``default``: what the command uses without it, for the help text."""
    p.add_argument(
        "--vehicle",
        metavar="FILE|NAME",
        help="vehicle description: a TOML file, or a shipped one (paper-table1, px4-sih, px4-hil-load, "
        f"ardupilot-sitl-quad); default: {default}",
    )


#: the controller names that mean the command's own sliding-mode law, configured by its own options (``--law``,
#: ``--switching``, ...): ``smc`` (the torque level; ``slung fly``: the level ``--law`` picks) and, for the flight
#: commands and replay, ``smc-attitude`` (``--law attitude``)
OWN_LAWS = ("smc", "smc-attitude")


def add_controller_choice(p: argparse.ArgumentParser, default: str) -> None:
    """``--controller NAME`` of ``sim``, ``fly``, ``demo`` and ``replay``: a controller of
    ``offboard.control.controllers.registry`` (checked when the command runs: :func:`chosen_controller`);
    ``default``: what the command flies without it, for the help text."""
    p.add_argument(
        "--controller",
        metavar="NAME",
        default=None,
        help="controller by name, as slung compare / sweep take them (smc, smc-attitude, cascade, lqr, zv, zvd, "
        f"swing-feedback, or one registered; docs/architecture.md); default: {default}",
    )


def chosen_controller(args: argparse.Namespace) -> str | None:
    """The ``--controller`` name (None: not given); UserError for a name the registry does not know."""
    name = getattr(args, "controller", None)
    if name is None:
        return None
    from offboard.control.controllers import registry

    if name not in registry.CONTROLLERS:
        raise UserError(f"unknown controller {name!r} (known: {', '.join(registry.CONTROLLERS)})")
    return str(name)


def add_feedforward_argument(p: argparse.ArgumentParser) -> None:
    """``--external-feedforward`` of the commands that build the measured-input filter (``sim``, ``fly``, ``demo``)."""
    p.add_argument(
        "--external-feedforward",
        action="store_true",
        help="with the kf filter: the external acceleration on the vehicle it estimates (a gust, a push; beyond 3 "
        "of its standard deviations) is fed forward into the law's F^(4), as the smc and smc-attitude rows of slung "
        "compare / sweep fly (default: off, the chain of the pendulum model alone)",
    )


def feedforward_tuning(args: argparse.Namespace, estimator: str = "kf") -> Any:
    """The measured-input filter's tuning for ``--external-feedforward`` (None: the defaults, or the option not
    given); the option with another estimator than ``kf`` is a :class:`UserError` (only that filter estimates the
    external acceleration)."""
    if not getattr(args, "external_feedforward", False):
        return None
    if estimator != "kf":
        raise UserError(f"--external-feedforward needs the kf filter (--estimator kf), not {estimator!r}")
    from estimators.filters.measured_model import FEEDFORWARD_TUNING

    return FEEDFORWARD_TUNING


def add_no_figures_argument(p: argparse.ArgumentParser) -> None:
    """``--no-figures`` of the commands that write a run's report folder (``sim``, ``fly``, ``demo``, ``replay``)."""
    p.add_argument(
        "--no-figures", action="store_true", help="write metrics and time series only (no PNG figures, no report.html)"
    )


def add_seed_argument(p: argparse.ArgumentParser) -> None:
    """``--seed`` of the commands that simulate sensors and disturbances (``sim``, ``demo``)."""
    p.add_argument(
        "--seed",
        type=non_negative_int,
        default=0,
        metavar="N",
        help="seed of the sensor noise and the disturbances (default 0; the same runs in slung sim and slung demo)",
    )
