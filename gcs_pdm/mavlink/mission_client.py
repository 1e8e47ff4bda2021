"""GCS side of the MAVLink mission protocol: upload, download, clear, set current.

Follows https://mavlink.io/en/services/mission.html: the vehicle drives an upload with
MISSION_REQUEST_INT (or the legacy MISSION_REQUEST, answered with MISSION_ITEM_INT all the same)
and ends it with MISSION_ACK; the GCS drives a download. Timeouts and retries (docs/mavlink.md):

* spec values: 1500 ms for operations, 250 ms for items, 5 retries;
* the timeout adapts to the measured round trip (4 x smoothed RTT, never above the spec value,
  never below ``min_item_s``), and a stage gives up only after it has gone ``retries`` spec
  timeouts without progress — never sooner than the spec would, much faster recovery on a good link;
* during an upload, when the vehicle stays silent, the client re-sends every item the vehicle
  may be waiting for (from the highest requested to one past the highest sent), in order: the
  vehicle takes the one it waits for and drops the others as out of sequence, as the spec says;
* a lost final MISSION_ACK cannot be recovered inside one transfer (the vehicle has finished),
  so the whole upload is repeated (``attempts``); re-uploading the same mission is idempotent.

An upload returns only after a MISSION_ACK with MAV_MISSION_ACCEPTED; everything else raises
:class:`MissionError` (and, if the client gives up mid-transfer, it sends
MAV_MISSION_OPERATION_CANCELLED so the vehicle keeps its previous mission).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from gcs_pdm.mavlink.connection import Link
from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.missions import MissionItem

log = logging.getLogger(__name__)

MISSION_MESSAGES = frozenset({
    "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK", "MISSION_COUNT", "MISSION_ITEM_INT",
    "MISSION_ITEM", "MISSION_CURRENT", "STATUSTEXT",
})
MAV_MISSION_ACCEPTED = mavlink2.MAV_MISSION_ACCEPTED
MAV_MISSION_OPERATION_CANCELLED = mavlink2.MAV_MISSION_OPERATION_CANCELLED
MAV_MISSION_TYPE_MISSION = mavlink2.MAV_MISSION_TYPE_MISSION
# Results after which trying again cannot help: the vehicle refuses this mission.
_FINAL_RESULTS = frozenset({
    mavlink2.MAV_MISSION_UNSUPPORTED_FRAME, mavlink2.MAV_MISSION_UNSUPPORTED, mavlink2.MAV_MISSION_NO_SPACE,
    mavlink2.MAV_MISSION_INVALID, mavlink2.MAV_MISSION_INVALID_PARAM1, mavlink2.MAV_MISSION_INVALID_PARAM2,
    mavlink2.MAV_MISSION_INVALID_PARAM3, mavlink2.MAV_MISSION_INVALID_PARAM4,
    mavlink2.MAV_MISSION_INVALID_PARAM5_X, mavlink2.MAV_MISSION_INVALID_PARAM6_Y,
    mavlink2.MAV_MISSION_INVALID_PARAM7, mavlink2.MAV_MISSION_DENIED,
})


# At most this many items are re-sent at once after a silence (bounds the burst on a slow radio).
_MAX_RESEND_WINDOW = 16


def result_name(code: int) -> str:
    entry = mavlink2.enums["MAV_MISSION_RESULT"].get(code)
    return entry.name if entry else f"MAV_MISSION_RESULT({code})"


class MissionError(RuntimeError):
    """A mission operation that did not complete; the message says which stage and why."""


class MissionRejected(MissionError):
    """The vehicle answered with a MISSION_ACK other than MAV_MISSION_ACCEPTED."""

    def __init__(self, operation: str, result: int):
        super().__init__(f"{operation}: vehicle replied {result_name(result)} ({result})")
        self.result = result


class MissionTimeout(MissionError):
    """The vehicle stopped answering (after all retries)."""


@dataclass
class MissionTimeouts:
    default_s: float = 1.5  # spec: operations (MISSION_COUNT, REQUEST_LIST, CLEAR_ALL)
    item_s: float = 0.25  # spec: mission items
    retries: int = 5  # spec: maximum retries
    min_item_s: float = 0.02  # floor of the adaptive timeout
    attempts: int = 5  # whole uploads tried before giving up (covers a lost final ACK)


class _RttEstimator:
    """Smoothed round-trip time (RFC 6298 style) driving the adaptive timeouts."""

    def __init__(self):
        self.srtt: float | None = None

    def sample(self, rtt: float) -> None:
        self.srtt = rtt if self.srtt is None else 0.875 * self.srtt + 0.125 * rtt

    def timeout(self, ceiling: float, floor: float) -> float:
        if self.srtt is None:
            return ceiling
        return min(ceiling, max(floor, 4.0 * self.srtt + 0.005))


@dataclass
class TransferStats:
    attempts: int = 0
    items_sent: int = 0
    resends: int = 0
    requests_seen: int = 0
    duration_s: float = 0.0


class MissionClient:
    """Mission operations against the vehicle on ``link`` (whose reader thread must run)."""

    def __init__(self, link: Link, timeouts: MissionTimeouts | None = None,
                 target_system: int | None = None, target_component: int | None = None):
        self.link = link
        self.timeouts = timeouts or MissionTimeouts()
        self._target = (target_system, target_component)
        self.rtt = _RttEstimator()
        self.last_stats = TransferStats()

    # --- plumbing ----------------------------------------------------------------------------

    def _vehicle(self) -> tuple[int, int]:
        if not self.link.running:
            raise MissionError("the link's reader is not running: call link.start() first")
        sysid, compid = self._target
        if sysid is not None and compid is not None:
            return sysid, compid
        return self.link.wait_for_vehicle(timeout=self.timeouts.default_s * (self.timeouts.retries + 1))

    def _for_us(self, msg, vehicle: tuple[int, int]) -> bool:
        """From the vehicle and addressed to this component (a router also forwards others' traffic)."""
        if (msg.get_srcSystem(), msg.get_srcComponent()) != vehicle:
            return False
        ts = getattr(msg, "target_system", None)
        if ts is None:
            return True
        own = self.link.config
        tc = getattr(msg, "target_component", 0)
        return ts in (0, own.source_system) and tc in (0, own.source_component)

    def _mission_type_ok(self, msg) -> bool:
        return getattr(msg, "mission_type", MAV_MISSION_TYPE_MISSION) == MAV_MISSION_TYPE_MISSION

    def _send_item(self, vehicle, item: MissionItem) -> None:
        self.link.send(self.link.mav.mission_item_int_encode(
            vehicle[0], vehicle[1], item.seq, item.frame, item.command, item.current, item.autocontinue,
            item.param1, item.param2, item.param3, item.param4, item.x, item.y, item.z, item.mission_type))
        self.last_stats.items_sent += 1

    # --- upload ------------------------------------------------------------------------------

    def upload(self, items: list[MissionItem]) -> TransferStats:
        """Replace the vehicle's mission by ``items``; returns only once the vehicle accepted it."""
        items = [item if item.seq == i else _with_seq(item, i) for i, item in enumerate(items)]
        if not items:
            self.clear()
            return self.last_stats
        vehicle = self._vehicle()
        self.last_stats = TransferStats()
        started = time.monotonic()
        last_error: MissionError | None = None
        with self.link.subscribe(MISSION_MESSAGES) as sub:
            for attempt in range(1, self.timeouts.attempts + 1):
                self.last_stats.attempts = attempt
                sub.drain()
                try:
                    self._upload_once(sub, vehicle, items)
                    self.last_stats.duration_s = time.monotonic() - started
                    log.info("mission of %d items uploaded in %.2f s (%d attempt(s), %d resends)",
                             len(items), self.last_stats.duration_s, attempt, self.last_stats.resends)
                    return self.last_stats
                except MissionRejected as exc:
                    if exc.result in _FINAL_RESULTS:
                        raise
                    last_error = exc
                except MissionTimeout as exc:
                    last_error = exc
                log.warning("mission upload attempt %d/%d failed: %s", attempt, self.timeouts.attempts, last_error)
            self._cancel(vehicle)
        raise MissionError(f"mission upload of {len(items)} items failed after {self.timeouts.attempts} attempts; "
                           f"last error: {last_error}")

    def _upload_once(self, sub, vehicle, items: list[MissionItem]) -> None:
        t = self.timeouts
        n = len(items)
        count_msg = self.link.mav.mission_count_encode(vehicle[0], vehicle[1], n, MAV_MISSION_TYPE_MISSION)
        self.link.send(count_msg)
        sent_at = time.monotonic()
        last_progress = sent_at
        highest_requested = -1  # nothing requested yet: MISSION_COUNT is what may need resending
        highest_sent = -1
        resent = False
        resend_at = sent_at + self.rtt.timeout(t.default_s, t.min_item_s)
        while True:
            now = time.monotonic()
            if now - last_progress > t.retries * (t.default_s if highest_requested < 0 else t.item_s) + t.item_s:
                stage = "MISSION_COUNT" if highest_requested < 0 else f"item {highest_requested}"
                raise MissionTimeout(f"mission upload: no answer from the vehicle after {stage}")
            msg = sub.get(timeout=max(0.0, resend_at - now))
            now = time.monotonic()
            if msg is None:
                # Silence: re-send what the vehicle most likely waits for.
                self.last_stats.resends += 1
                resent = True
                if highest_requested < 0:
                    self.link.send(count_msg)
                    resend_at = now + self.rtt.timeout(t.default_s, t.min_item_s)
                else:
                    # The vehicle waits for some item in [highest requested, highest sent + 1]:
                    # send them all in order; it takes the one it waits for and then the
                    # following ones, and drops the rest as out of sequence. Sending only items
                    # it ignores is not harmless: MAVSDK, for one, restarts its re-request timer
                    # on every item, so it would never re-request.
                    last = min(highest_sent + 1, n - 1, highest_requested + _MAX_RESEND_WINDOW - 1)
                    for seq in range(highest_requested, last + 1):
                        self._send_item(vehicle, items[seq])
                    highest_sent = max(highest_sent, last)
                    resend_at = now + self.rtt.timeout(t.item_s, t.min_item_s)
                continue
            if not self._for_us(msg, vehicle) or not self._mission_type_ok(msg):
                continue
            mtype = msg.get_type()
            if mtype in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
                seq = msg.seq
                self.last_stats.requests_seen += 1
                if not 0 <= seq < n:
                    log.warning("vehicle requested item %d of a %d-item mission; ignored", seq, n)
                    continue
                if seq > highest_requested:
                    if not resent:  # Karn: a reply to a re-sent message is no RTT sample
                        self.rtt.sample(now - sent_at)
                    highest_requested = seq
                    last_progress = now
                resent = False
                self._send_item(vehicle, items[seq])
                highest_sent = max(highest_sent, seq)
                sent_at = now
                resend_at = now + self.rtt.timeout(t.item_s, t.min_item_s)
            elif mtype == "MISSION_ACK":
                if msg.type == MAV_MISSION_ACCEPTED:
                    if highest_requested == n - 1:
                        if not resent:
                            self.rtt.sample(now - sent_at)
                        return
                    # An ACCEPTED before the last item was requested belongs to some other exchange.
                    continue
                raise MissionRejected("mission upload", msg.type)

    def _cancel(self, vehicle) -> None:
        try:
            self.link.send(self.link.mav.mission_ack_encode(vehicle[0], vehicle[1], MAV_MISSION_OPERATION_CANCELLED,
                                                            MAV_MISSION_TYPE_MISSION))
        except OSError as exc:
            log.warning("could not send mission cancel: %s", exc)

    # --- download ----------------------------------------------------------------------------

    def download(self) -> list[MissionItem]:
        """The vehicle's current mission."""
        t = self.timeouts
        vehicle = self._vehicle()
        self.last_stats = TransferStats(attempts=1)
        started = time.monotonic()
        with self.link.subscribe(MISSION_MESSAGES) as sub:
            sub.drain()
            count = self._request_count(sub, vehicle)
            items: list[MissionItem] = []
            for seq in range(count):
                items.append(self._request_item(sub, vehicle, seq))
            self.link.send(self.link.mav.mission_ack_encode(vehicle[0], vehicle[1], MAV_MISSION_ACCEPTED,
                                                            MAV_MISSION_TYPE_MISSION))
        self.last_stats.duration_s = time.monotonic() - started
        log.info("mission of %d items downloaded in %.2f s (%d resends)", count, self.last_stats.duration_s,
                 self.last_stats.resends)
        return items

    def _ask(self, sub, vehicle, request, reply, *, spec_s: float, floor_s: float, give_up_s: float,
             failure: str):
        """Send ``request`` until ``reply(msg)`` returns something other than None, and return that.

        The one send/retry loop of the GCS-driven exchanges: each send waits the adaptive timeout
        (``spec_s`` at most, ``floor_s`` at least) for an answer from the vehicle; the exchange gives
        up only after ``give_up_s`` *and* the spec's number of retries (a vehicle still busy with an
        earlier transfer answers only once that one times out). Karn's rule: only an answer to the
        first send is an RTT sample. ``failure`` (with ``{sends}``) is the MissionTimeout message.
        ``reply`` may raise (e.g. MissionRejected) to end the exchange.
        """
        give_up = time.monotonic() + give_up_s
        sends = 0
        while time.monotonic() < give_up or sends <= self.timeouts.retries:
            sends += 1
            self.link.send(request)
            sent_at = time.monotonic()
            deadline = sent_at + self.rtt.timeout(spec_s, floor_s)
            while (remaining := deadline - time.monotonic()) > 0:
                msg = sub.get(timeout=remaining)
                if msg is None or not self._for_us(msg, vehicle):
                    continue
                result = reply(msg)
                if result is not None:
                    if sends == 1:
                        self.rtt.sample(time.monotonic() - sent_at)
                    return result
            self.last_stats.resends += 1
        raise MissionTimeout(failure.format(sends=sends))

    def _request_count(self, sub, vehicle) -> int:
        t = self.timeouts

        def reply(msg):
            if not self._mission_type_ok(msg):
                return None
            if msg.get_type() == "MISSION_COUNT":
                return msg.count
            if msg.get_type() == "MISSION_ACK" and msg.type != MAV_MISSION_ACCEPTED:
                raise MissionRejected("mission download", msg.type)
            return None

        request = self.link.mav.mission_request_list_encode(vehicle[0], vehicle[1], MAV_MISSION_TYPE_MISSION)
        return self._ask(sub, vehicle, request, reply, spec_s=t.default_s, floor_s=t.min_item_s * 5,
                         give_up_s=t.retries * t.default_s,
                         failure="mission download: no MISSION_COUNT after {sends} MISSION_REQUEST_LIST")

    def _request_item(self, sub, vehicle, seq: int) -> MissionItem:
        t = self.timeouts

        def reply(msg):
            if not self._mission_type_ok(msg):
                return None
            mtype = msg.get_type()
            if mtype in ("MISSION_ITEM_INT", "MISSION_ITEM") and msg.seq == seq:
                return _item_from_message(msg)
            if mtype == "MISSION_ACK" and msg.type != MAV_MISSION_ACCEPTED:
                raise MissionRejected(f"mission download (item {seq})", msg.type)
            return None

        request = self.link.mav.mission_request_int_encode(vehicle[0], vehicle[1], seq, MAV_MISSION_TYPE_MISSION)
        return self._ask(sub, vehicle, request, reply, spec_s=t.item_s, floor_s=t.min_item_s,
                         give_up_s=t.retries * t.item_s + t.item_s,
                         failure=f"mission download: item {seq} not received after {{sends}} requests")

    # --- clear / set current ---------------------------------------------------------------

    def clear(self) -> None:
        """Delete the vehicle's mission (MISSION_CLEAR_ALL until MISSION_ACK)."""
        t = self.timeouts
        vehicle = self._vehicle()

        def reply(msg):
            if msg.get_type() != "MISSION_ACK":
                return None
            if not self._mission_type_ok(msg) and msg.mission_type != mavlink2.MAV_MISSION_TYPE_ALL:
                return None
            if msg.type == MAV_MISSION_ACCEPTED:
                return True
            raise MissionRejected("mission clear", msg.type)

        request = self.link.mav.mission_clear_all_encode(vehicle[0], vehicle[1], MAV_MISSION_TYPE_MISSION)
        with self.link.subscribe(MISSION_MESSAGES) as sub:
            sub.drain()
            self._ask(sub, vehicle, request, reply, spec_s=t.default_s, floor_s=t.min_item_s * 5,
                      give_up_s=t.retries * t.default_s,
                      failure="mission clear: no MISSION_ACK after {sends} MISSION_CLEAR_ALL")

    def set_current(self, seq: int) -> None:
        """Make item ``seq`` current; confirmed by the vehicle's MISSION_CURRENT (spec: no ACK)."""
        t = self.timeouts
        vehicle = self._vehicle()
        request = self.link.mav.mission_set_current_encode(vehicle[0], vehicle[1], seq)
        with self.link.subscribe(MISSION_MESSAGES) as sub:
            sub.drain()
            for _ in range(t.retries + 1):
                self.link.send(request)
                deadline = time.monotonic() + t.default_s
                while (remaining := deadline - time.monotonic()) > 0:
                    msg = sub.get(timeout=remaining)
                    if msg is None or (msg.get_srcSystem(), msg.get_srcComponent()) != vehicle:
                        continue
                    if msg.get_type() == "MISSION_CURRENT" and msg.seq == seq:
                        return
                    if msg.get_type() == "STATUSTEXT" and msg.severity <= mavlink2.MAV_SEVERITY_ERROR:
                        raise MissionError(f"set current item {seq}: vehicle says {msg.text!r}")
        raise MissionTimeout(f"set current item {seq}: no MISSION_CURRENT with seq {seq}")


def _with_seq(item: MissionItem, seq: int) -> MissionItem:
    from dataclasses import replace
    return replace(item, seq=seq)


def _item_from_message(msg) -> MissionItem:
    if msg.get_type() == "MISSION_ITEM":  # legacy float item: positions in degrees
        from gcs_pdm.missions import xy_scale
        scale = xy_scale(msg.frame)
        x, y = round(msg.x * scale), round(msg.y * scale)
    else:
        x, y = msg.x, msg.y
    return MissionItem(seq=msg.seq, frame=msg.frame, command=msg.command, current=msg.current,
                       autocontinue=msg.autocontinue, param1=msg.param1, param2=msg.param2, param3=msg.param3,
                       param4=msg.param4, x=x, y=y, z=msg.z, mission_type=getattr(msg, "mission_type", 0))
