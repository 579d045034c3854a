"""``slung``: the command-line front end. Parses, dispatches, prints errors; holds no logic of its own.

Each subcommand lives in its own module exposing ``configure(parser)`` and ``run(args) -> int``; this file
only maps names to modules, so commands can be added without touching each other. A :class:`UserError`
(bad input) becomes one line on stderr and exit code 2; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from estimators.errors import UserError

#: subcommand -> (module, one-line help). Only the chosen command's module is imported (``slung --help`` imports
#: none), which keeps start-up fast and the flight commands free of the emulator's package.
COMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("offboard.harness.sim_cli", "simulate a scenario in one process (plant + estimator + controller)"),
    "bench": ("offboard.harness.bench_cli", "measure the speed of the plant, controller and estimator"),
    "emulate": ("sim_bridge.emulator_cli", "run the MAVLink autopilot emulator (PX4 or ArduPilot flavour)"),
    "fly": ("offboard.flight.fly_cli", "fly a real or emulated vehicle over MAVLink"),
    "px4-hil": ("sim_bridge.sitl.px4_hil_cli", "be real PX4 SITL's simulator: a vehicle with a slung load"),
    "demo": ("offboard.harness.demo_cli", "start the emulator and fly the paper scenario end to end"),
    "replay": (
        "offboard.logs.replay_cli",
        "replay a flight log (.tlog, .ulg, .bin) through the estimator and controller",
    ),
    "compare": ("offboard.harness.compare_cli", "fly every controller on the same runs and compare them side by side"),
    "sweep": (
        "offboard.harness.sweep_cli",
        "Monte Carlo robustness of the controllers over parameter distributions (Dask)",
    ),
    "export": ("offboard.logs.export_cli", "write a run folder's time series as CSV"),
}

#: subcommand -> the example line its ``--help`` ends with (run as written from a source tree)
EXAMPLES: dict[str, str] = {
    "sim": "slung sim --scenario paper --out runs/paper",
    "bench": "slung bench --repeat 2000 --runs 1",
    "emulate": "slung emulate --flavor px4 --lockstep",
    "fly": "slung fly --connect udpin:0.0.0.0:14540 --scenario hover --duration 20 --out runs/hover",
    "px4-hil": "slung px4-hil --px4 --load-sensor 100",
    "demo": "slung demo --seed 3 --out runs/demo",
    "replay": "slung replay runs/demo/flight.tlog",
    "compare": "slung compare --scenario rest-to-rest --out runs/compare",
    "sweep": "slung sweep --runs 100 --workers 2 --out runs/sweep",
    "export": "slung export --csv runs/demo",
}


#: what ``slung --help`` tells a user (this module's docstring is for developers)
USER_DESCRIPTION = """\
slung flies a quadrotor that carries a load on a cable along a trajectory and damps the load's swing
(flatness-based sliding-mode control, PX4 or ArduPilot over MAVLink). It can also simulate a flight,
run a bundled autopilot emulator, and replay a flight log through the same estimator and controller."""

USER_EPILOG = """\
first steps:
  slung demo                      fly the paper's scenario against the bundled emulator (about half a minute);
                                  open report.html in the folder it prints
  slung sim --scenario paper      the same scenario simulated in one process
  slung COMMAND --help            the options of one command

docs: README.md and docs/usage.md in the source tree"""


def version() -> str:
    """The installed package's version (``slung --version``)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _version

    try:
        return _version("slung")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown (not installed)"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2 (argparse's own code, without the usage dump)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser. Every command is listed; only ``command``'s module is imported and configures its options
    (none when ``command`` is None: ``slung --help``), so that ``slung fly`` loads nothing of the emulator's
    package. A chosen command whose module is not installed is left out (argparse then names the choices)."""
    parser = _Parser(
        prog="slung",
        description=USER_DESCRIPTION,
        epilog=USER_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"slung {version()}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name, (module_name, help_text) in COMMANDS.items():
        if name != command:
            sub.add_parser(name, help=help_text, description=help_text)  # listed, not configured
            continue
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:
                continue
            raise
        p = sub.add_parser(
            name,
            help=help_text,
            description=help_text,
            epilog=f"example:\n  {EXAMPLES[name]}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.configure(p)
        p.set_defaults(_run=module.run)
    return parser


def _chosen_command(argv: Sequence[str]) -> str | None:
    """The subcommand named in ``argv`` (the first argument that is not an option), if it is a known one."""
    for arg in argv:
        if not arg.startswith("-"):
            return arg if arg in COMMANDS else None
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``slung`` console script; returns the process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command = _chosen_command(argv)
    parser = build_parser(command)
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args._run(args) or 0)
    except UserError as exc:
        print(f"slung {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"slung {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
