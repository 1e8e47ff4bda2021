"""The `gcs-pdm` command: a thin dispatcher over the subcommands each package registers.

Every package that offers a command has a module with ``register(subparsers)``; it adds its
subparser(s) and sets ``func`` (returning an exit code). Imports are per subcommand so that
``gcs-pdm replay`` does not pay for FastAPI or matplotlib.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from gcs_pdm.start_up import starting

# subcommand name -> module with register(subparsers)
COMMAND_MODULES: dict[str, str] = {
    "replay": "gcs_pdm.mavlink.cli",
    "plan": "gcs_pdm.planning.cli",
    "experiment": "gcs_pdm.planning.cli",
    "fit": "gcs_pdm.fitting.cli",
    "serve": "gcs_pdm.service.cli",
    "demo": "gcs_pdm.service.cli",
    "sim": "gcs_pdm.sim.cli",
    "vehicle": "gcs_pdm.vehicle.cli",
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gcs-pdm", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    registered: set[str] = set()
    for name, module_name in COMMAND_MODULES.items():
        if only is not None and name != only:
            continue
        if module_name in registered:
            continue
        importlib.import_module(module_name).register(sub)
        registered.add(module_name)
    return parser


def main(argv: list[str] | None = None) -> int:
    with starting():
        return _main(list(sys.argv[1:] if argv is None else argv))


def _main(argv: list[str]) -> int:
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(command if command in COMMAND_MODULES else None)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2) if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        build_parser().print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
