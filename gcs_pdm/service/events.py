"""Live updates: an append-only ring of numbered events that any thread may publish to.

Readers (the SSE endpoint, the demo's terminal printer, tests) ask for "everything after seq N",
so a slow reader never blocks a publisher and a reconnecting SSE client resumes with
``Last-Event-ID``. Events carry both the wall time they were published at and, where there is
one, the vehicle's message time.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Event:
    seq: int
    kind: str  # fault, plan, upload, mission, job, status, link, statustext, policy
    data: dict[str, Any]
    wall_time: float = field(default_factory=time.time)

    def to_dict(self) -> dict[str, Any]:
        return {"seq": self.seq, "kind": self.kind, "wall_time": self.wall_time, "data": self.data}


class EventBus:
    def __init__(self, capacity: int = 2000):
        self._events: deque[Event] = deque(maxlen=capacity)
        self._cond = threading.Condition()
        self._seq = 0

    def publish(self, kind: str, /, **data: Any) -> Event:
        with self._cond:
            self._seq += 1
            ev = Event(self._seq, kind, data)
            self._events.append(ev)
            self._cond.notify_all()
        return ev

    @property
    def last_seq(self) -> int:
        return self._seq

    def since(self, seq: int, kinds: frozenset[str] | None = None) -> list[Event]:
        with self._cond:
            return [e for e in self._events if e.seq > seq and (kinds is None or e.kind in kinds)]

    def wait(self, seq: int, timeout: float) -> list[Event]:
        """Events after ``seq``, waiting up to ``timeout`` s for the first one."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._seq <= seq:
                left = deadline - time.monotonic()
                if left <= 0:
                    return []
                self._cond.wait(left)
            return [e for e in self._events if e.seq > seq]
