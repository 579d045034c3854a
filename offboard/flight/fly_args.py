"""The command-line options of ``slung fly`` (also ``slung demo``'s): reference, flight, output and link options,
MAVLink signing; units in the help texts (s, Hz, rad, m)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from offboard.cli_args import (
    add_controller_arguments,
    add_controller_choice,
    add_feedforward_argument,
    add_no_figures_argument,
    non_negative_float,
    positive_float,
)
from offboard.control.options import EndAction, Law, Output, values
from offboard.flight.latency import DEFAULT_LIMIT_S as DEFAULT_LATENCY_LIMIT_S
from offboard.flight.link.setpoints import MASKS
from offboard.flight.loop import (
    DEFAULT_RATE_HZ,
    RATE_MAX_HZ,
    RATE_MIN_HZ,
)
from offboard.flight.staleness import STALE_CEILING_S, STALE_FLOOR_S


def add_signing_arguments(p: argparse.ArgumentParser) -> None:
    """--signing-key / --signing-link-id / --signing-state (docs/deploy.md, "MAVLink signing")."""
    p.add_argument(
        "--signing-key",
        metavar="HEX|@FILE",
        help="sign every packet with this MAVLink 2 key and accept only signed packets: 64 hex digits, or @FILE "
        "holding them (or the 32 raw bytes); prefer @FILE, a command line is visible to other users",
    )
    p.add_argument("--signing-link-id", type=int, default=1, metavar="N", help="our signing link id, 0..255 (1)")
    p.add_argument(
        "--signing-state",
        metavar="FILE",
        help="where the last signing timestamp is kept between sessions (default "
        "$XDG_STATE_HOME/slung/signing-<key id>.json, i.e. ~/.local/state/slung/...)",
    )


def signing_config(args: argparse.Namespace) -> Any:
    """The link's :class:`~offboard.flight.link.connection.SigningConfig` from the options, None without a key."""
    import hashlib
    import os

    from estimators.mavlink_signing import parse_key
    from offboard.flight.link.connection import SigningConfig

    text = getattr(args, "signing_key", None)
    if not text:
        return None
    key = parse_key(text)
    state = getattr(args, "signing_state", None)
    if state:
        path = Path(state)
    else:
        base = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state") / "slung"
        path = base / f"signing-{hashlib.sha256(key).hexdigest()[:12]}.json"
        try:
            base.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"cannot create {base} for the signing timestamp: {exc.strerror or exc}") from None
    return SigningConfig(key, int(args.signing_link_id), path)


def add_reference_arguments(p: argparse.ArgumentParser) -> None:
    """--scenario / --trajectory / --move (--arrive-by, --max-accel, --max-speed) / --duration."""
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--scenario", metavar="NAME", help="named scenario (paper, rest-to-rest, hover, circle)")
    g.add_argument("--trajectory", metavar="FILE", help="trajectory file (TOML, docs/references.md)")
    g.add_argument(
        "--move",
        metavar="X,Y,Z",
        help="go to the goal X,Y (m, north and west of where control starts) at height Z (m above take-off), the load "
        "at rest at both ends: by --arrive-by, or within --max-accel / --max-speed, else as fast as the vehicle "
        "allows; e.g. --move 3,0,2 --arrive-by 4 (docs/references.md, Moves)",
    )
    p.add_argument("--arrive-by", type=positive_float, metavar="S", help="with --move: the move's time, s")
    p.add_argument("--max-accel", type=positive_float, metavar="M/S2", help="with --move: peak acceleration, m/s^2")
    p.add_argument("--max-speed", type=positive_float, metavar="M/S", help="with --move: peak speed, m/s")
    p.add_argument("--duration", type=positive_float, metavar="S", help="flight time under offboard control, s")


def add_flight_arguments(p: argparse.ArgumentParser, demo: bool = False) -> None:
    """Options shared by ``fly`` and ``demo``."""
    # --switching / --epsilon resolved per law in fly() (flight_law.resolve_switching): smooth switching for both laws,
    # each loop's boundary layer from its gains unless --epsilon gives the paper's one width for all (torque law)
    add_controller_arguments(p, flight=True)
    add_controller_choice(p, "the sliding-mode law at the level --law picks (smc-attitude: --law attitude)")
    add_feedforward_argument(p)
    p.add_argument(
        "--law",
        choices=("auto", *values(Law)),
        default="auto",
        help="controller: attitude = the sliding-mode law on attitude and thrust, for an autopilot that runs its own "
        "attitude loops (smooth switching by default, each loop's boundary layer from its gains, --epsilon unused); "
        "torque = the paper's torque-level law (needed for --output actuator; smooth switching by default, each "
        "loop's boundary layer the sliding variable of a 2 cm / 0.02 rad error, or --epsilon for all); auto "
        "(default): attitude with --output attitude when robust gains exist for the vehicle behind PX4's default "
        "attitude loop, else torque (a load swinging faster than that loop, e.g. the paper's vehicle)",
    )
    p.add_argument(
        "--output",
        choices=values(Output),
        default="attitude",
        help="attitude: SET_ATTITUDE_TARGET (PX4 and ArduPilot); actuator: SET_ACTUATOR_CONTROL_TARGET "
        "(PX4 <= v1.13, the emulator)",
    )
    p.add_argument(
        "--mask",
        choices=tuple(MASKS),
        default=None,
        help="SET_ATTITUDE_TARGET fields: attitude (type_mask 7), attitude+rates (0), rates (128); default: "
        "attitude on PX4, attitude+rates on ArduPilot (it reads the body rates as feed-forward, and with the "
        "attitude alone its input shaping let the demo's roll and heading run away)",
    )
    p.add_argument(
        "--rate",
        type=positive_float,
        default=DEFAULT_RATE_HZ,
        metavar="HZ",
        help=f"loop rate, {RATE_MIN_HZ:g}..{RATE_MAX_HZ:g} Hz (default {DEFAULT_RATE_HZ:g})",
    )
    if not demo:
        p.add_argument(
            "--backend",
            choices=("pymavlink", "mavsdk"),
            default="pymavlink",
            help="MAVLink library for management (default pymavlink)",
        )
        p.add_argument(
            "--lockstep",
            action="store_true",
            help="the bundled emulator's lockstep handshake (slung emulate --lockstep)",
        )
        p.add_argument("--no-takeoff", action="store_true", help="the vehicle is already flying at the start")
    p.add_argument(
        "--identify-load",
        type=positive_float,
        nargs="?",
        const=10.0,
        default=None,
        metavar="S",
        help="identify the load's mass and cable length in an identification hover of S s (default 10, at most "
        "10) at the reference's start, before control; the vehicle file's load is the prior, the identified one "
        "flies when confident",
    )
    p.add_argument(
        "--no-hover-learning",
        action="store_true",
        help="map thrust with the autopilot's (or the vehicle file's) hover throttle, not the one learned in flight "
        "from the vertical acceleration (default: learned, once trusted)",
    )
    p.add_argument(
        "--stale-limit",
        type=positive_float,
        default=None,
        metavar="S",
        help="a fixed telemetry staleness limit, s (default: derived from the link's gaps in the hold before "
        "control, within --stale-floor..--stale-ceiling)",
    )
    p.add_argument(
        "--stale-floor",
        type=positive_float,
        default=STALE_FLOOR_S,
        metavar="S",
        help=f"the derived staleness limit's floor, s (default {STALE_FLOOR_S:g})",
    )
    p.add_argument(
        "--stale-ceiling",
        type=positive_float,
        default=STALE_CEILING_S,
        metavar="S",
        help=f"the derived staleness limit's ceiling, s (default {STALE_CEILING_S:g}; PX4's own offboard-loss "
        "timeout is 1 s)",
    )
    p.add_argument(
        "--swing-limit",
        type=positive_float,
        default=0.8,
        metavar="RAD",
        help="abort to hold above this estimated swing angle, rad (default 0.8)",
    )
    p.add_argument(
        "--settle",
        type=non_negative_float,
        default=5.0,
        metavar="S",
        help="after the reference ends, keep flying it for up to S s while the load still swings (default 5; 0: "
        "hand over at once)",
    )
    p.add_argument(
        "--settle-swing",
        type=positive_float,
        default=0.05,
        metavar="RAD",
        help="the estimated swing amplitude below which the flight ends, rad (default 0.05)",
    )
    p.add_argument(
        "--divergence-limit",
        type=positive_float,
        default=1.0,
        metavar="M",
        help="estimator divergence watchdog: estimate vs autopilot position, m (default 1)",
    )
    p.add_argument(
        "--telemetry-timeout",
        type=positive_float,
        default=10.0,
        metavar="S",
        help="how long the pre-flight waits for attitude and position telemetry, s (default 10)",
    )
    p.add_argument(
        "--start-timeout",
        type=positive_float,
        default=10.0,
        metavar="S",
        help="longest hold at the reference's start before control starts anyway, s (default 10)",
    )
    p.add_argument(
        "--tracking-limit",
        type=positive_float,
        default=None,
        metavar="M",
        help="supervision: end the flight (hold) when the load's estimated position error exceeds M m (default 2 m "
        "plus what a swing at --swing-limit moves the load: 2 + l sin(swing limit))",
    )
    p.add_argument(
        "--latency-limit",
        type=positive_float,
        default=DEFAULT_LATENCY_LIMIT_S,
        metavar="S",
        help="latency watchdog: one-way link delay that, held for 1 s, ends the flight in hold, s "
        f"(default {DEFAULT_LATENCY_LIMIT_S:g})",
    )
    p.add_argument("--end", choices=values(EndAction), default="hold", help="what to do at the end (default hold)")
    p.add_argument(
        "--on-signal", choices=values(EndAction), default="hold", help="what Ctrl-C / SIGTERM does (default hold)"
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="N",
        help="run the loop with SCHED_FIFO real-time priority N (1..99; needs the right to; default off)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="fly a reference the pre-flight feasibility check finds beyond the vehicle's limits",
    )
    add_no_figures_argument(p)
