"""A scanned tlog's frames a message type at a time: the replay's columnar twin of ``FrameMapper.feed``.

The live link maps each packet as it comes (``FrameMapper.feed``). A replay has the whole log,
scanned into integer columns (``gcs_pdm.mavlink.tlog.ScannedTlog``), so once the mapper is
*settled* — vehicle identified, clock giving times, no frame held back — :func:`map_scanned`
maps the rest of the log with numpy instead of a Python call per message:

1. whose messages (the vehicle's; the others counted, foreign autopilot heartbeats recorded),
   and their times: the ``time_boot_ms`` of all timed messages at once through the clock
   (``VehicleClock.on_time_boots``: runs of consistent samples at once, any other sample
   through the clock's own rules), untimed messages "hold last" by a search in that column;
2. per mapped message type, every payload decoded at once (``PayloadLayout.unpack_many``), each
   rule's match, key, field conversions, sums, transforms and plausibility gate applied to whole
   columns, exactly as the compiled per-message builders do them (same operations in the same
   order on float64, so the same values and Python types);
3. the frames made from the columns (``tolist()`` then the frame classes' constructors), merged
   back into log order, a chunk of messages at a time: the values stay numpy arrays until their
   chunk is made, and a chunk's frames die young (memory and garbage collections bounded).

A message type whose rules this module does not reproduce exactly — a 64-bit integer field, a
float key, a sum over integer and float fields together, a transform or text under the gate, a gate
that depends on a message field — goes through the mapper's own compiled builder, message by
message, in the same merge. Frames, their order and every counter are the per-message path's
(``tests/test_frame_columns.py`` holds the two equal on real, fixture and damaged logs).
"""
from __future__ import annotations

import operator
from dataclasses import dataclass, fields
from typing import Iterator

import numpy as np

from gcs_pdm.mavlink.mapping import Constant, FieldRule, FrameMapper, _HEARTBEAT, _matches, conversion

#: messages per chunk of frames made and handed out: its frames die young (a larger chunk keeps
#: more frames alive through collections; 512 measured as fast as no collector at all)
CHUNK_MESSAGES = 512

_INTEGER_CODES = frozenset("bBhHiI")  # exact in float64, as Python's comparisons of these ints are
_FLOAT_CODES = frozenset("fd")
_EXACT_IN_FLOAT = 2 ** 53  # integers below this convert to float64 exactly


class _PerMessage(Exception):
    """A rule of a message type this module does not reproduce: map that type message by message."""


class _Same:
    """A constructor argument every frame of a stream gets alike (a key name, None)."""

    def __init__(self, value):
        self.value = value

    def take(self, lo: int, hi: int) -> list:
        return [self.value] * (hi - lo)


class _Listed:
    """A constructor argument as Python objects already (text, a transform's results, frames)."""

    def __init__(self, values: list):
        self.values = values

    def take(self, lo: int, hi: int) -> list:
        return self.values[lo:hi]


class _Numbers:
    """A numeric constructor argument, kept as an array until its chunk is made (Python floats for a
    whole log would hold 32 bytes a value); ``absent``: where the frame gets None (or None: nowhere)."""

    def __init__(self, values: np.ndarray, absent: np.ndarray | None = None):
        self.values = values
        self.absent = absent if absent is not None and absent.any() else None

    def take(self, lo: int, hi: int) -> list:
        listed = self.values[lo:hi].tolist()
        if self.absent is not None:
            for j in np.flatnonzero(self.absent[lo:hi]).tolist():
                listed[j] = None
        return listed


@dataclass
class _Stream:
    """Frames of one source in log order: ``keys`` (message index × slots + the frame's place in
    its message's output) and either a frame class with its constructor arguments (``_Same``,
    ``_Listed``, ``_Numbers``), or (``cls`` None) the frames themselves, ``_Listed`` in ``args[0]``."""

    keys: np.ndarray
    cls: type | None
    args: list
    times: np.ndarray  # each frame's time_s (float64), to pass over frames without making them

    def frame(self, i: int):
        """Frame ``i`` of the stream alone (the values its chunk would make)."""
        if self.cls is None:
            return self.args[0].values[i]
        return self.cls(*(arg.take(i, i + 1)[0] for arg in self.args))


def map_scanned(mapper: FrameMapper, data: bytes, columns, start: int) -> Iterator[list]:
    """The frames of records ``start:`` of a scanned tlog (``columns``: :attr:`ScannedTlog.columns`
    of ``data``) as lists in log order, a chunk of messages at a time: what feeding each record to
    ``mapper.feed_from`` would give, leaving the mapper's counters, clock and foreign systems as
    that would. The mapper must be :meth:`~FrameMapper.settled`."""
    yield from _merged(*_streams(mapper, data, columns, start))


def map_scanned_for(mapper: FrameMapper, data: bytes, columns, start: int, consumed: frozenset) -> Iterator["Chunk"]:
    """:func:`map_scanned` for a consumer of the frame types ``consumed`` alone: a :class:`Chunk`
    at a time, whose frames of other types are passed over (their times and counts kept, each made
    only if asked for). The mapper's counters, clock and foreign systems are :func:`map_scanned`'s."""
    streams, n, slots = _streams(mapper, data, columns, start)
    yield from _chunks(streams, n, slots, consumed)


def _streams(mapper: FrameMapper, data: bytes, columns, start: int) -> tuple[list["_Stream"], int, int]:
    """The streams of frames of records ``start:`` (see :func:`map_scanned`), the number of records
    and the key slots per record; every counter of the mapper updated."""
    if not mapper.settled():
        raise ValueError("map_scanned needs a settled mapper (vehicle identified, clock running, nothing held)")
    column = [np.frombuffer(c, dtype=np.uint64)[start:] for c in columns[:6]]
    n = column[0].size
    if n == 0:
        return [], 0, 1
    msgid = column[1].astype(np.int64)
    sysid = column[2].astype(np.int64)
    payload_start, payload_end = column[4].astype(np.int64), column[5].astype(np.int64)
    recv = _receive_seconds(column[0])
    raw = np.frombuffer(data, dtype=np.uint8)
    stats, clock = mapper.stats, mapper.clock
    ours = (sysid == mapper.target_system) & (column[3] == mapper.target_component)
    stats.other_source += n - int(np.count_nonzero(ours))
    plans = {m: mapper.dispatch[m] for m in np.unique(msgid[ours]).tolist() if m in mapper.dispatch}

    # message times: timed messages through the clock, untimed ones "hold last" (or receive time)
    timed = np.flatnonzero(ours & np.isin(msgid, [m for m, p in plans.items() if p.time_offset is not None]))
    vehicle_time = not clock.fallback  # else receive time for good
    now_before_run = clock.now
    if vehicle_time:
        boot = _time_boot_s(raw, msgid[timed], payload_start[timed], payload_end[timed], plans)
        timed_t, accepted = clock.on_time_boots(boot, recv[timed], msgid[timed])
        now_after = np.maximum(now_before_run, np.maximum.accumulate(np.where(accepted, timed_t, -np.inf)))
        stats.time_rejected += timed.size - int(np.count_nonzero(accepted))
    else:  # receive time for good, under the clock's jump rules: every vehicle message passes, in order
        fed = np.flatnonzero(ours)
        fed_t, fed_ok = clock.receive_times(recv[fed], msgid[fed])
        stats.time_rejected += fed.size - int(np.count_nonzero(fed_ok))
        received_t, received_ok = np.full(n, np.nan), np.zeros(n, dtype=bool)
        received_t[fed], received_ok[fed] = fed_t, fed_ok
        timed_t, accepted = received_t[timed], received_ok[timed]

    def now_at(positions: np.ndarray) -> np.ndarray:
        """The clock's time when each of these messages arrived (after the timed ones before it)."""
        if not timed.size:
            return np.full(positions.size, now_before_run)
        before = np.searchsorted(timed, positions) - 1
        return np.where(before >= 0, now_after[np.maximum(before, 0)], now_before_run)

    foreign = np.flatnonzero(~ours & (msgid == _HEARTBEAT) & (sysid != mapper.target_system))
    if foreign.size:
        nows = now_at(foreign).tolist() if vehicle_time else [clock.now] * foreign.size
        for p, now in zip(foreign.tolist(), nows):
            mapper._note_foreign(int(sysid[p]), int(column[3][p]), data[int(payload_start[p]):int(payload_end[p])], now)

    times = np.full(n, np.nan)
    usable = np.zeros(n, dtype=bool)
    times[timed] = timed_t
    usable[timed[accepted]] = True
    untimed = np.flatnonzero(ours & np.isin(msgid, [m for m, p in plans.items()
                                                     if p.time_offset is None and p.emit is not None]))
    if vehicle_time:
        times[untimed], usable[untimed] = now_at(untimed), True
    else:
        times[untimed], usable[untimed] = received_t[untimed], received_ok[untimed]

    mapped = {m: p for m, p in plans.items() if p.emit is not None}
    slots = 1 + max((sum(len(r.instances) for r in p.rules) for p in mapped.values()), default=0)
    streams: list[_Stream] = []
    for m, plan in mapped.items():
        positions = np.flatnonzero(usable & (msgid == m))
        if not positions.size:
            continue
        try:
            _check_columnar(plan, mapper.gate is not None)
        except _PerMessage:
            streams.append(_message_by_message(mapper, plan, positions, times[positions], data,
                                               payload_start, payload_end, slots))
            continue
        rows = plan.layout.unpack_many(raw, payload_start[positions], payload_end[positions])
        with np.errstate(all="ignore"):  # NaN, inf and overflow are values here, as in Python's floats
            streams += _type_streams(mapper, plan, rows, positions, times[positions], slots)
    return streams, n, slots


def _receive_seconds(stamp_us: np.ndarray) -> np.ndarray:
    """``ts_us / 1e6`` of each record as the per-message replay computes it (a stamp beyond 2**53 µs,
    a damaged one, converted by Python's own rounding)."""
    recv = stamp_us.astype(np.float64) / 1e6
    big = np.flatnonzero(stamp_us >= _EXACT_IN_FLOAT)
    if big.size:
        recv[big] = [int(us) / 1e6 for us in stamp_us[big].tolist()]
    return recv


def _time_boot_s(raw: np.ndarray, msgid: np.ndarray, start: np.ndarray, end: np.ndarray, plans: dict) -> np.ndarray:
    """Each message's ``time_boot_ms`` in seconds; the bytes a zero-truncated payload dropped are zeros."""
    offset = np.zeros(msgid.size, dtype=np.int64)
    for m, plan in plans.items():
        if plan.time_offset is not None:
            offset[msgid == m] = plan.time_offset
    at = start + offset
    value = np.zeros(msgid.size, dtype=np.int64)
    for k in range(4):
        inside = at + k < end
        value |= np.where(inside, raw[np.where(inside, at + k, 0)], 0).astype(np.int64) << (8 * k)
    return value / 1000.0


def _code(lay, position: int) -> str:
    try:
        return lay.field_at(position)[2]
    except IndexError:  # a spec pointing past the payload: the per-message builder raises as it always did
        raise _PerMessage from None


def _check_columnar(plan, gated: bool) -> None:
    """Raise :class:`_PerMessage` if a rule of this message type is not reproduced here exactly."""
    lay = plan.layout
    for rule in plan.rules:
        for position, _wanted in rule.match:
            _code(lay, position)
        if rule.key_position is not None and _code(lay, rule.key_position) not in _INTEGER_CODES:
            raise _PerMessage  # float keys (NaN is its own key) and 64-bit ones
        names = [f.name for f in fields(rule.frame_cls)][1:]
        for inst in rule.instances:
            if gated and inst.checks is None:
                raise _PerMessage  # the gate's range depends on a field of the message
            checked = {name for name, _low, _high in inst.checks or ()}
            for name, source in zip(names, inst.sources):
                if isinstance(source, Constant):
                    if name in checked and source.value is not None:
                        raise _PerMessage
                    continue
                if not all(isinstance(v, (int, float)) and abs(v) < _EXACT_IN_FLOAT for v in source.missing):
                    raise _PerMessage  # compared as float64 here, exactly in Python
                if source.how == "field":
                    if _code(lay, source.position) not in _INTEGER_CODES | _FLOAT_CODES:
                        raise _PerMessage
                elif source.how == "sum":
                    codes = {_code(lay, p) for a, b in source.spans for p in range(a, b)}
                    if not (codes <= _INTEGER_CODES or codes <= _FLOAT_CODES):
                        raise _PerMessage  # the per-message sum changes type midway
                elif name in checked:  # text and transforms are not numbers to gate
                    raise _PerMessage
                elif source.how == "text" and _code(lay, source.position) != "s":
                    raise _PerMessage
                elif source.how == "transform" and any(_code(lay, p) not in _INTEGER_CODES for _n, p in source.needed):
                    raise _PerMessage


def _column(rows: np.ndarray, lay, position: int) -> np.ndarray:
    """The values at one position of the unpacked tuple, for every row: integers as int64 and
    floats as float64 (what Python compares and computes them as), text as bytes."""
    name, element, code = lay.field_at(position)
    values = rows[name] if element is None else rows[name][:, element]
    if code in _INTEGER_CODES:
        return values.astype(np.int64)
    if code in _FLOAT_CODES:
        return values.astype(np.float64)
    return values


def _type_streams(mapper: FrameMapper, plan, rows: np.ndarray, positions: np.ndarray, times: np.ndarray,
                  slots: int) -> list[_Stream]:
    """The frames every rule of one message type makes from its decoded ``rows`` (at ``positions``
    of the log, message times ``times``), as streams; the mapper's counters updated."""
    lay, stats = plan.layout, mapper.stats
    gated_counts = mapper.gate.gated if mapper.gate is not None else None  # the counter the rules' gate keeps
    out = []
    slot = 0
    for rule in plan.rules:
        chosen = np.ones(rows.size, dtype=bool)
        for position, wanted in rule.match:
            values = _column(rows, lay, position)
            matching = [v for v in np.unique(values).tolist() if _matches(v, wanted)]
            chosen &= np.isin(values, matching)
        if rule.key_position is None:
            groups = [(chosen, rule.instances)]
        else:
            key = _column(rows, lay, rule.key_position).astype(np.int64)
            groups, keyed = [], np.zeros(rows.size, dtype=bool)
            for raw_key, instances in rule.by_key.items():
                hit = chosen & (key == raw_key)
                keyed |= hit
                groups.append((hit, instances))
            for value, count in zip(*(c.tolist() for c in np.unique(key[chosen & ~keyed], return_counts=True))):
                stats.unmapped_keys[(lay.name, value)] += count
        place = {id(inst): slot + j for j, inst in enumerate(rule.instances)}
        slot += len(rule.instances)
        for hit, instances in groups:
            index = np.flatnonzero(hit)
            if not index.size:
                continue
            for inst in instances:
                args = _instance_columns(lay, gated_counts, rule, inst, rows[index])
                out.append(_Stream(positions[index] * slots + place[id(inst)], rule.frame_cls,
                                   [_Numbers(times[index]), *args], times[index]))
                stats.frames_by_kind[rule.kind] += index.size
    return out


def _instance_columns(lay, gated_counts, rule, inst, rows: np.ndarray) -> list:
    """The constructor arguments after ``time_s`` of one rule instance's frames from its ``rows``,
    gated as the instance's ``make`` gates them (``gated_counts``: the gate's counter)."""
    names = [f.name for f in fields(rule.frame_cls)][1:]
    args: list = []
    numbers: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # field -> (values, absent), to gate
    for name, source in zip(names, inst.sources):
        if isinstance(source, Constant):
            args.append(_Same(source.value))
        elif source.how == "text":
            args.append(_Listed([b.split(b"\0", 1)[0].decode("utf-8", "replace")
                                 for b in _column(rows, lay, source.position).tolist()]))
        elif source.how == "transform":
            args.append(_Listed(_transformed(rows, lay, source)))
        else:
            numbers[name] = _numbers(rows, lay, source)
            args.append(name)  # filled in after the gate
    for name, low, high in inst.checks or ():
        if name not in numbers:
            continue  # a field the rule leaves None
        values, absent = numbers[name]
        fails = ~absent & ~((low <= values) & (values <= high))  # NaN fails, as in the gate
        if fails.any():
            bad = values[fails]
            finite = np.isfinite(bad)
            below = int(np.count_nonzero(finite & (bad < low)))
            for reason, count in (("not_finite", bad.size - int(np.count_nonzero(finite))), ("below_range", below),
                                  ("above_range", int(np.count_nonzero(finite)) - below)):
                if count:
                    gated_counts[(rule.kind, name, reason)] += count
            numbers[name] = (values, absent | fails)
    for i, name in enumerate(names):
        if name in numbers:
            args[i] = _Numbers(*numbers[name])
    return args


def _numbers(rows: np.ndarray, lay, source: FieldRule) -> tuple[np.ndarray, np.ndarray]:
    """A field's or a sum's converted values and where they are "not available" (the per-message
    builder's None): the raw values in ``missing``, NaN, a sum with nothing to add."""
    missing = list(source.missing)
    if source.how == "field":
        raw = _column(rows, lay, source.position)
        absent = np.isin(raw, missing) if missing else np.zeros(raw.size, dtype=bool)
        if raw.dtype.kind == "f":
            absent |= np.isnan(raw)
    else:  # a sum, element by element in the builder's order (float addition is not associative)
        parts = [_column(rows, lay, p) for a, b in source.spans for p in range(a, b)]
        floats = any(part.dtype.kind == "f" for part in parts)
        raw = np.zeros(rows.size, dtype=np.float64 if floats else np.int64)
        seen = np.zeros(rows.size, dtype=bool)
        for part in parts:
            counted = ~np.isin(part, missing) if missing else np.ones(part.size, dtype=bool)
            raw = raw + np.where(counted, part, 0)
            seen |= counted
        absent = ~seen
    how = conversion(source.scale, source.offset)
    if how[0] == "divide":
        return raw.astype(np.float64) / how[1] + how[2], absent
    if how[0] == "multiply":
        return raw.astype(np.float64) * how[1] + how[2], absent
    return raw, absent


def _transformed(rows: np.ndarray, lay, source: FieldRule) -> list:
    """A named transform of each row: called once per distinct input (transforms are functions of
    their fields), its result handed to every row with that input."""
    inputs = np.stack([_column(rows, lay, p).astype(np.int64) for _name, p in source.needed], axis=1)
    distinct, which = np.unique(inputs, axis=0, return_inverse=True)
    results = [source.fn(dict(zip((name for name, _p in source.needed), row))) for row in distinct.tolist()]
    return [results[i] for i in which.reshape(-1).tolist()]


def _message_by_message(mapper: FrameMapper, plan, positions: np.ndarray, times: np.ndarray, data: bytes,
                        payload_start: np.ndarray, payload_end: np.ndarray, slots: int) -> _Stream:
    """One message type's frames by the mapper's own compiled builder, a message at a time (as
    ``feed_from`` makes them, counters included)."""
    frames, keys = [], []
    emit = plan.emit
    for p, t, a, b in zip(positions.tolist(), times.tolist(), payload_start[positions].tolist(),
                          payload_end[positions].tolist()):
        try:
            values = plan.values(data, a, b)
        except Exception:  # noqa: BLE001 - a bad payload is counted, never fatal (as in feed_from)
            mapper.stats.undecodable += 1
            continue
        made = emit(t, values)
        frames += made
        keys += range(p * slots, p * slots + len(made))
    return _Stream(np.array(keys, dtype=np.int64), None, [_Listed(frames)],
                   np.array([f.time_s for f in frames], dtype=np.float64))


def _merged(streams: list[_Stream], n: int, slots: int) -> Iterator[list]:
    """The streams' frames in log order (by key), made and handed out a chunk of messages at a time."""
    for frames, _keys in _merged_with_keys(streams, np.arange(0, n + CHUNK_MESSAGES, CHUNK_MESSAGES) * slots):
        if frames:
            yield frames

class Chunk:
    """A chunk of messages' frames for a consumer of some frame types (:func:`map_scanned_for`).

    ``frames``: the consumed types' frames in log order. The other ``passed`` frames are passed
    over: the chunk keeps their times in log order (``passed_times``) and makes one only when
    asked (:meth:`passed_frame`). Gap ``g`` (0 … ``len(frames)``) holds the passed-over frames
    between ``frames[g - 1]`` and ``frames[g]``: ``passed_times[gap_start[g]:gap_start[g + 1]]``,
    the latest of them ``latest_in_gap[g]`` (-inf: none; NaN times never count, as ``t >= x`` is
    False for them). ``first_time_s`` / ``last_time_s``: the times of the chunk's first and last
    frames, whatever their type."""

    __slots__ = ("frames", "passed", "first_time_s", "last_time_s", "passed_times", "_gap", "_streams", "_source",
                 "_offset", "_gap_start", "_latest")

    def __init__(self, frames: list, first_time_s: float, last_time_s: float, passed_times: np.ndarray,
                 gap: np.ndarray, streams: list, source: np.ndarray, offset: np.ndarray):
        self.frames = frames
        self.passed = int(passed_times.size)
        self.first_time_s, self.last_time_s = first_time_s, last_time_s
        self.passed_times = passed_times
        self._gap, self._streams, self._source, self._offset = gap, streams, source, offset
        self._gap_start = self._latest = None

    @property
    def gap_start(self) -> list[int]:
        if self._gap_start is None:
            self._gap_start = np.searchsorted(self._gap, np.arange(len(self.frames) + 2)).tolist()
        return self._gap_start

    @property
    def latest_in_gap(self) -> list[float]:
        if self._latest is None:
            latest = np.full(len(self.frames) + 1, -np.inf)
            if self.passed:
                gaps, first = np.unique(self._gap, return_index=True)
                found = np.fmax.reduceat(self.passed_times, first)
                latest[gaps] = np.where(np.isnan(found), -np.inf, found)
            self._latest = latest.tolist()
        return self._latest

    def passed_frame(self, j: int):
        """The ``j``-th passed-over frame of the chunk, made: the frame :func:`map_scanned` makes."""
        return self._streams[int(self._source[j])].frame(int(self._offset[j]))


def _chunks(streams: list[_Stream], n: int, slots: int, consumed: frozenset) -> Iterator[Chunk]:
    """:func:`_merged` for a consumer of the ``consumed`` frame types: the others' frames passed over."""
    wanted, others = [], []
    for s in streams:
        if s.cls is not None:
            (wanted if s.cls in consumed else others).append(s)
        else:  # frames made message by message: split by their types
            frames = s.args[0].values
            take = np.array([type(f) in consumed for f in frames], dtype=bool)
            for part, into in ((take, wanted), (~take, others)):
                if part.any():
                    index = np.flatnonzero(part)
                    into.append(_Stream(s.keys[index], None, [_Listed([frames[i] for i in index.tolist()])],
                                        s.times[index]))
    edges = np.arange(0, n + CHUNK_MESSAGES, CHUNK_MESSAGES) * slots
    other_bounds = [np.searchsorted(s.keys, edges).tolist() for s in others]
    no_times, no_index = np.empty(0), np.empty(0, dtype=np.int64)
    for c, (frames, keys) in enumerate(_merged_with_keys(wanted, edges)):
        passed_keys, passed_times, source, offset = [], [], [], []
        for k, (s, bound) in enumerate(zip(others, other_bounds)):
            lo, hi = bound[c], bound[c + 1]
            if hi > lo:
                passed_keys.append(s.keys[lo:hi])
                passed_times.append(s.times[lo:hi])
                source.append(np.full(hi - lo, k))
                offset.append(np.arange(lo, hi))
        if not passed_keys:
            if frames:
                yield Chunk(frames, frames[0].time_s, frames[-1].time_s, no_times, no_index, others, no_index, no_index)
            continue
        passed_key = np.concatenate(passed_keys)
        order = np.argsort(passed_key, kind="stable")
        passed_key, times = passed_key[order], np.concatenate(passed_times)[order]
        first = frames[0].time_s if frames and keys[0] < passed_key[0] else float(times[0])
        last = frames[-1].time_s if frames and keys[-1] > passed_key[-1] else float(times[-1])
        yield Chunk(frames, first, last, times, np.searchsorted(keys, passed_key), others,
                    np.concatenate(source)[order], np.concatenate(offset)[order])


def _merged_with_keys(streams: list[_Stream], edges: np.ndarray) -> Iterator[tuple[list, np.ndarray]]:
    """Per chunk (between ``edges`` of keys), the streams' frames in log order and their keys."""
    bounds = [np.searchsorted(s.keys, edges).tolist() for s in streams]
    for c in range(len(edges) - 1):
        parts, keys = [], []
        for s, bound in zip(streams, bounds):
            lo, hi = bound[c], bound[c + 1]
            if hi > lo:
                parts.append(list(map(s.cls, *(arg.take(lo, hi) for arg in s.args))) if s.cls is not None
                             else s.args[0].take(lo, hi))
                keys.append(s.keys[lo:hi])
        if len(parts) == 1:
            yield parts[0], keys[0]
        elif parts:
            key = np.concatenate(keys)
            order = np.argsort(key, kind="stable")
            yield list(operator.itemgetter(*order.tolist())([f for part in parts for f in part])), key[order]
        else:
            yield [], np.empty(0, dtype=np.int64)
