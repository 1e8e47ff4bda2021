"""tlog files: write them (8-byte big-endian µs timestamp + raw packet) and scan them fast.

The scanner walks the bytes itself instead of feeding pymavlink's parser one byte at a time:
it reads a record's header, checks the CRC (``fastcrc`` + the dialect's CRC_EXTRA) and hands out
the payload as a memoryview, so messages nobody maps cost only a CRC and a counter. Damage is
skipped and counted, never fatal:

* a packet whose CRC fails, or whose message id is not in the dialect, is skipped whole when a
  plausible record follows it, else byte by byte until one does (``garbage_bytes``);
* a record cut off by the end of the file is counted in ``truncated_tail_bytes``.

``scanned_tlog`` reads and scans a file once and keeps its records for the next reader, so a command
that reads a log twice (``gcs-pdm replay`` derives the provisional vehicle description, then
replays) decodes it once; the replay takes the kept scan (``take_kept_scan``) and nothing stays in
memory after it. ``tlog_message_dicts`` decodes only the named messages of a tlog into pymavlink-style field
dicts (what the provisional vehicle description reads).
"""
from __future__ import annotations

import logging
import struct
from array import array
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator

from fastcrc.crc16 import mcrf4xx

from gcs_pdm.mavlink.wire import CRC_EXTRA_BYTES, MAVLINK_IFLAG_SIGNED, SIGNATURE_LEN, layout

log = logging.getLogger(__name__)

_TIMESTAMP = struct.Struct(">Q")


#: wall seconds between two attempts to resume a recording stopped by a disk error
RESUME_RETRY_S = 5.0
#: free bytes the disk must have again before a stopped recording resumes
RESUME_FREE_BYTES = 8 << 20


class TlogWriter:
    """Appends records to a tlog; safe to call from the reader thread and senders at once.

    A write never raises: a full or failing disk (ENOSPC, EIO, a read-only remount) stops the
    recording — said once in the log, in :meth:`report` and through ``on_change`` — and the records
    meanwhile are counted as dropped; every ``RESUME_RETRY_S`` it looks for ``RESUME_FREE_BYTES`` of
    free space and resumes appending. What was in the write buffer when the disk failed may end as a
    cut record in the file, which the tlog scanner skips and counts (``garbage_bytes``)."""

    def __init__(self, path: str | Path, *, clock=time.time, wall=None, opener=open):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._opener = opener  # tests pass a fault-injecting one
        self._file: BinaryIO | None = opener(self.path, "ab")
        self._closed = False
        self._lock = threading.Lock()
        self._clock = clock
        self._wall = wall if wall is not None else (lambda: time.monotonic())  # looked up per call
        self.records = 0
        self.dropped = 0  # records not written while the recording was stopped
        self.failure: str | None = None
        self.stops = 0
        self._retry_at = 0.0
        self.on_change = None  # callback(report) when the recording stops or resumes

    def write(self, packet: bytes, timestamp_s: float | None = None) -> None:
        stamp = self._clock() if timestamp_s is None else timestamp_s
        self._append(_TIMESTAMP.pack(int(round(stamp * 1e6))) + bytes(packet))

    def write_us(self, packet: bytes, timestamp_us: int) -> None:
        """Like :meth:`write` with the timestamp already in integer microseconds."""
        self._append(_TIMESTAMP.pack(timestamp_us) + bytes(packet))

    def _append(self, record: bytes) -> None:
        changed = None
        with self._lock:
            if self._closed:
                return
            if self._file is None:
                if not self._try_resume(record):
                    self.dropped += 1
                    return
                changed = self._report()
            else:
                try:
                    self._file.write(record)
                    self.records += 1
                except OSError as exc:
                    self.dropped += 1
                    changed = self._stop(exc)
        if changed is not None and self.on_change is not None:
            self.on_change(changed)

    def _stop(self, exc: OSError) -> dict:
        self.failure = f"tlog {self.path.name}: {exc.strerror or exc}"
        self.stops += 1
        self._retry_at = self._wall() + RESUME_RETRY_S
        self._discard(self._file)
        self._file = None
        log.warning("recording stopped: %s; telemetry continues unrecorded, resuming when the disk has room",
                    self.failure)
        return self._report()

    @staticmethod
    def _discard(fh) -> None:
        try:
            fh.close()  # flushes what it can, and closes the descriptor whatever happens
        except OSError:
            pass

    def _try_resume(self, record: bytes) -> bool:
        """Reopen and write ``record`` through to the disk; False (quietly: the stop was said) while
        the disk still refuses it."""
        if self._wall() < self._retry_at:
            return False
        self._retry_at = self._wall() + RESUME_RETRY_S
        import shutil

        try:
            if shutil.disk_usage(self.path.parent).free < RESUME_FREE_BYTES:
                return False
            fh = self._opener(self.path, "ab")
        except OSError:
            return False
        try:
            fh.write(record)
            fh.flush()
        except OSError:
            self._discard(fh)
            return False
        self._file = fh
        self.records += 1
        log.warning("recording resumed to %s (%d records dropped while stopped)", self.path.name, self.dropped)
        self.failure = None
        return True

    def _report(self) -> dict:
        out = {"recording": self._file is not None, "stopped": self.failure is not None, "file": self.path.name,
               "records": self.records, "dropped": self.dropped, "stops": self.stops}
        if self.failure is not None:
            out["reason"] = self.failure
        return out

    def report(self) -> dict:
        with self._lock:
            return self._report()

    def flush(self) -> None:
        with self._lock:
            if self._file is not None and not self._closed:
                try:
                    self._file.flush()
                except OSError as exc:
                    self._stop(exc)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            if self._file is not None:
                try:
                    self._file.close()
                except OSError as exc:
                    log.warning("tlog %s: closing failed: %s", self.path.name, exc.strerror or exc)
                self._file = None

    def __enter__(self) -> "TlogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class ScanStats:
    records: int = 0  # CRC-valid packets handed out
    bad_crc: int = 0  # well-framed packets whose CRC did not match
    unknown_msgid: int = 0  # well-framed packets of message ids outside the dialect
    garbage_bytes: int = 0  # bytes skipped while looking for the next record
    truncated_tail_bytes: int = 0  # an incomplete record at the end of the file
    mavlink1: int = 0
    mavlink2: int = 0
    signed: int = 0
    first_timestamp_us: int | None = None
    last_timestamp_us: int | None = None

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _find_magic(data: bytes, start: int) -> int:
    a = data.find(b"\xfd", start)
    b = data.find(b"\xfe", start)
    if a < 0:
        return b
    if b < 0:
        return a
    return a if a < b else b


def scan_tlog_bytes(data: bytes, stats: ScanStats | None = None) -> Iterator[tuple[int, int, int, int, memoryview, int, int]]:
    """Yield ``(timestamp_us, msgid, sysid, compid, payload, packet_start, packet_end)`` per valid packet.

    A tlog record is an 8-byte big-endian µs timestamp followed by one MAVLink 1 (0xFE) or
    MAVLink 2 (0xFD) packet; MAVLink 2 payloads come back zero-truncated, as on the wire.
    """
    return _scan_records(data, stats, views=True)


def scan_tlog_bounds(data: bytes, stats: ScanStats | None = None) -> Iterator[tuple[int, ...]]:
    """Like :func:`scan_tlog_bytes` with each payload as its bounds in ``data``: ``(timestamp_us,
    msgid, sysid, compid, payload_start, payload_end, packet_start, packet_end)``, plain integers
    (the rows of :attr:`ScannedTlog.columns`)."""
    return _scan_records(data, stats)


def _scan_records(data: bytes, stats: ScanStats | None, views: bool = False) -> Iterator[tuple]:
    """:func:`scan_tlog_bytes` (``views``), or with the payload as its bounds: ``(timestamp_us,
    msgid, sysid, compid, payload_start, payload_end, packet_start, packet_end)``, plain integers."""
    st = stats if stats is not None else ScanStats()
    mv = memoryview(data)
    n = len(data)
    pos = 0
    extras = CRC_EXTRA_BYTES
    crc16 = mcrf4xx
    ts_unpack = _TIMESTAMP.unpack_from
    first_ts = None
    last_ts = None
    while pos + 9 <= n:
        p = pos + 8  # packet start
        magic = data[p]
        if magic == 0xFD:
            if p + 12 > n:
                st.truncated_tail_bytes += n - pos
                break
            plen = data[p + 1]
            body_end = p + 10 + plen
            end = body_end + 2
            signed = data[p + 2] & MAVLINK_IFLAG_SIGNED
            if signed:
                end += SIGNATURE_LEN
            msgid = data[p + 7] | (data[p + 8] << 8) | (data[p + 9] << 16)
            sysid = data[p + 5]
            compid = data[p + 6]
            v2 = True
        elif magic == 0xFE:
            if p + 8 > n:
                st.truncated_tail_bytes += n - pos
                break
            plen = data[p + 1]
            body_end = p + 6 + plen
            end = body_end + 2
            msgid = data[p + 5]
            sysid = data[p + 3]
            compid = data[p + 4]
            v2 = signed = False
        else:
            nxt = _find_magic(data, p + 1)
            if nxt < 0:
                st.garbage_bytes += n - pos
                pos = n
                break
            st.garbage_bytes += nxt - 8 - pos
            pos = nxt - 8
            continue
        if end > n:
            # Either the file was cut off inside this record, or this "record" is garbage whose
            # length byte points past the end: look for a complete record further on first.
            nxt = _find_magic(data, p + 1)
            while 0 <= nxt and nxt + 4 <= n:
                if _plausible_record(data, nxt - 8, n):
                    break
                nxt = _find_magic(data, nxt + 1)
            else:
                st.truncated_tail_bytes += n - pos
                break
            st.garbage_bytes += nxt - 8 - pos
            pos = nxt - 8
            continue
        extra = extras.get(msgid)
        good = extra is not None and crc16(extra, crc16(mv[p + 1:body_end])) == (data[body_end] | (data[body_end + 1] << 8))
        if good:
            ts = ts_unpack(data, pos)[0]
            if first_ts is None:
                first_ts = ts
            last_ts = ts
            st.records += 1
            if v2:
                st.mavlink2 += 1
                st.signed += 1 if signed else 0  # a packet handed out, as the other counters
                payload_start = p + 10
            else:
                st.mavlink1 += 1
                payload_start = p + 6
            if views:
                yield ts, msgid, sysid, compid, mv[payload_start:body_end], p, end
            else:
                yield ts, msgid, sysid, compid, payload_start, body_end, p, end
            pos = end
            continue
        # A damaged or foreign packet: skip it whole if a record seems to start right after it
        # (the usual case: one corrupted packet), otherwise resynchronise byte by byte.
        if end == n or (end + 9 <= n and data[end + 8] in (0xFD, 0xFE)):
            if extra is None:
                st.unknown_msgid += 1
            else:
                st.bad_crc += 1
            pos = end
            continue
        nxt = _find_magic(data, p + 1)
        if nxt < 0:
            st.garbage_bytes += n - pos
            pos = n
            break
        st.garbage_bytes += nxt - 8 - pos
        pos = nxt - 8
    else:
        if pos < n:
            st.truncated_tail_bytes += n - pos
    st.first_timestamp_us = first_ts
    st.last_timestamp_us = last_ts


def _plausible_record(data: bytes, start: int, n: int) -> bool:
    """A record fits in the file at ``start`` (used only to tell garbage from a cut-off tail)."""
    if start < 0:
        return False
    p = start + 8
    if data[p] == 0xFD:
        if p + 12 > n:
            return False
        end = p + 12 + data[p + 1] + (SIGNATURE_LEN if data[p + 2] & MAVLINK_IFLAG_SIGNED else 0)
    else:
        if p + 8 > n:
            return False
        end = p + 8 + data[p + 1]
    return end <= n


#: files up to this size keep their scan for the next reader (8 integers a record: a 100,000-message
#: tlog, 4.6 MB, keeps 6.4 MB); larger ones are streamed each time
SCAN_CACHE_MAX_BYTES = 64 * 1024 * 1024

Record = tuple[int, int, int, int, memoryview, int, int]
_COLUMNS = 8  # the fields of a record of _scan_records


@dataclass
class ScannedTlog:
    """One file read and scanned: its bytes, its records as integer columns, its stats.

    Columns, not a list of tuples: 100,000 records held as Python objects made every garbage
    collection of the process walk them (≈ 0.3 s of CPU over a replay), integer arrays are not
    tracked."""

    data: bytes
    columns: tuple[array, ...]  # timestamp_us, msgid, sysid, compid, payload start/end, packet start/end
    stats: ScanStats

    def __len__(self) -> int:
        return len(self.columns[0])

    def records(self, msgids=None) -> Iterator[Record]:
        """The records as :func:`scan_tlog_bytes` yields them; ``msgids``: only those messages'
        (picked from the message-id column at once, not record by record)."""
        mv = memoryview(self.data)
        columns = self.columns
        if msgids is not None:
            import numpy as np

            picked = np.flatnonzero(np.isin(np.frombuffer(columns[1], dtype=np.uint64), list(msgids))).tolist()
            columns = tuple([column[i] for i in picked] for column in columns)
        for ts, msgid, sysid, compid, payload_start, payload_end, start, end in zip(*columns):
            yield ts, msgid, sysid, compid, mv[payload_start:payload_end], start, end


_last_scan: tuple[tuple, ScannedTlog] | None = None


def _scan_key(path: Path) -> tuple | None:
    """What identifies a file's content for a kept scan (None: too large to keep)."""
    st = path.stat()
    if st.st_size > SCAN_CACHE_MAX_BYTES:
        return None
    return str(path.resolve()), st.st_size, st.st_mtime_ns, st.st_ino


def scanned_tlog(path: str | Path) -> ScannedTlog | None:
    """The file scanned and kept for the next reader (the previous call's scan when the file is the
    same: path, size, modification time, inode); None for a file above
    :data:`SCAN_CACHE_MAX_BYTES` (stream it with :func:`scan_tlog` instead). Only one is kept."""
    global _last_scan
    path = Path(path)
    key = _scan_key(path)
    if key is None:
        return None
    last = _last_scan
    if last is not None and last[0] == key:
        return last[1]
    data = path.read_bytes()
    scanned = _scan_flawless(data)
    if scanned is None:  # damage somewhere: the sequential scanner skips and counts it
        stats = ScanStats()
        flat = array("Q")  # all non-negative; a timestamp may use all 64 bits
        extend = flat.extend
        for record in _scan_records(data, stats):
            extend(record)
        scanned = ScannedTlog(data, tuple(flat[i::_COLUMNS] for i in range(_COLUMNS)), stats)
    _last_scan = (key, scanned)
    return scanned


def _crc_accumulate(crc, byte):
    """MAVLink's CRC-16/MCRF4XX step (``crc_accumulate``) over arrays of CRCs and bytes."""
    tmp = byte ^ (crc & 0xFF)
    tmp ^= (tmp << 4) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF


def _scan_flawless(data: bytes) -> ScannedTlog | None:
    """The scan of a tlog without a flaw — every record complete, of a known message, CRC-valid —
    with the headers and CRCs of all records computed at once (numpy); None at the first flaw, for
    the sequential scanner to skip and count the damage. On a flawless file the sequential scanner
    hands out exactly these records (it only moves from one good record to the next)."""
    import numpy as np

    n = len(data)
    starts = array("q")  # record starts
    append = starts.append
    pos = 0
    while pos + 9 <= n:  # walk the chain of records by their length bytes
        magic = data[pos + 8]
        if magic == 0xFD:
            if pos + 20 > n:
                return None
            end = pos + 20 + data[pos + 9] + (SIGNATURE_LEN if data[pos + 10] & MAVLINK_IFLAG_SIGNED else 0)
        elif magic == 0xFE:
            if pos + 16 > n:
                return None
            end = pos + 16 + data[pos + 9]
        else:
            return None
        append(pos)
        pos = end
    if pos != n or not starts:
        return None
    raw = np.frombuffer(data, dtype=np.uint8)
    record = np.frombuffer(starts, dtype=np.int64)
    p = record + 8  # packet starts

    def at(offset: int) -> np.ndarray:  # header byte per packet (clipped: v1 headers are shorter)
        return raw[np.minimum(p + offset, n - 1)].astype(np.int64)

    v2 = raw[p] == 0xFD
    header = np.where(v2, 10, 6)
    body_end = p + header + at(1)
    signed = v2 & ((at(2) & MAVLINK_IFLAG_SIGNED) != 0)
    msgid = np.where(v2, at(7) | (at(8) << 8) | (at(9) << 16), at(5))
    extras = _crc_extra_table()
    if msgid.max() >= extras.size:
        return None
    extra = extras[msgid]
    if (extra < 0).any():
        return None
    # the CRC over each packet's bytes after the magic, longest packets first so that the packets
    # still running at byte j are a prefix
    length = body_end - p - 1
    order = np.argsort(-length, kind="stable")
    first, length_sorted = p[order] + 1, length[order]
    crc = np.full(order.size, 0xFFFF, dtype=np.int64)
    running = np.searchsorted(-length_sorted, -np.arange(int(length_sorted[0])), side="left")  # length > j
    for j, k in enumerate(running.tolist()):
        crc[:k] = _crc_accumulate(crc[:k], raw[first[:k] + j])
    crc = _crc_accumulate(crc, extra[order])
    sent = raw[body_end[order]].astype(np.int64) | (raw[body_end[order] + 1].astype(np.int64) << 8)
    if (crc != sent).any():
        return None
    timestamp = raw[record[:, None] + np.arange(8)].view(">u8").ravel().astype(np.uint64)
    packet_end = body_end + 2 + np.where(signed, SIGNATURE_LEN, 0)
    columns = tuple(array("Q", column.astype(np.uint64).tobytes())
                    for column in (timestamp, msgid, np.where(v2, at(5), at(3)), np.where(v2, at(6), at(4)),
                                   p + header, body_end, p, packet_end))
    n_v2 = int(v2.sum())
    stats = ScanStats(records=int(record.size), mavlink1=int(record.size) - n_v2, mavlink2=n_v2,
                      signed=int(signed.sum()), first_timestamp_us=int(timestamp[0]),
                      last_timestamp_us=int(timestamp[-1]))
    return ScannedTlog(data, columns, stats)


_EXTRA_TABLE = None


def _crc_extra_table():
    """msgid -> CRC_EXTRA (-1: not in the dialect), as an array."""
    global _EXTRA_TABLE
    if _EXTRA_TABLE is None:
        import numpy as np

        table = np.full(max(CRC_EXTRA_BYTES) + 1, -1, dtype=np.int64)
        for msgid, extra in CRC_EXTRA_BYTES.items():
            table[msgid] = extra[0]
        _EXTRA_TABLE = table
    return _EXTRA_TABLE


def take_kept_scan(path: str | Path) -> ScannedTlog | None:
    """The scan :func:`scanned_tlog` kept of this file, handed over and no longer kept (the last
    reader, a replay, takes it); None when none is kept."""
    global _last_scan
    last, _last_scan = _last_scan, None
    if last is not None and last[0] == _scan_key(Path(path)):
        return last[1]
    return None


def scan_tlog(path: str | Path, stats: ScanStats | None = None) -> Iterator[tuple[int, int, int, int, memoryview, int, int]]:
    """:func:`scan_tlog_bytes` over a file (read whole: tlogs of a flight are megabytes)."""
    data = Path(path).read_bytes()
    yield from scan_tlog_bytes(data, stats)


def tlog_message_dicts(path: str | Path, names, *, system: int | None = None) -> Iterator[tuple[str, dict]]:
    """``(message name, fields)`` of the CRC-valid packets of the named messages, fields as
    pymavlink's ``msg.to_dict()`` gives them; only those messages are decoded (``system``: only
    from that system). Packets whose payload cannot be unpacked are skipped."""
    from gcs_pdm.mavlink.dialect import MESSAGE_IDS_BY_NAME

    wanted = {MESSAGE_IDS_BY_NAME[n]: layout(MESSAGE_IDS_BY_NAME[n]) for n in names}
    scanned = scanned_tlog(path)
    for _ts, msgid, sysid, _compid, payload, _start, _end in (scanned.records(wanted) if scanned else scan_tlog(path)):
        lay = wanted.get(msgid)
        if lay is None or (system is not None and sysid != system):
            continue
        try:
            fields = lay.as_dict(payload)
        except Exception:  # noqa: BLE001 - a CRC-valid packet that still does not unpack: skip it
            continue
        yield lay.name, fields


def tlog_message_columns(path: str | Path, name: str, *, system: int | None = None) -> dict:
    """One message's CRC-valid packets of a tlog as numpy columns, all at once: field -> array in
    file order (arrays ``(n, count)``; zero-truncated payloads padded with the zeros they dropped),
    plus ``"sysid"`` and ``"tlog_time_us"`` (each record's tlog timestamp). Numeric fields only (text fields are left out)."""
    import numpy as np

    from gcs_pdm.mavlink.dialect import MESSAGE_IDS_BY_NAME

    msgid = MESSAGE_IDS_BY_NAME[name]
    lay = layout(msgid)
    scanned = scanned_tlog(path)
    if scanned is not None:
        data, columns = scanned.data, [np.frombuffer(c, dtype=np.uint64) for c in scanned.columns]
    else:
        data = Path(path).read_bytes()
        rows = np.array(list(_scan_records(data, None)), dtype=np.uint64).reshape(-1, _COLUMNS)
        columns = list(rows.T)
    picked = columns[1] == msgid
    if system is not None:
        picked &= columns[2] == system
    sysid = columns[2][picked].astype(np.int64)
    rows = lay.unpack_many(np.frombuffer(data, dtype=np.uint8), columns[4][picked].astype(np.int64),
                           columns[5][picked].astype(np.int64))
    out = {"sysid": sysid, "tlog_time_us": columns[0][picked].astype(np.int64)}
    for field_name, (code, _repeat) in lay.codes.items():
        if code != "s":
            out[field_name] = np.ascontiguousarray(rows[field_name])
    return out
