"""Whether one sender is behind the vehicle's system and component id: MAVLink's sequence numbers.

Every MAVLink sender numbers its packets, one counter per link, modulo 256. From one sender the
step from a packet to the next is 1, or a little more when packets were lost; it is never
"backwards" (a step over 128, modulo 256) unless more than 128 packets in a row were lost. Two
senders using the same system and component id — a second vehicle or a simulator configured with
the same id, a replayed recording, a hostile sender — interleave two counters, and about every
other switch between them is a backward step. The mapping cannot tell their packets apart (the ids
are all it has), so the pack and ESC readings of both reach the estimator as one vehicle's; what
can be done is to say so: ``SequenceStats.verdict`` and a warning, live (``SequenceMonitor``, in the
link's ``trust_report``) and in a replay (``sequence_stats``, the summary's ``vehicle.sequence``).
A link that duplicates packets (two radios into one stream) looks the same: the verdict names both.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: out-of-sequence steps (backward, or a repeated number) as a share of the packets above which the
#: id is taken to have more than one sender, once there are at least MIN_PACKETS packets. One sender
#: on a lossy link gives none; two interleaved senders about one every other switch between them
SHARED_FRACTION = 0.05
MIN_PACKETS = 100
MAGIC_V2 = 0xFD


@dataclass
class SequenceStats:
    """One system/component id's packets: how many, how many a forward gap says were lost, and how
    many arrived out of sequence (a backward step or a repeated number)."""

    system: int
    component: int
    packets: int = 0
    lost: int = 0
    out_of_sequence: int = 0

    @property
    def shared(self) -> bool:
        return self.packets >= MIN_PACKETS and self.out_of_sequence > SHARED_FRACTION * self.packets

    @property
    def verdict(self) -> str:
        if self.packets < MIN_PACKETS:
            return f"too few packets to tell ({self.packets} of {MIN_PACKETS})"
        if self.shared:
            return (f"more than one sender uses system {self.system} component {self.component} (or the link "
                    f"duplicates packets): {self.out_of_sequence} of {self.packets} packets out of sequence; their "
                    f"readings are mixed as one vehicle's")
        return "one sender"

    def to_dict(self) -> dict:
        return {"system": self.system, "component": self.component, "packets": self.packets, "lost": self.lost,
                "out_of_sequence": self.out_of_sequence, "shared": self.shared, "verdict": self.verdict}


def _step_counts(steps: np.ndarray) -> tuple[int, int]:
    """(lost, out of sequence) from steps between consecutive sequence numbers, modulo 256."""
    forward = (steps >= 1) & (steps <= 128)
    return int(np.sum(steps[forward] - 1)), int(np.count_nonzero(~forward))


def sequence_stats(system: np.ndarray, component: np.ndarray, seq: np.ndarray, target: tuple[int, int]
                   ) -> SequenceStats:
    """The stats of id ``target`` over a log's packets (columns in log order)."""
    mine = (np.asarray(system) == target[0]) & (np.asarray(component) == target[1])
    s = np.asarray(seq, dtype=np.int64)[mine]
    lost, out = _step_counts(np.diff(s) % 256) if s.size > 1 else (0, 0)
    return SequenceStats(target[0], target[1], int(s.size), lost, out)


def scan_sequence_numbers(data: bytes, packet_starts) -> np.ndarray:
    """Each packet's sequence number, from its header in ``data`` (byte 4 in MAVLink 2, 2 in 1)."""
    buf = np.frombuffer(data, dtype=np.uint8)
    starts = np.frombuffer(packet_starts, dtype=np.uint64).astype(np.int64) if not isinstance(
        packet_starts, np.ndarray) else packet_starts.astype(np.int64)
    if starts.size == 0:
        return np.empty(0, dtype=np.int64)
    return buf[starts + np.where(buf[starts] == MAGIC_V2, 4, 2)].astype(np.int64)


class SequenceMonitor:
    """Per system/component id, live: each packet's sequence number against the previous one's;
    warns once per id when it looks shared."""

    def __init__(self):
        self._last: dict[tuple[int, int], int] = {}
        self._stats: dict[tuple[int, int], SequenceStats] = {}
        self._warned: set[tuple[int, int]] = set()

    def note(self, system: int, component: int, seq: int) -> None:
        key = (system, component)
        st = self._stats.get(key)
        if st is None:
            st = self._stats[key] = SequenceStats(system, component)
        last = self._last.get(key)
        self._last[key] = seq
        st.packets += 1
        if last is None:
            return
        step = (seq - last) % 256
        if 1 <= step <= 128:
            st.lost += step - 1
        else:
            st.out_of_sequence += 1
            if key not in self._warned and st.shared:
                self._warned.add(key)
                log.warning("%s", st.verdict)

    def stats(self, system: int | None, component: int | None) -> SequenceStats | None:
        return self._stats.get((system, component))
