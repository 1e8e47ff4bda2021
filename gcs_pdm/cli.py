"""The `gcs-pdm` command: a thin dispatcher over the subcommands each package registers.

Every package that offers a command has a module with ``register(subparsers)``; it adds its
subparser(s) and sets ``func`` (returning an exit code). Imports are per subcommand so that
``gcs-pdm replay`` does not pay for FastAPI or matplotlib, and ``gcs-pdm --help`` for none of them.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from gcs_pdm import compiled, process_gc, process_threads
from gcs_pdm.command_errors import CommandError, error

#: subcommand -> (module with ``register(subparsers)``, the one line ``gcs-pdm --help`` shows). The
#: lines live here so that ``gcs-pdm --help`` imports no command module (they import numpy, numba,
#: pydantic: a second); a command's own ``--help`` imports only its module.
COMMANDS: dict[str, tuple[str, str]] = {
    "replay": ("gcs_pdm.replay.cli",
               "replay a tlog (or an ArduPilot .bin / PX4 .ulg log) through the telemetry frames and summarise it"),
    "plan": ("gcs_pdm.planning.cli", "plan a route for a scenario file and print it"),
    "experiment": ("gcs_pdm.planning.cli", "rebuild the paper's Table III"),
    "fit": ("gcs_pdm.fitting.cli", "learn battery/motor parameters from flight logs (SA -> LM)"),
    "serve": ("gcs_pdm.service.cli", "run the decision service beside a ground station (MAVLink + HTTP)"),
    "demo": ("gcs_pdm.service.cli", "simulated vehicle + service on loopback: the Table III flight, live"),
    "sim": ("gcs_pdm.sim.cli", "simulated MAVLink vehicle (fixed wing, system 1) on a UDP link"),
    "vehicle": ("gcs_pdm.vehicle_cli", "print, validate and write vehicle descriptions (docs/vehicles.md)"),
    "packs": ("gcs_pdm.packs_cli", "each pack's health across flights: ingest logs (pool or Dask), list, show, assign"),
    "signing": ("gcs_pdm.mavlink.signing_cli", "MAVLink 2 signing: `signing init` writes a key and says how to set it up"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser with ``only``'s module registered (all its commands, options and their checks);
    every other command is a name with its help line, enough to list and to reject."""
    parser = argparse.ArgumentParser(prog="gcs-pdm", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    if only is not None:
        importlib.import_module(COMMANDS[only][0]).register(_WithHelpLines(sub))
    for name, (_, summary) in COMMANDS.items():
        if name not in sub.choices:
            sub.add_parser(name, help=summary)
    return parser


class _WithHelpLines:
    """What a module's ``register`` is handed: ``add_parser`` that gives each command its help line."""

    def __init__(self, subparsers: argparse._SubParsersAction):
        self._subparsers = subparsers

    def add_parser(self, name: str, **kwargs) -> argparse.ArgumentParser:
        return self._subparsers.add_parser(name, help=COMMANDS[name][1], **kwargs)


def main(argv: list[str] | None = None) -> int:
    process_threads.one_blas_thread()  # before a command's module imports numpy
    compiled.hold_compiler_at_exit()  # no numba compilation while the interpreter exits (a crash)
    with process_gc.command():
        return _main(list(sys.argv[1:] if argv is None else argv), from_command_line=argv is None)


def _main(argv: list[str], from_command_line: bool = False) -> int:
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args, extras = parser.parse_known_args(argv)
    names, deepest = _chosen_parser(parser, argv)
    if extras:  # the subcommand's usage, not the top level's (argparse would show gcs-pdm's)
        deepest.error(f"unrecognized arguments: {' '.join(extras)}")
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2) if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    #: the process's own arguments (a command may run itself again, ``compiled.interpret_while_cold``)
    args.process_argv = argv if from_command_line else None
    if not getattr(args, "func", None):
        build_parser().print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except CommandError as exc:
        return error(" ".join(names), str(exc), exc.status)
    except SystemExit as exc:  # a command's SystemExit("message"): the convention's form, exit 2
        if isinstance(exc.code, str):
            return error(" ".join(names), exc.code.removeprefix(f"{names[0]}: "))
        raise


def _chosen_parser(parser: argparse.ArgumentParser, argv: list[str]) -> tuple[list[str], argparse.ArgumentParser]:
    """The subcommand names in ``argv`` (``["vehicle", "init"]``) and the parser of the last one."""
    names: list[str] = []
    for token in (a for a in argv if not a.startswith("-")):
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        if sub is None:
            break
        if token in sub.choices:
            names.append(token)
            parser = sub.choices[token]
    return names or ["?"], parser


if __name__ == "__main__":
    sys.exit(main())
