"""The one convention every ``gcs-pdm`` command follows (docs/cli.md has the table):

- an error is one line on stderr, ``gcs-pdm <command>: error: <what>`` (argparse's own usage
  errors have the same form, after that command's usage);
- exit 2: a usage or input error (a wrong flag, a missing or unreadable file, a file that is no
  log, an invalid description); exit 1: the command ran but found nothing to diagnose or do, or
  what it ran ended badly (no feasible plan, the demo's vehicle did not land); exit 0: success.

A command module returns :func:`error`'s value, or raises :class:`CommandError` from deep inside;
``gcs_pdm.cli`` prints the latter (and a ``SystemExit`` carrying a message) in the same form.
Lives apart from ``gcs_pdm.cli``, which runs as ``__main__`` under ``python -m gcs_pdm.cli``.
"""
from __future__ import annotations

import sys

#: exit statuses (docs/cli.md)
EXIT_OK = 0
EXIT_NOTHING = 1
EXIT_USAGE = 2


class CommandError(Exception):
    """A command's error, told as ``gcs-pdm <command>: error: <message>``; exit ``status``."""

    def __init__(self, message: str, status: int = EXIT_USAGE):
        super().__init__(message)
        self.status = status


def error(command: str, message: str, status: int = EXIT_USAGE) -> int:
    """Print ``gcs-pdm <command>: error: <message>`` on stderr and return ``status`` (exit 2 by default)."""
    print(f"gcs-pdm {command}: error: {message}", file=sys.stderr)
    return status


def warning(command: str, message: str) -> None:
    """``gcs-pdm <command>: warning: <message>`` on stderr (the command goes on)."""
    print(f"gcs-pdm {command}: warning: {message}", file=sys.stderr)
