"""What a flight-log file is, from its first bytes: a tlog (timestamped MAVLink), an ArduPilot
DataFlash log or a PX4 ULog.

Every command that reads a log asks :func:`log_kind` first, so a file that is no log at all (a
README given by mistake) is told as such, in the same words everywhere (docs/cli.md), instead of
failing later on a symptom ("no vehicle HEARTBEAT seen").
"""
from __future__ import annotations

from pathlib import Path

#: ULog's file magic ("ULog", then 0x01 0x12 0x35) and its version byte after it
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: every DataFlash message starts with HEAD1 HEAD2 (0xA3 0x95); the file starts with a message
DATAFLASH_HEAD = b"\xa3\x95"
#: enough of a tlog for a few whole packets, even after a damaged start
SNIFF_BYTES = 65536

KINDS = ("tlog", "dataflash", "ulog")
#: the words every command uses for a file that is none of them
NOT_A_LOG = "not a MAVLink (tlog), DataFlash (.bin) or ULog (.ulg) log"


class NotALog(ValueError):
    """The file is none of the flight logs gcs-pdm reads."""


def log_kind(path: str | Path) -> str:
    """``"tlog"``, ``"dataflash"`` or ``"ulog"``; :class:`NotALog` (with what the file starts with)
    when it is none of them. A tlog counts when its first 64 KiB hold one MAVLink packet whose
    checksum is right (a text file never does by chance); OSError when it cannot be read."""
    path = Path(path)
    with path.open("rb") as f:
        head = f.read(SNIFF_BYTES)
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_HEAD):
        return "dataflash"
    from gcs_pdm.mavlink.tlog import scan_tlog_bytes

    if next(iter(scan_tlog_bytes(head)), None) is not None:
        return "tlog"
    raise NotALog(f"{path}: {NOT_A_LOG} ({_starts_with(head)})")


def _starts_with(head: bytes) -> str:
    if not head:
        return "the file is empty"
    text = head[:24].decode("ascii", errors="replace")
    if all(c.isprintable() or c in "\r\n\t" for c in text):
        return "it starts with text: " + repr(text.splitlines()[0][:24] if text.strip() else text)
    return "it starts with bytes " + head[:8].hex(" ")
