"""``gcs-pdm signing init``: a MAVLink 2 signing key for the service, and how to give the same key to
the vehicle and the ground station (gcs_pdm.mavlink.signing)."""
from __future__ import annotations

import argparse
from pathlib import Path

from gcs_pdm.command_errors import error

DEFAULT_KEY_FILE = "gcs-pdm-data/signing.key"


def register(subparsers) -> None:
    p = subparsers.add_parser("signing")
    sub = p.add_subparsers(dest="signing_command", metavar="ACTION", required=True)
    init = sub.add_parser("init", help="write a new signing passphrase (mode 600) and print how to set it up")
    init.add_argument("--key-file", type=Path, default=Path(DEFAULT_KEY_FILE),
                      help=f"where to write it (default {DEFAULT_KEY_FILE}; the service reads it as signing_key_file)")
    init.add_argument("--force", action="store_true", help="replace an existing key file (the old key stops working)")
    init.add_argument("--target-system", type=int, default=1, help="the vehicle's system id, for the instructions")
    init.set_defaults(func=_init)


def _init(args: argparse.Namespace) -> int:
    from gcs_pdm.mavlink.signing import new_passphrase, setup_instructions, write_key_file

    passphrase = new_passphrase()
    try:
        path = write_key_file(args.key_file, passphrase, overwrite=args.force)
    except FileExistsError:
        return error("signing init", f"{args.key_file} exists (the key in use?); --force replaces it")
    except OSError as exc:
        return error("signing init", f"{args.key_file}: {exc.strerror or exc}")
    print(setup_instructions(passphrase, path.resolve(), args.target_system))
    return 0
