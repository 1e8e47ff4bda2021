"""When to (re)read the vehicle's mission: a pure component fed with messages and message time.

The vehicle's mission changes under the service's feet: an operator uploads one from the ground
station, the vehicle sets home (ArduPilot replaces item 0 then, and answers a read before home
with 0 items), or a read fails. :class:`MissionWatcher` sees the vehicle's messages and says when
a read is due and why; the shell (the live loop) does the read with the mission client and
reports back with :meth:`read_done` / :meth:`read_failed`. It reads:

* once when the vehicle is first heard (HEARTBEAT from an autopilot);
* when home is set (first HOME_POSITION, or one that moved), so item 0 and a mission loaded before
  boot are seen as the vehicle holds them;
* when the vehicle says its mission changed: MISSION_CURRENT's ``mission_id`` (MAVLink 2023+,
  PX4's CRC of the mission) or ``total`` changed, a MISSION_CHANGED (where the dialect has it) not
  caused by us, a MISSION_ACK(ACCEPTED) the vehicle sends to another GCS (its upload finished), or
  a MISSION_COUNT the vehicle sends that differs from the count we hold;
* again after ``empty_retry_s`` while a read returned 0 items and home is not yet set, and after
  ``failed_retry_s`` (doubling up to ``max_retry_s``) when a read failed.

A change seen while a read is running makes another read due once it ends (the read may have
caught the old mission). After the service's own upload, :meth:`uploaded` records the new count
and the next new mission id is adopted without a read.
"""
from __future__ import annotations

from dataclasses import dataclass

MAV_AUTOPILOT_INVALID = 8
MAV_MISSION_ACCEPTED = 0
MAV_MISSION_TYPE_MISSION = 0
NO_MISSION_TOTAL = 0xFFFF  # MISSION_CURRENT.total when the vehicle has no mission (PX4)


@dataclass(frozen=True)
class ReadDue:
    reason: str
    since_s: float


class MissionWatcher:
    def __init__(self, own_system: int = 255, own_component: int = 190, *, empty_retry_s: float = 3.0,
                 failed_retry_s: float = 2.0, max_retry_s: float = 30.0, home_moved_m: float = 1.0):
        self.own = (own_system, own_component)
        self.empty_retry_s = empty_retry_s
        self.failed_retry_s = failed_retry_s
        self.max_retry_s = max_retry_s
        self.home_moved_e7 = home_moved_m / 0.0111  # 1e-7 deg of latitude is ~1.11 cm
        self.vehicle_address: tuple[int, int] | None = None
        self.autopilot: int | None = None
        self.vehicle_type: int | None = None
        self.home: tuple[int, int] | None = None
        self.count: int | None = None  # items in the last mission read (or uploaded)
        self.mission_id: int | None = None
        self.total: int | None = None
        self.reading = False
        self._due: ReadDue | None = None
        self._due_is_retry = False
        self._not_before = 0.0
        self._failures = 0
        self._adopt_next_id = False

    # --- messages ------------------------------------------------------------------------------

    def on_message(self, msg, time_s: float) -> None:
        handler = self._HANDLERS.get(msg.get_type())
        if handler is not None:
            handler(self, msg, time_s)

    def _from_vehicle(self, msg) -> bool:
        return self.vehicle_address is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == self.vehicle_address

    def _on_heartbeat(self, msg, time_s) -> None:
        if self.vehicle_address is None and msg.autopilot != MAV_AUTOPILOT_INVALID:
            self.vehicle_address = (msg.get_srcSystem(), msg.get_srcComponent())
            self.autopilot, self.vehicle_type = msg.autopilot, msg.type
            self._want("vehicle first heard", time_s)

    def _on_home(self, msg, time_s) -> None:
        if not self._from_vehicle(msg):
            return
        home = (msg.latitude, msg.longitude)
        if self.home is None:
            self.home = home
            self._want("home set", time_s)
        elif max(abs(home[0] - self.home[0]), abs(home[1] - self.home[1])) > self.home_moved_e7:
            self.home = home
            self._want("home moved", time_s)

    def _on_current(self, msg, time_s) -> None:
        if not self._from_vehicle(msg):
            return
        mission_id = getattr(msg, "mission_id", 0) or None  # 0: not supported (or old dialect)
        if mission_id is not None:
            if self._adopt_next_id and mission_id != self.mission_id:
                self._adopt_next_id = False
            elif self.mission_id is not None and mission_id != self.mission_id:
                self._want("mission id changed", time_s)
            self.mission_id = mission_id
        total = getattr(msg, "total", None)
        if total is not None:  # NO_MISSION_TOTAL after a mission is a change too (cleared)
            if self.total is not None and total != self.total:
                self._want("mission item total changed", time_s)
            self.total = total

    def _on_ack(self, msg, time_s) -> None:
        if not self._from_vehicle(msg) or getattr(msg, "mission_type", 0) != MAV_MISSION_TYPE_MISSION:
            return
        if msg.type == MAV_MISSION_ACCEPTED and msg.target_system not in (0, self.own[0]):
            self._want(f"upload by system {msg.target_system} accepted", time_s)

    def _on_changed(self, msg, time_s) -> None:
        if getattr(msg, "mission_type", 0) != MAV_MISSION_TYPE_MISSION:
            return
        if getattr(msg, "origin_sysid", None) != self.own[0] or getattr(msg, "origin_compid", None) != self.own[1]:
            self._want("vehicle reports its mission changed", time_s)

    def _on_count(self, msg, time_s) -> None:
        if (self._from_vehicle(msg) and getattr(msg, "mission_type", 0) == MAV_MISSION_TYPE_MISSION
                and not self.reading and self.count is not None and msg.count != self.count):
            self._want("vehicle announced a different item count", time_s)

    _HANDLERS = {
        "HEARTBEAT": _on_heartbeat, "HOME_POSITION": _on_home, "MISSION_CURRENT": _on_current,
        "MISSION_ACK": _on_ack, "MISSION_CHANGED": _on_changed, "MISSION_COUNT": _on_count,
    }

    # --- decisions -----------------------------------------------------------------------------

    def _want(self, reason: str, time_s: float, retry: bool = False) -> None:
        """A read is due; an event (not a retry) also cancels a retry's waiting time."""
        if not retry:
            self._not_before = 0.0
        if self._due is None or (self._due_is_retry and not retry):
            self._due = ReadDue(reason, time_s)
            self._due_is_retry = retry

    def due(self, time_s: float) -> ReadDue | None:
        """The read to start now (and why), or None."""
        if self.reading or self._due is None or time_s < self._not_before:
            return None
        return self._due

    def read_started(self, time_s: float) -> None:
        self.reading = True
        self._due = None

    def read_done(self, count: int, time_s: float) -> None:
        self.reading = False
        self.count = count
        self._failures = 0
        self._not_before = 0.0
        if count == 0 and self.home is None:
            # Before home, ArduPilot answers with 0 items whatever it holds: ask again later.
            self._want("empty mission read before home was set", time_s, retry=True)
            self._not_before = time_s + self.empty_retry_s

    def read_failed(self, time_s: float) -> None:
        self.reading = False
        self._failures += 1
        self._want("previous read failed", time_s, retry=True)
        self._not_before = time_s + min(self.max_retry_s, self.failed_retry_s * 2 ** (self._failures - 1))

    def uploaded(self, count: int) -> None:
        """The service itself uploaded ``count`` items: no read needed for the change it caused."""
        self.count = count
        self._adopt_next_id = True
        self.total = None  # re-baseline on the next MISSION_CURRENT
