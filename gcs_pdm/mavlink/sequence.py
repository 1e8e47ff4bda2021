"""Whether one sender is behind the vehicle's system and component id: MAVLink's sequence numbers.

Every MAVLink sender numbers its packets, one counter per link, modulo 256. From one sender the
step from a packet to the next is 1, or a little more when packets were lost; it is never
"backwards" (a step over 128, modulo 256) unless more than 128 packets in a row were lost. Two
senders using the same system and component id — a second vehicle or a simulator configured with
the same id, a replayed recording, a hostile sender — interleave two counters, and about every
other switch between them is a backward step. The mapping cannot tell their packets apart (the ids
are all it has), so the pack and ESC readings of both reach the estimator as one vehicle's; what
can be done is to say so: live (``SequenceMonitor``, in the link's ``trust_report``) and in a replay
(``sequence_stats``, the summary's ``vehicle.sequence``), with a warning. A link that duplicates
packets (two radios into one stream) looks the same: the verdict names both.

The test runs over the last ``WINDOW`` steps, so a second sender that starts late in a long session
is not diluted by the hours before it: ``shared_now`` is the latest window's verdict (what the
operator's console shows), ``shared`` whether any window so far was.
"""
from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np

from gcs_pdm.mavlink.wire import MAGIC_V2, SEQ_AT_V1, SEQ_AT_V2

log = logging.getLogger(__name__)

#: steps (consecutive packets of one id) per test window, and the share of them out of sequence
#: (backward, or a repeated number) above which the id is taken to have more than one sender. One
#: sender on a lossy link gives none; two interleaved senders about one every other switch
WINDOW = 500
SHARED_FRACTION = 0.05
#: a window is judged once it holds this many steps
MIN_STEPS = 100
#: the largest step from one sender's packet to its next (modulo 256) read as packets lost, not as a
#: step back: half the counter's range
MAX_FORWARD_STEP = 128


def _shared(out: int, steps: int) -> bool:
    return steps >= MIN_STEPS and out > SHARED_FRACTION * steps


@dataclass
class SequenceStats:
    """One system/component id's packets: how many, how many a forward gap says were lost, how many
    arrived out of sequence (a backward step or a repeated number), and the same in the latest
    window of steps and in the worst one."""

    system: int
    component: int
    packets: int = 0
    lost: int = 0
    out_of_sequence: int = 0
    window_steps: int = 0  # steps in the latest window (up to WINDOW)
    window_out: int = 0  # of them out of sequence
    shared_before: bool = False  # whether any window so far (judged: MIN_STEPS or more) looked shared

    @property
    def shared_now(self) -> bool:
        return _shared(self.window_out, self.window_steps)

    @property
    def shared(self) -> bool:
        return self.shared_now or self.shared_before

    @property
    def verdict(self) -> str:
        if self.packets <= MIN_STEPS and not self.shared:
            return f"too few packets to tell ({self.packets} of {MIN_STEPS + 1})"
        if not self.shared:
            return "one sender"
        now = (f"now {self.window_out} of the last {self.window_steps} packets out of sequence" if self.shared_now
               else f"earlier, not in the last {self.window_steps} packets")
        return (f"more than one sender uses system {self.system} component {self.component} (or the link "
                f"duplicates packets): {now}; their readings are mixed as one vehicle's")

    def to_dict(self) -> dict:
        return {"system": self.system, "component": self.component, "packets": self.packets, "lost": self.lost,
                "out_of_sequence": self.out_of_sequence, "window": {"steps": self.window_steps, "out": self.window_out},
                "shared_now": self.shared_now, "shared": self.shared, "verdict": self.verdict}


def sequence_stats(system: np.ndarray, component: np.ndarray, seq: np.ndarray, target: tuple[int, int]
                   ) -> SequenceStats:
    """The stats of id ``target`` over a log's packets (columns in log order), as
    ``SequenceMonitor`` would leave them at the log's end."""
    mine = (np.asarray(system) == target[0]) & (np.asarray(component) == target[1])
    s = np.asarray(seq, dtype=np.int64)[mine]
    st = SequenceStats(target[0], target[1], int(s.size))
    if s.size < 2:
        return st
    steps = np.diff(s) % 256
    forward = (steps >= 1) & (steps <= MAX_FORWARD_STEP)
    out = ~forward
    st.lost = int(np.sum(steps[forward] - 1))
    st.out_of_sequence = int(np.count_nonzero(out))
    tail = out[-WINDOW:]
    st.window_steps, st.window_out = int(tail.size), int(np.count_nonzero(tail))
    # every window the live monitor judged after a step: the growing first ones (MIN_STEPS to WINDOW
    # steps), then each full one, from the running sum of the out-of-sequence flags
    cs = np.concatenate([[0], np.cumsum(out)])
    n = np.arange(1, out.size + 1)
    counts = np.where(n <= WINDOW, cs[1:], cs[1:] - cs[np.maximum(n - WINDOW, 0)])
    lengths = np.minimum(n, WINDOW)
    st.shared_before = bool(np.any((lengths >= MIN_STEPS) & (counts > SHARED_FRACTION * lengths)))
    return st


def scan_sequence_numbers(data: bytes, packet_starts) -> np.ndarray:
    """Each packet's sequence number, from its header in ``data`` (``wire.split_packet``'s ``seq``, for
    a whole log at once)."""
    buf = np.frombuffer(data, dtype=np.uint8)
    starts = (packet_starts if isinstance(packet_starts, np.ndarray)
              else np.frombuffer(packet_starts, dtype=np.uint64)).astype(np.int64)
    if starts.size == 0:
        return np.empty(0, dtype=np.int64)
    return buf[starts + np.where(buf[starts] == MAGIC_V2, SEQ_AT_V2, SEQ_AT_V1)].astype(np.int64)


class SequenceMonitor:
    """Per system/component id, live: each packet's sequence number against the previous one's,
    over a window of the latest ``WINDOW`` steps; warns once per id when it looks shared."""

    def __init__(self):
        self._last: dict[tuple[int, int], int] = {}
        self._stats: dict[tuple[int, int], SequenceStats] = {}
        self._windows: dict[tuple[int, int], deque] = {}
        self._warned: set[tuple[int, int]] = set()

    def note(self, system: int, component: int, seq: int) -> None:
        key = (system, component)
        st = self._stats.get(key)
        if st is None:
            st = self._stats[key] = SequenceStats(system, component)
            self._windows[key] = deque(maxlen=WINDOW)
        last = self._last.get(key)
        self._last[key] = seq
        st.packets += 1
        if last is None:
            return
        step = (seq - last) % 256
        out = not 1 <= step <= MAX_FORWARD_STEP
        if out:
            st.out_of_sequence += 1
        else:
            st.lost += step - 1
        window = self._windows[key]
        if len(window) == WINDOW:
            st.window_out -= window[0]
        window.append(out)
        st.window_out += out
        st.window_steps = len(window)
        if st.shared_now:
            st.shared_before = True
            if key not in self._warned:
                self._warned.add(key)
                log.warning("%s", st.verdict)

    def last_seq(self, system: int, component: int) -> int | None:
        """The sequence number of the id's latest packet (None before its first)."""
        return self._last.get((system, component))

    def stats(self, system: int | None, component: int | None) -> SequenceStats | None:
        return self._stats.get((system, component))
