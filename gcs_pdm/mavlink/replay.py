"""Replay a tlog through the live frame-mapping code, by message time.

``replay_tlog`` scans the file (``gcs_pdm.mavlink.tlog``; a file the provisional vehicle description
has just read is not scanned again), maps every CRC-valid packet with the
same :class:`~gcs_pdm.mavlink.mapping.FrameMapper` the live link uses, and hands each frame to
an optional ``frame_consumer``. As fast as possible (``speed=None``) the packets are fed one by one
only until the mapper is settled (vehicle identified, clock running); the rest of the log is mapped
a message type at a time over the scan's columns (``gcs_pdm.mavlink.frame_columns``: the same
frames, in the same order, and the same counters). Pacing at ×``speed`` real time follows the
tlog timestamps message by message; ``udp_target`` re-sends every valid packet, unchanged, to a
UDP address so other tools (QGroundControl, MAVProxy) can watch the replay. A file above
``SCAN_CACHE_MAX_BYTES`` is streamed and fed message by message.

Hook for the estimator/diagnoser: a ``frame_consumer`` that also has a ``report()`` method
returning a dict gets that dict into the summary under ``"consumer"``; a ``"faults"`` list in
it (``[{"time_s": …, "type": …, "magnitude": …}, …]``) is lifted to ``summary["faults"]``.

A consumer that ignores most frames says so, and the column mapping then does not make them
(two thirds of a log: position, air data, status, mission progress): ``consumed_frame_types``,
the frame classes it must see every frame of, and ``passed_over(count)``, told how many other
frames it was not handed (a pipeline counts them). Optionally ``next_due_s``: a frame of any type
whose ``time_s`` reaches it is handed over all the same, at its place in the log (the trace's
samples: ``gcs_pdm.replay.vehicle.TracedPipeline``); it is read again after every frame handed.
Without ``consumed_frame_types`` (and in paced, UDP, streamed and not-yet-settled stretches) every
frame is handed over, as the live link does. The summary is the same either way: the counts and
the frame time span come from the columns (``tests/test_skip_frames.py``).
"""
from __future__ import annotations

import logging
import socket
import time
from array import array
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gcs_pdm.mavlink.dialect import MESSAGE_CLASSES
from gcs_pdm.mavlink.frame_columns import Chunk, map_scanned, map_scanned_for
from gcs_pdm.mavlink.mapping import FrameMapper
from gcs_pdm.mavlink.sequence import scan_sequence_numbers, sequence_stats
from gcs_pdm.mavlink.tlog import ScannedTlog, ScanStats, scan_tlog_bounds, scanned_tlog, take_kept_scan

log = logging.getLogger(__name__)

FrameConsumer = Callable[[Any], None]


@dataclass
class ReplaySummary:
    path: str
    size_bytes: int
    messages_by_type: dict[str, int]
    scan: dict
    mapping: dict
    vehicle: dict
    frame_time_span_s: tuple[float, float] | None
    tlog_start_utc: str | None
    tlog_duration_s: float | None
    elapsed_s: float
    consumer: dict | None = None
    faults: list = field(default_factory=list)

    @property
    def readable(self) -> bool:
        """False when not one valid MAVLink packet could be read."""
        return self.messages > 0

    @property
    def not_diagnosed(self) -> list[str]:
        """What could not be diagnosed from this log, and why (empty: every diagnosis had its data)."""
        return undiagnosable(self.size_bytes, self.scan, self.mapping, self.vehicle)

    @property
    def messages(self) -> int:
        return self.scan["records"]

    @property
    def frames(self) -> int:
        return sum(self.mapping["frames_by_kind"].values())

    @property
    def skipped(self) -> dict[str, int]:
        return {k: self.scan[k] for k in ("bad_crc", "unknown_msgid", "garbage_bytes", "truncated_tail_bytes")}

    def to_dict(self) -> dict:
        return {
            "path": self.path,
            "size_bytes": self.size_bytes,
            "messages": self.messages,
            "messages_by_type": self.messages_by_type,
            "frames": self.frames,
            "frames_by_kind": self.mapping["frames_by_kind"],
            "skipped": self.skipped,
            "scan": self.scan,
            "mapping": self.mapping,
            "vehicle": self.vehicle,
            "frame_time_span_s": [round(t, 6) for t in self.frame_time_span_s] if self.frame_time_span_s else None,
            "tlog_start_utc": self.tlog_start_utc,
            "tlog_duration_s": self.tlog_duration_s,
            "elapsed_s": round(self.elapsed_s, 4),
            "messages_per_s": round(self.messages / self.elapsed_s) if self.elapsed_s > 0 else None,
            "faults": self.faults,
            "consumer": self.consumer,
            "readable": self.readable,
            "not_diagnosed": self.not_diagnosed,
        }


def undiagnosable(size_bytes: int, scan: dict, mapping: dict, vehicle: dict) -> list[str]:
    """Reasons, one per diagnosis that lacked its data (the streams come from docs/mavlink.md)."""
    if size_bytes == 0:
        return ["nothing: the file is empty"]
    if scan["records"] == 0:
        return [f"nothing: no valid MAVLink packet in {size_bytes} bytes (not a tlog?; "
                f"{scan['garbage_bytes']} bytes unreadable, {scan['bad_crc']} bad CRC)"]
    if vehicle.get("system") is None:
        return ["nothing: no autopilot HEARTBEAT, so no vehicle was identified (try --system N --component M)"]
    kinds = mapping["frames_by_kind"]
    out = []
    if not kinds.get("pack"):
        unmapped = [k for k in mapping["unmapped_keys"] if "BATTERY_STATUS" in k]
        why = f" (BATTERY_STATUS ids seen but not mapped: {', '.join(unmapped)})" if unmapped else ""
        out.append(f"battery packs (state of charge, pack health): no BATTERY_STATUS frames for the packs{why}")
    if not kinds.get("motor"):
        out.append("motors (power loss, temperature): no ESC_TELEMETRY_1_TO_4 frames")
    if not kinds.get("ambient"):
        out.append("thermal models: no ambient temperature (SCALED_PRESSURE)")
    return out


def _utc(timestamp_us: int) -> str | None:
    """A tlog stamp as an ISO date, None when no calendar holds it: the 8-byte stamp lies outside
    the packet's CRC, so a damaged one reaches here from an otherwise valid record."""
    try:
        return datetime.fromtimestamp(timestamp_us / 1e6, tz=timezone.utc).isoformat()
    except (OverflowError, ValueError, OSError):
        return None


def _udp_sender(target: str):
    host, _, port = target.rpartition(":")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    address = (host or "127.0.0.1", int(port))
    return sock, address


def _counted(rows, by_id: Counter, headers: tuple):
    """The rows of a streamed scan, counting their message ids and keeping each packet's system,
    component and start (``headers``: three arrays, for the sequence-number check)."""
    systems, components, starts = headers
    for row in rows:
        by_id[row[1]] += 1
        systems.append(row[2])
        components.append(row[3])
        starts.append(row[6])
        yield row


#: a tlog stamp further than this ahead of the previous one (µs) is not waited for by a paced replay:
#: the 8-byte stamp lies outside the packet's CRC, so a damaged one can be years ahead, and a log
#: left recording between two flights holds hours of nothing
PACE_MAX_GAP_US = 600 * 1_000_000


def _paced(rows, data: bytes, speed: float | None, sock):
    """The rows at ×``speed`` real time by their tlog timestamps, each packet re-sent over UDP
    (``sock``: socket and address) before it is mapped. A stamp more than ``PACE_MAX_GAP_US`` ahead
    of the previous one, or behind it, starts the pacing afresh from itself (no wait)."""
    pace_origin_ts = pace_origin_wall = previous_ts = None
    for row in rows:
        ts_us = row[0]
        if speed is not None:
            if pace_origin_ts is None or not previous_ts <= ts_us <= previous_ts + PACE_MAX_GAP_US:
                pace_origin_ts, pace_origin_wall = ts_us, time.monotonic()
            previous_ts = ts_us
            delay = (ts_us - pace_origin_ts) / 1e6 / speed - (time.monotonic() - pace_origin_wall)
            if delay > 0:
                time.sleep(delay)
        if sock is not None:
            try:
                sock[0].sendto(data[row[6]:row[7]], sock[1])
            except OSError as exc:  # a closed port on the other side must not stop the replay
                log.debug("UDP resend failed: %s", exc)
        yield row


def _frames_by_message(mapper: FrameMapper, rows, data: bytes):
    """The frames of each record that makes any, a record at a time (``rows``: the scan's)."""
    feed_from = mapper.feed_from
    # each payload is read in place in the file's bytes, from its bounds
    for ts_us, msgid, sysid, compid, payload_start, payload_end, _start, _end in rows:
        frames = feed_from(ts_us / 1e6, msgid, sysid, compid, data, payload_start, payload_end)
        if frames:
            yield frames


def _frames_by_type(mapper: FrameMapper, scanned: ScannedTlog, consumed: frozenset | None = None):
    """The frames of a scanned log: record by record until the mapper is settled (vehicle
    identified, clock running, nothing held), then the rest a message type at a time
    (``gcs_pdm.mavlink.frame_columns``), in chunks in log order; the same frames and counters.
    With ``consumed`` (frame classes) the column stretch comes as chunks (:class:`Chunk`) whose frames of
    other types are passed over."""
    feed_from, data = mapper.feed_from, scanned.data
    for index, (ts_us, msgid, sysid, compid, payload_start, payload_end, _s, _e) in enumerate(zip(*scanned.columns)):
        if mapper.settled():
            if consumed is None:
                yield from map_scanned(mapper, data, scanned.columns, index)
            else:
                yield from map_scanned_for(mapper, data, scanned.columns, index, consumed)
            return
        frames = feed_from(ts_us / 1e6, msgid, sysid, compid, data, payload_start, payload_end)
        if frames:
            yield frames


def _hand_consumed(chunk: Chunk, consume) -> None:
    """A chunk's consumed frames to a consumer that wants no others."""
    for frame in chunk.frames:
        consume(frame)
    if chunk.passed:
        consume.passed_over(chunk.passed)


def _hand_over(chunk: Chunk, consume) -> None:
    """A chunk's consumed frames, and each passed-over frame whose time reaches the consumer's
    ``next_due_s`` when it comes, in log order; the rest counted as passed over."""
    handed = 0
    latest = chunk.latest_in_gap
    for g, frame in enumerate(chunk.frames):
        if latest[g] >= consume.next_due_s:
            handed += _hand_due(chunk, g, consume)
        consume(frame)
    if latest[-1] >= consume.next_due_s:
        handed += _hand_due(chunk, len(chunk.frames), consume)
    if chunk.passed > handed:
        consume.passed_over(chunk.passed - handed)


def _hand_due(chunk: Chunk, gap: int, consume) -> int:
    """The passed-over frames of one gap that are due when they come, made and handed over."""
    handed = 0
    start, end = chunk.gap_start[gap], chunk.gap_start[gap + 1]
    for j, t in enumerate(chunk.passed_times[start:end].tolist(), start):
        if t >= consume.next_due_s:
            consume(chunk.passed_frame(j))
            handed += 1
    return handed


def replay_tlog(path: str | Path, *, mapper: FrameMapper | None = None,
                frame_consumer: FrameConsumer | None = None, speed: float | None = None,
                udp_target: str | None = None) -> ReplaySummary:
    """Replay ``path`` to its end; damaged data is skipped and counted, never raised."""
    path = Path(path)
    scanned = take_kept_scan(path)  # kept by the provisional description's pass, if it ran
    if scanned is None and speed is None and not udp_target:
        scanned = scanned_tlog(path)  # None above the size limit: streamed below
        take_kept_scan(path)  # nothing stays kept after the replay
    mapper = mapper or FrameMapper()
    by_id: Counter = Counter()
    first_t = last_t = None
    sock = None
    if scanned is not None:
        data, stats = scanned.data, scanned.stats
        rows = zip(*scanned.columns)  # the columns straight into the mapping: no record objects
        ids, counts = np.unique(np.frombuffer(scanned.columns[1], dtype=np.uint64), return_counts=True)
        by_id.update(dict(zip(ids.tolist(), counts.tolist())))
    else:
        data, stats = path.read_bytes(), ScanStats()
        headers = (array("Q"), array("Q"), array("Q"))
        rows = _counted(scan_tlog_bounds(data, stats), by_id, headers)
    if speed is not None or udp_target:
        sock = _udp_sender(udp_target) if udp_target else None
        rows = _paced(rows, data, speed, sock)
    consume = frame_consumer
    consumed = getattr(frame_consumer, "consumed_frame_types", None)
    started = time.perf_counter()
    if scanned is not None and sock is None and speed is None:  # the whole log at hand: by message type
        batches = _frames_by_type(mapper, scanned, None if consumed is None else frozenset(consumed))
    else:
        batches = _frames_by_message(mapper, rows, data)
    dues = hasattr(frame_consumer, "next_due_s")
    for frames in batches:
        if type(frames) is Chunk:
            if first_t is None:
                first_t = frames.first_time_s
            last_t = frames.last_time_s
            if dues:
                _hand_over(frames, consume)
            else:
                _hand_consumed(frames, consume)
            continue
        if first_t is None:
            first_t = frames[0].time_s
        last_t = frames[-1].time_s
        if consume is not None:
            for frame in frames:
                consume(frame)
    leftovers = mapper.flush()
    if frame_consumer is not None:
        for frame in leftovers:
            frame_consumer(frame)
    elapsed = time.perf_counter() - started
    if sock is not None:
        sock[0].close()
    skipped = stats.bad_crc + stats.unknown_msgid
    if skipped or stats.garbage_bytes or stats.truncated_tail_bytes:
        log.warning("%s: skipped %d bad-CRC and %d unknown packets, %d garbage bytes, %d truncated tail bytes",
                    path.name, stats.bad_crc, stats.unknown_msgid, stats.garbage_bytes, stats.truncated_tail_bytes)
    consumer_report = None
    faults: list = []
    report = getattr(frame_consumer, "report", None)
    if callable(report):
        consumer_report = report()
        faults = list(consumer_report.get("faults", [])) if isinstance(consumer_report, dict) else []
    names = {msgid: (MESSAGE_CLASSES[msgid].msgname if msgid in MESSAGE_CLASSES else str(msgid)) for msgid in by_id}
    start_utc = duration = None
    if stats.first_timestamp_us is not None:
        start_utc = _utc(stats.first_timestamp_us)
        duration = (stats.last_timestamp_us - stats.first_timestamp_us) / 1e6
    vehicle = {"system": mapper.target_system, "component": mapper.target_component,
               "reboots": mapper.clock.reboots, "clock": "receive-time fallback" if mapper.clock.fallback else "vehicle"}
    if mapper.target_system is not None:
        systems, components, starts = (scanned.columns[2], scanned.columns[3], scanned.columns[6]) \
            if scanned is not None else headers
        seq = sequence_stats(np.frombuffer(systems, dtype=np.uint64), np.frombuffer(components, dtype=np.uint64),
                             scan_sequence_numbers(data, starts), (mapper.target_system, mapper.target_component))
        vehicle["sequence"] = seq.to_dict()
        if seq.shared:
            log.warning("%s: %s", path.name, seq.verdict)
    return ReplaySummary(
        path=str(path), size_bytes=len(data),
        messages_by_type=dict(sorted(((names[k], v) for k, v in by_id.items()), key=lambda kv: (-kv[1], kv[0]))),
        scan=stats.to_dict(), mapping=mapper.stats.to_dict(),
        vehicle=vehicle,
        frame_time_span_s=(first_t, last_t) if first_t is not None else None,
        tlog_start_utc=start_utc, tlog_duration_s=duration, elapsed_s=elapsed,
        consumer=consumer_report, faults=faults,
    )
