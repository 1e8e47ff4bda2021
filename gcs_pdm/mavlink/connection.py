"""The MAVLink link: one pymavlink connection, one reader thread, many consumers.

A :class:`Link` owns a ``mavutil.mavlink_connection`` (``udpin:``, ``udpout:``, ``tcp:``, serial)
with MAVLink 2 and the ``ardupilotmega`` dialect pinned (``gcs_pdm.mavlink.dialect``). A single
reader thread receives every packet, records it to the tlog, turns the vehicle's packets into
frames through a :class:`~gcs_pdm.mavlink.mapping.FrameMapper`, and copies messages into the
queues of whoever subscribed (the mission client, the service). Nothing else reads the socket, so
the telemetry consumer and the mission client never steal each other's messages.
"""
from __future__ import annotations

import errno
import hashlib
import logging
import os
import queue
import re
import socket
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from gcs_pdm.mavlink.heartbeat_watch import HeartbeatWatch
from gcs_pdm.mavlink.dialect import DIALECT, MESSAGE_IDS_BY_NAME, mavlink2, mavutil
from gcs_pdm.mavlink.mapping import FrameMapper, ForeignSystem
from gcs_pdm.mavlink.sequence import SequenceMonitor
from gcs_pdm.mavlink.signing import SignatureCheck
from gcs_pdm.mavlink.tlog import TlogWriter
from gcs_pdm.mavlink.wire import split_packet

log = logging.getLogger(__name__)

# The service is one more system on the vehicle's link, NOT the ground station: system 255 is the
# GCS's id (ArduPilot's MAV_GCS_SYSID, formerly SYSID_MYGCS) and a heartbeat from it counts as "GCS
# alive", so sending as 255 would hide a real loss of the ground station from the GCS failsafe.
# 245 is ours: high, like ground-side tools, clear of vehicles (1..) and of 255/254 used by
# ground stations (docs/operations.md, "Safety"). Component 195 is MAV_COMP_ID_PATHPLANNER
# ("supplies a mission flight plan"), which neither QGroundControl nor Mission Planner (190) use.
DEFAULT_SOURCE_SYSTEM = 245
DEFAULT_SOURCE_COMPONENT = mavlink2.MAV_COMP_ID_PATHPLANNER
DEFAULT_RCVBUF_BYTES = 4 * 1024 * 1024
HEARTBEAT_ID = MESSAGE_IDS_BY_NAME["HEARTBEAT"]
# ArduPilot's and PX4's default system id: the vehicle we track unless told otherwise.
DEFAULT_TARGET_SYSTEM = 1
# Loopback and a port of its own: a router or the ground station forwards the vehicle to it
# (14550 is QGroundControl's; 0.0.0.0 would take packets from anyone on the network).
DEFAULT_URL = "udpin:127.0.0.1:14551"


class LinkError(RuntimeError):
    """A link that cannot be opened; the message says why in one line."""


_NET_URL = re.compile(r"^(udpin|udpout|udp|tcp|tcpin):([^:]+):(\d{1,5})$")


def check_link_url(url: str) -> tuple[str, str, int] | tuple[str, str]:
    """``(scheme, host, port)`` for a network link or ``("serial", device)``; LinkError if unusable.

    pymavlink guesses a lot from a bare string (a regular file is read as a log, a path under
    /bin/ is executed), so only these forms get to it: udpin:/udpout:/udp:/tcp:/tcpin:HOST:PORT
    and an existing character device (a serial port).
    """
    m = _NET_URL.match(url)
    if m:
        port = int(m.group(3))
        if not 0 < port < 65536:
            raise LinkError(f"MAVLink URL {url!r}: port {port} is out of range 1..65535")
        return m.group(1), m.group(2), port
    if ":" in url and not url.startswith("/"):
        raise LinkError(f"MAVLink URL {url!r} not understood: use udpin:HOST:PORT, udpout:HOST:PORT, "
                        "tcp:HOST:PORT, tcpin:HOST:PORT or a serial device such as /dev/ttyUSB0")
    try:
        mode = os.stat(url).st_mode
    except FileNotFoundError:
        raise LinkError(f"serial device {url} does not exist") from None
    except OSError as exc:
        raise LinkError(f"serial device {url}: {exc.strerror}") from None
    if not stat.S_ISCHR(mode):
        raise LinkError(f"{url} is not a serial device (for a recorded log use `gcs-pdm replay`)")
    return "serial", url


def _check_udp_port_free(host: str, port: int) -> None:
    """Two listeners on one UDP port would each get some of the vehicle's packets, silently
    (pymavlink binds with SO_REUSEADDR, which Linux lets two sockets share): refuse instead."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind((host, port))  # no SO_REUSEADDR: fails if anyone holds the port
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise LinkError(f"MAVLink port udpin:{host}:{port} is already in use (another gcs-pdm, a router or "
                            "a ground station?)") from None
        raise LinkError(f"cannot listen on udpin:{host}:{port}: {exc.strerror or exc}") from None
    finally:
        probe.close()


@dataclass
class LinkConfig:
    """Everything needed to open a link; all of it can come from the service's config file."""

    url: str = DEFAULT_URL  # udpin:127.0.0.1:14551, udpout:host:14550, tcp:host:5760, /dev/ttyUSB0
    baud: int = 57600
    source_system: int = DEFAULT_SOURCE_SYSTEM
    source_component: int = DEFAULT_SOURCE_COMPONENT
    target_system: int | None = DEFAULT_TARGET_SYSTEM  # None ("auto"): the first autopilot heartbeat
    target_component: int | None = None
    signing_key_file: str | None = None  # 32 raw bytes, 64 hex digits, or a passphrase (SHA-256)
    allow_unsigned: bool = False  # with signing: accept unsigned packets too
    rcvbuf_bytes: int = DEFAULT_RCVBUF_BYTES
    tlog_path: str | None = None
    # A GCS-type heartbeat makes the service visible to routers and vehicles. Caveat: ArduPilot
    # counts any heartbeat from system SYSID_MYGCS as "GCS alive" (docs/mavlink.md).
    heartbeat_hz: float = 1.0


def load_signing_key(path: str | Path) -> bytes:
    """A MAVLink 2 signing key from a file: 32 raw bytes, 64 hex digits, or a passphrase."""
    raw = Path(path).read_bytes()
    if len(raw) == 32:
        return raw
    text = raw.decode("utf-8", "replace").strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text)
        except ValueError:
            pass
    if not text:
        raise ValueError(f"signing key file {path} is empty")
    # Same derivation as MAVProxy's "signing setup <passphrase>".
    return hashlib.sha256(text.encode("utf-8")).digest()


class MessageSubscription:
    """A queue of received messages of some types, filled by the link's reader thread."""

    def __init__(self, link: "Link", types: frozenset[str] | None, maxsize: int):
        self._link = link
        self.types = types
        self.queue: queue.Queue = queue.Queue(maxsize)
        self.dropped = 0

    def _offer(self, msg) -> None:
        try:
            self.queue.put_nowait(msg)
        except queue.Full:
            self.dropped += 1
            if self.dropped in (1, 10, 100) or self.dropped % 1000 == 0:
                log.warning("subscription %s full: %d messages dropped", sorted(self.types or ["*"]), self.dropped)

    def get(self, timeout: float | None = None):
        """Next message, or None after ``timeout`` seconds."""
        try:
            return self.queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def drain(self) -> int:
        n = 0
        while True:
            try:
                self.queue.get_nowait()
                n += 1
            except queue.Empty:
                return n

    def close(self) -> None:
        self._link.unsubscribe(self)

    def __enter__(self) -> "MessageSubscription":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Link:
    """One MAVLink connection shared by telemetry and the mission client."""

    def __init__(self, config: LinkConfig, mapper: FrameMapper | None = None):
        self.config = config
        self.mapper = mapper or FrameMapper(target_system=config.target_system,
                                            target_component=config.target_component)
        self.conn = None
        self.tlog: TlogWriter | None = None
        self._send_lock = threading.Lock()
        self._subs_lock = threading.Lock()
        self._subscriptions: list[MessageSubscription] = []
        self._frame_listeners: list[Callable] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.received = 0
        self.bad_data = 0
        self.sequence = SequenceMonitor()  # whether one sender is behind each id (sequence numbers)
        self.sent = 0
        self.rcvbuf_effective: int | None = None
        self.signature_check: SignatureCheck | None = None  # with a signing key (open)
        self.handle_failures = 0  # packets whose handling raised (a consumer's bug), counted
        self._failure_logged_at: float | None = None
        # monotonic time of the tracked vehicle's last HEARTBEAT (for "link lost" decisions)
        self._vehicle_heartbeat_at: float | None = None
        # ... and of its last packet whose timestamp the vehicle clock accepted (its timed stream)
        self._vehicle_timed_at: float | None = None
        self.heartbeats = HeartbeatWatch()

    # --- lifecycle ---------------------------------------------------------------------------

    def open(self) -> "Link":
        """Open the connection; LinkError (one line) for a bad URL, a taken port, a missing device or key."""
        cfg = self.config
        where = check_link_url(cfg.url)
        key = None
        if cfg.signing_key_file:
            try:
                key = load_signing_key(cfg.signing_key_file)
            except OSError as exc:
                raise LinkError(f"signing key file {cfg.signing_key_file}: {exc.strerror or exc}") from None
            except ValueError as exc:
                raise LinkError(str(exc)) from None
        if where[0] in ("udpin", "udp"):
            _check_udp_port_free(where[1], where[2])
        try:
            self.conn = mavutil.mavlink_connection(
                cfg.url, baud=cfg.baud, source_system=cfg.source_system, source_component=cfg.source_component,
                dialect=DIALECT, autoreconnect=cfg.url.startswith("tcp"))
        except (OSError, ValueError) as exc:
            raise LinkError(f"cannot open MAVLink link {cfg.url}: {getattr(exc, 'strerror', None) or exc}") from None
        if getattr(self.conn, "WIRE_PROTOCOL_VERSION", "2.0") != "2.0":
            raise RuntimeError("pymavlink did not select MAVLink 2 (MAVLINK20 must be set before import)")
        self.conn.mav.srcSystem = cfg.source_system
        self.conn.mav.srcComponent = cfg.source_component
        if where[0] in ("udpin", "udp"):
            # pymavlink bound with SO_REUSEADDR; clearing it makes a second listener's bind fail
            # (Linux checks the flag of the socket already bound) rather than share our packets.
            self.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 0)
        self._enlarge_receive_buffer()
        if key is not None:
            allow = (lambda _mav, _msgid: True) if cfg.allow_unsigned else None
            self.conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=allow,
                                    initial_timestamp=None, link_id=0)
            # the signature before anything is stored from a packet (pymavlink stores the timestamp first)
            self.signature_check = SignatureCheck.install(self.conn.mav)
        if cfg.tlog_path:
            self.tlog = TlogWriter(cfg.tlog_path)
        self.conn.mav.set_send_callback(self._on_sent)
        return self

    def _enlarge_receive_buffer(self) -> None:
        sock = getattr(self.conn, "port", None)
        if not isinstance(sock, socket.socket):
            return  # serial: the driver's buffer is what it is
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.config.rcvbuf_bytes)
            self.rcvbuf_effective = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        except OSError as exc:
            log.warning("could not enlarge SO_RCVBUF: %s", exc)
            return
        # Linux reports twice the granted size and caps it at net.core.rmem_max; a privileged
        # process may go past the cap with SO_RCVBUFFORCE.
        force = getattr(socket, "SO_RCVBUFFORCE", None)
        if self.rcvbuf_effective < self.config.rcvbuf_bytes and force is not None:
            try:
                sock.setsockopt(socket.SOL_SOCKET, force, self.config.rcvbuf_bytes)
                self.rcvbuf_effective = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
            except OSError:
                pass
        if self.rcvbuf_effective < self.config.rcvbuf_bytes:
            log.warning("SO_RCVBUF is %d bytes, asked for %d (raise net.core.rmem_max): fast bursts may drop",
                        self.rcvbuf_effective, self.config.rcvbuf_bytes)

    def start(self) -> "Link":
        """Open if needed and start the reader thread (idempotent)."""
        if self.conn is None:
            self.open()
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="mavlink-reader", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self.conn is not None:
            try:
                self.conn.close()
            except OSError:
                pass
        if self.tlog is not None:
            self.tlog.close()

    def __enter__(self) -> "Link":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # --- consumers ---------------------------------------------------------------------------

    def subscribe(self, types: Iterable[str] | None = None, maxsize: int = 10000) -> MessageSubscription:
        """A queue receiving every later message of ``types`` (all types if None)."""
        sub = MessageSubscription(self, frozenset(types) if types is not None else None, maxsize)
        with self._subs_lock:
            self._subscriptions = self._subscriptions + [sub]
        return sub

    def unsubscribe(self, sub: MessageSubscription) -> None:
        with self._subs_lock:
            self._subscriptions = [s for s in self._subscriptions if s is not sub]

    def add_frame_listener(self, callback: Callable) -> None:
        """``callback(frame)`` for every frame, called on the reader thread: keep it quick."""
        self._frame_listeners = self._frame_listeners + [callback]

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def target_system(self) -> int | None:
        return self.mapper.target_system

    @property
    def target_component(self) -> int | None:
        return self.mapper.target_component

    @property
    def foreign_systems(self) -> list[ForeignSystem]:
        """Other systems that sent vehicle heartbeats on this link (never tracked)."""
        return list(self.mapper.foreign_systems.values())

    def vehicle_silent_s(self, now: float | None = None) -> float | None:
        """Wall seconds since the tracked vehicle was last heard; None if it was never heard.
        (Wall time on purpose: a silent vehicle sends no message time to measure silence by.)

        Heard means a HEARTBEAT and, once the vehicle has sent timed telemetry (its clock is
        synced), that telemetry too: on an unsigned link anyone can send the vehicle's heartbeat,
        and heartbeats alone must not keep a silent vehicle "up" (docs/operations.md)."""
        if self._vehicle_heartbeat_at is None:
            return None
        now = time.monotonic() if now is None else now
        silent = now - self._vehicle_heartbeat_at
        timed = self._timed_silent_s(now)
        return silent if timed is None else max(silent, timed)

    def _timed_silent_s(self, now: float) -> float | None:
        clock = self.mapper.clock
        if self._vehicle_timed_at is None or clock.fallback:
            return None
        return now - self._vehicle_timed_at

    def silence_cause(self, now: float | None = None) -> str:
        """Why the vehicle counts as silent: no heartbeat, or heartbeats without its timed telemetry."""
        now = time.monotonic() if now is None else now
        hb = None if self._vehicle_heartbeat_at is None else now - self._vehicle_heartbeat_at
        timed = self._timed_silent_s(now)
        if hb is not None and timed is not None and timed > hb + 1.0:
            return (f"heartbeats without the vehicle's timed telemetry for {timed:.1f} s (spoofed heartbeats, "
                    "or its streams stopped)")
        return f"no heartbeat for {hb if hb is not None else 0.0:.1f} s"

    def trust_report(self) -> dict:
        """What the link refused to believe, for /status: foreign vehicles, rejected timestamps,
        values outside the physical envelope, packets that did not parse."""
        stats = self.mapper.stats
        return {"target_system": self.mapper.target_system, "vehicle_silent_s": self.vehicle_silent_s(),
                "foreign_systems": [f.to_dict() for f in self.foreign_systems],
                "clock": self.mapper.clock.to_dict(), "time_rejected": stats.time_rejected,
                "gated": stats.to_dict()["gated"], "bad_data": self.bad_data, "other_source": stats.other_source,
                "handle_failures": self.handle_failures,
                "signing": self.signing_report(), "heartbeats": self.heartbeats.to_dict(time.monotonic()),
                "recording": self.recording_report(),
                "sequence": (None if (seq := self.sequence.stats(self.mapper.target_system,
                                                                 self.mapper.target_component)) is None
                             else seq.to_dict())}

    def recording_report(self) -> dict:
        """The live tlog: recording, or stopped and why (a full or failing disk), records dropped."""
        if self.tlog is None:
            return {"recording": False, "reason": "not recording (record_tlog off)", "stopped": False}
        return self.tlog.report()

    def signing_report(self) -> dict:
        """Whether the link is signed (a key is set and unsigned packets are refused) and what the
        signature check refused."""
        check = self.signature_check
        signed = check is not None and not self.config.allow_unsigned
        out = {"signed": signed, "key": check is not None, "allow_unsigned": bool(self.config.allow_unsigned)}
        if check is not None:
            out.update(check.to_dict())
        return out

    def wait_for_vehicle(self, timeout: float = 10.0) -> tuple[int, int]:
        """Block until the vehicle's heartbeat has been seen; its (system, component)."""
        deadline = time.monotonic() + timeout
        while not self.mapper.locked:
            if time.monotonic() > deadline:
                raise TimeoutError(f"no autopilot heartbeat on {self.config.url} within {timeout:.1f} s")
            time.sleep(0.02)
        return self.mapper.target_system, self.mapper.target_component

    # --- sending -----------------------------------------------------------------------------

    @property
    def mav(self):
        """pymavlink's encoder (``link.mav.mission_count_encode(...)``); send with :meth:`send`."""
        return self.conn.mav

    def send(self, msg) -> None:
        with self._send_lock:
            self.conn.mav.send(msg)

    def _on_sent(self, msg, *_args) -> None:
        self.sent += 1
        if self.tlog is not None:
            self.tlog.write(msg.get_msgbuf())

    # --- reader --------------------------------------------------------------------------------

    def _run(self) -> None:
        next_heartbeat = 0.0
        period = 1.0 / self.config.heartbeat_hz if self.config.heartbeat_hz > 0 else None
        conn = self.conn
        while not self._stop.is_set():
            if period is not None and time.monotonic() >= next_heartbeat:
                next_heartbeat = time.monotonic() + period
                self._send_heartbeat()
            try:
                msg = conn.recv_msg()
            except (OSError, ConnectionError) as exc:
                log.warning("link %s: receive failed: %s", self.config.url, exc)
                time.sleep(0.1)
                continue
            except Exception:  # noqa: BLE001 - a parser surprise must not kill the reader
                log.exception("link %s: unexpected receive error", self.config.url)
                continue
            if msg is None:
                conn.select(0.02)
                continue
            try:
                self.handle_message(msg)
            except Exception:  # noqa: BLE001 - one bad packet or consumer must not stop the link
                # counted; the traceback at most once a minute (a fault hit by every packet must not
                # write a traceback per packet: a full disk once wrote 21,042 in 48 s)
                self.handle_failures += 1
                now = time.monotonic()
                if self._failure_logged_at is None or now - self._failure_logged_at >= 60.0:
                    self._failure_logged_at = now
                    log.exception("link %s: failed to handle %s (%d failures so far; logged once a minute)",
                                  self.config.url, msg.get_type(), self.handle_failures)

    def _send_heartbeat(self) -> None:
        try:
            self.send(self.conn.mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0,
                                                     mavlink2.MAV_STATE_ACTIVE))
        except OSError as exc:  # udpin before the peer is known, tcp while reconnecting
            log.debug("heartbeat not sent: %s", exc)

    def handle_message(self, msg) -> None:
        """Record, map and dispatch one received message (public so tests can inject packets)."""
        if msg.get_type() == "BAD_DATA":
            self.bad_data += 1
            return
        self.received += 1
        raw = msg.get_msgbuf()
        # Receive time rounded to the tlog's microseconds, so replay sees exactly what live saw.
        recv_us = int(round((getattr(msg, "_timestamp", None) or time.time()) * 1e6))
        if self.tlog is not None:
            self.tlog.write_us(raw, recv_us)  # never raises: a full disk stops the recording, not the link
        packet = split_packet(bytes(raw))
        if packet is not None:
            previous_seq = self.sequence.last_seq(packet.sysid, packet.compid)
            self.sequence.note(packet.sysid, packet.compid, packet.seq)
            clock = self.mapper.clock
            accepted = clock.accepted
            frames = self.mapper.feed(recv_us / 1e6, packet.msgid, packet.sysid, packet.compid, packet.payload)
            if (self.mapper.locked and packet.sysid == self.mapper.target_system
                    and packet.compid == self.mapper.target_component):
                now = time.monotonic()
                if self.mapper.clock is clock and clock.accepted > accepted:
                    self._vehicle_timed_at = now
                    self.heartbeats.note_timed(now, clock.now)
                if packet.msgid == HEARTBEAT_ID:
                    self.heartbeats.note(now, packet.payload, packet.seq, previous_seq, self._timed_silent_s(now),
                                         self.mapper.clock.accepted if self.mapper.clock.synced else None)
                    self._vehicle_heartbeat_at = now
            for frame in frames:
                for listener in self._frame_listeners:
                    try:
                        listener(frame)
                    except Exception:  # noqa: BLE001 - one bad consumer must not starve the others
                        log.exception("frame listener failed")
        mtype = msg.get_type()
        for sub in self._subscriptions:
            if sub.types is None or mtype in sub.types:
                sub._offer(msg)
