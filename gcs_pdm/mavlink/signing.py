"""MAVLink 2 signing that an attacker cannot turn against the link.

pymavlink 2.4.50's ``MAVLink.check_signature`` stores a packet's signing timestamp for its stream
*before* it compares the signature. One packet signed with a wrong key and a timestamp a year ahead
therefore raises the stream's timestamp, and every genuine packet afterwards is refused as an "old
timestamp": the link goes blind for good. :class:`SignatureCheck` replaces that method on the
connection's parser: the signature is verified first, and only a packet that carries the right key
may move anything stored (the stream's timestamp, the timestamp we sign with). The timestamp rules
are the MAVLink 2 signing spec's, as pymavlink applies them: a known stream's timestamp must rise; a
new stream's may be at most one minute behind ours.

Rejections are counted by reason and logged at most once a minute (a flood of forged packets must
not become a flood of log lines; pymavlink logged one INFO line each).
"""
from __future__ import annotations

import hashlib
import logging
import secrets
import struct
import time
from pathlib import Path

log = logging.getLogger(__name__)

#: signing timestamps count 10 µs; a new stream may be this far behind our own (the spec's minute)
NEW_STREAM_SLACK = 6000 * 1000
#: seconds between two log lines about rejected signed packets (the counts are kept in between)
LOG_PERIOD_S = 60.0
_TIMESTAMP = struct.Struct("<IH")
REASONS = ("bad_signature", "old_timestamp", "stale_new_stream")


def signature_matches(key: bytes, msgbuf: bytes | bytearray) -> bool:
    """Whether a signed packet's 6-byte signature is SHA-256(key + packet up to it)[:6]."""
    h = hashlib.sha256()
    h.update(key)
    h.update(bytes(msgbuf[:-6]))
    return secrets.compare_digest(h.digest()[:6], bytes(msgbuf[-6:]))


def packet_timestamp(msgbuf: bytes | bytearray) -> tuple[int, int]:
    """(link id, 48-bit signing timestamp in 10 µs) of a signed packet."""
    low, high = _TIMESTAMP.unpack(bytes(msgbuf[-12:-6]))
    return msgbuf[-13], low + (high << 32)


class RateLimitedLog:
    """A warning that may recur very often: counted every time, logged at most once a period."""

    def __init__(self, logger: logging.Logger, period_s: float = LOG_PERIOD_S, clock=time.monotonic):
        self.logger = logger
        self.period_s = period_s
        self.clock = clock
        self.count = 0
        self._since_log = 0
        self._logged_at: float | None = None
        self.lines = 0  # log lines written, for the tests and /status

    def note(self, message: str, *args) -> None:
        self.count += 1
        self._since_log += 1
        now = self.clock()
        if self._logged_at is None or now - self._logged_at >= self.period_s:
            self.logger.warning(message + " (%d in the last %s, %d in all)", *args, self._since_log,
                                "minute" if self._logged_at is not None else "moment", self.count)
            self._logged_at = now
            self._since_log = 0
            self.lines += 1


class SignatureCheck:
    """``check_signature`` for a pymavlink ``MAVLink`` parser with signing set up: the signature
    first, then the timestamp rules; counts what it refused (``rejected`` by reason)."""

    def __init__(self, mav, clock=time.monotonic):
        self.mav = mav
        self.accepted = 0
        self.rejected = dict.fromkeys(REASONS, 0)
        self._log = RateLimitedLog(log, clock=clock)

    @classmethod
    def install(cls, mav, clock=time.monotonic) -> "SignatureCheck":
        check = cls(mav, clock)
        mav.check_signature = check  # pymavlink calls self.check_signature(msgbuf, sys, comp)
        return check

    def _refuse(self, reason: str, system: int, component: int) -> bool:
        self.rejected[reason] += 1
        self._log.note("signed packet from %d/%d refused: %s", system, component, reason.replace("_", " "))
        return False

    def __call__(self, msgbuf, src_system: int, src_component: int) -> bool:
        signing = self.mav.signing
        if signing.secret_key is None or not signature_matches(signing.secret_key, msgbuf):
            return self._refuse("bad_signature", src_system, src_component)
        link_id, timestamp = packet_timestamp(msgbuf)
        stream = (link_id, src_system, src_component)
        known = signing.stream_timestamps.get(stream)
        if known is not None and timestamp <= known:
            return self._refuse("old_timestamp", src_system, src_component)  # a replayed packet
        if known is None and timestamp + NEW_STREAM_SLACK < signing.timestamp:
            return self._refuse("stale_new_stream", src_system, src_component)
        signing.stream_timestamps[stream] = timestamp
        signing.timestamp = max(signing.timestamp, timestamp)
        self.accepted += 1
        return True

    @property
    def log_lines(self) -> int:
        return self._log.lines

    def to_dict(self) -> dict:
        signing = self.mav.signing
        return {"accepted": self.accepted, "rejected": dict(self.rejected),
                "unsigned_accepted": signing.unsigned_count, "unsigned_refused": signing.reject_count}


# --- setting a key up (gcs-pdm signing init) ------------------------------------------------------

def new_passphrase() -> str:
    """A random passphrase (24 characters, 144 bits). The key is its SHA-256, as MAVProxy's
    ``signing setup``, Mission Planner and QGroundControl derive a key from a passphrase, so the same
    text can be typed into each (``connection.load_signing_key`` reads it back the same way)."""
    while True:  # not led by "-" or "_": MAVProxy's command line would read "-..." as an option
        passphrase = secrets.token_urlsafe(18)
        if passphrase[0].isalnum():
            return passphrase


def passphrase_key(passphrase: str) -> bytes:
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def write_key_file(path: str | Path, passphrase: str, *, overwrite: bool = False) -> Path:
    """The passphrase in a file only its owner can read; FileExistsError unless ``overwrite``."""
    import os

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if overwrite else os.O_EXCL)
    fd = os.open(p, flags, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(passphrase + "\n")
    os.chmod(p, 0o600)
    return p


def setup_instructions(passphrase: str, key_file: Path, target_system: int = 1) -> str:
    """How to give the same key to the vehicle and the ground station (printed by ``signing init``)."""
    hexkey = passphrase_key(passphrase).hex()
    return f"""\
Signing passphrase written to {key_file} (mode 600). The key is SHA-256(passphrase):
  passphrase: {passphrase}
  key (hex):  {hexkey}

1. This service: signing_key_file = "{key_file}" in its settings file (or the environment
   variable GCS_PDM_SIGNING_KEY_FILE={key_file}), then restart. /status then reports
   link_trust.signing.signed = true, and unsigned packets are refused.

2. The vehicle (ArduPilot): the key goes in with a SETUP_SIGNING message (id 256), sent over USB
   or another link you trust, never over the radio. With MAVProxy connected to the vehicle:
     module load signing
     signing setup {passphrase}
   This sends SETUP_SIGNING (target system {target_system}) with the key above and the current time,
   and signs MAVProxy's own link with it. ArduPilot stores the key and from then on refuses unsigned
   packets on its telemetry ports (USB stays open, so a lost key can be reset there).
   From a script: mav.setup_signing_send({target_system}, 1, bytes.fromhex("{hexkey}"), timestamp)
   with timestamp in 10 µs units since 2015-01-01.

3. The ground station and anything else on the link must sign too:
   MAVProxy   signing key {passphrase}
   Mission Planner  Setup > Advanced > MAVLink Signing: add the passphrase, Use
   QGroundControl   Application Settings > MAVLink > MAVLink 2 signing key: the passphrase
   (each derives the key with SHA-256, as above; a tool that asks for raw bytes takes the hex).

Keep the file secret: whoever has it can command the vehicle.
"""
