"""Flights as records: the store's flights kept in step with the vehicle (shell over
:mod:`gcs_pdm.packs.flights`, which says where a flight begins and ends).

* at a flight's end its active faults stop being active (they stay in its history, ``GET
  /flights/{id}``), and whoever listens (``on_end``: the packs' health points) is told;
* at a flight's start nothing of an earlier flight (or an earlier run of the service) is active; a
  fault the operator declared on the ground since joins the new flight; the live loop
  (``on_begin``) drops its fault tracker's state and, after a reboot, restarts its clock;
* an open flight found at start-up (the service stopped during it) is restored; the vehicle's next
  message decides whether it goes on (same clock, still armed) or ended (disarmed, rebooted, silent).

Runs on the telemetry thread (``observe``, ``silent``); the HTTP threads only read the store.
"""
from __future__ import annotations

import logging
import math
from collections import deque
from typing import Callable

import numpy as np

from gcs_pdm.frames import PackFrame
from gcs_pdm.packs.flights import Boundary, FlightBoundaries
from gcs_pdm.packs.cell_curves import pack_health_point
from gcs_pdm.packs.health import HealthSettings
from gcs_pdm.packs.identity import SERIAL_MESSAGES, identify, serial_text

log = logging.getLogger(__name__)

#: the open flight's last heard time is written at most this often (message seconds)
TOUCH_EVERY_S = 5.0
#: pack samples kept from before take-off (the rest a capacity starts from), message seconds
GROUND_WINDOW_S = 600.0
#: a flight's health points are made this long after it ended (the rest after landing gives the
#: capacity its end point), or at once when the next flight begins or the service closes
HEALTH_AFTER_END_S = HealthSettings().min_rest_after_s + 30.0


class PackSamples:
    """Each pack's (time, current, voltage, temperature) as heard: the ground window before a flight,
    the flight, and the rest after it, for the flight's health points."""

    def __init__(self):
        self.rows: dict[str, deque] = {}

    def add(self, f: PackFrame) -> None:
        self.rows.setdefault(f.pack, deque()).append((f.time_s, _num(f.current_a), _num(f.voltage_v),
                                                      _num(f.temperature_c)))

    def trim_before(self, t: float) -> None:
        for q in self.rows.values():
            while q and q[0][0] < t:
                q.popleft()

    def arrays(self, pack: str, t0: float, t1: float) -> np.ndarray:
        a = np.array([r for r in self.rows.get(pack, ()) if t0 <= r[0] <= t1], float).reshape(-1, 4)
        return a


class PackSerials:
    """The pack serial numbers the autopilot reports (SMART_BATTERY_INFO / BATTERY_INFO), per slot of
    the vehicle description, with the message time each was heard: a flight's health point goes to
    the pack that was in the slot during that flight (packs are swapped on the ground).

    ``listen(link)`` subscribes to the messages; ``drain`` (telemetry thread) reads what came."""

    def __init__(self, service):
        self.service = service
        self._sub = None
        self._link = None
        #: per slot: [(message time heard, serial)], the newest last
        self.heard: dict[str, list[tuple[float, str]]] = {}
        #: battery ids that named a serial but are no pack of the description (counted, once logged)
        self.unmapped_ids: dict[int, int] = {}

    def listen(self, link) -> None:
        self.close()
        subscribe = getattr(link, "subscribe", None)  # a test's stand-in link may not relay messages
        if subscribe is not None:
            self._link, self._sub = link, subscribe(SERIAL_MESSAGES)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None

    def drain(self, time_s: float) -> None:
        """The serials heard since the last call, at message time ``time_s`` (the messages carry none)."""
        while self._sub is not None:
            msg = self._sub.get(timeout=0)
            if msg is None:
                return
            target = getattr(self._link, "target_system", None)
            if target is not None and msg.get_srcSystem() != target:
                continue  # another vehicle's (a smart battery is a component of its vehicle's system)
            self.add(int(getattr(msg, "id", 0)), getattr(msg, "serial_number", None), time_s)

    def add(self, battery_id: int, raw_serial, time_s: float) -> None:
        serial = serial_text(raw_serial)
        if serial is None:
            return
        slot = next((name for name, p in self.service.described_packs().items() if p.mavlink_battery_id == battery_id),
                    None)
        if slot is None:
            self.unmapped_ids[battery_id] = self.unmapped_ids.get(battery_id, 0) + 1
            if self.unmapped_ids[battery_id] == 1:
                log.warning("battery %d reports serial %s but is no pack of the vehicle description: not used",
                            battery_id, serial)
            return
        seen = self.heard.setdefault(slot, [])
        if not seen or seen[-1][1] != serial:
            if seen:
                log.info("slot %s: pack serial %s replaces %s at t=%.1f s", slot, serial, seen[-1][1], time_s)
            seen.append((time_s, serial))

    def at(self, slot: str, time_s: float) -> str | None:
        """The serial heard in ``slot`` last before ``time_s`` (else the first heard after it: the
        message may come only once the link is up); None: the autopilot has not said."""
        seen = self.heard.get(slot)
        if not seen:
            return None
        before = [s for t, s in seen if t <= time_s]
        return before[-1] if before else seen[0][1]

    def restart_clock(self) -> None:
        """A vehicle reboot: message times start again; each slot keeps the serial heard last (the
        pack is still in it until the autopilot says otherwise)."""
        self.heard = {slot: [(-math.inf, seen[-1][1])] for slot, seen in self.heard.items() if seen}

    def latest(self, slot: str) -> str | None:
        seen = self.heard.get(slot)
        return seen[-1][1] if seen else None


def _num(x) -> float:
    return float(x) if x is not None else math.nan


class FlightRecorder:
    def __init__(self, service):
        self.service = service
        store = service.store
        opened = store.open_flight()
        self.flight_id: int | None = opened["id"] if opened else None
        store.current_flight_id = self.flight_id
        self.boundaries = FlightBoundaries(service.config.flight_end_after_link_lost_s,
                                           open_until_s=opened["last_s"] if opened else None)
        self._touched_s = -math.inf
        self.samples = PackSamples()
        self.serials = PackSerials(service)
        #: ended flights whose health points wait for the rest after landing: (id, start, end)
        self._pending: list[tuple[int, float, float]] = []
        self._flight_start_s: float | None = opened["started_s"] if opened else None
        #: (flight id, boundary, ids of the operator's ground faults that joined it)
        self.on_begin: Callable[[int, Boundary, set], None] = lambda flight_id, boundary, kept: None
        self.on_end: Callable[[int, Boundary], None] = lambda flight_id, boundary: None
        self._publish()

    def observe(self, time_s: float, armed: bool | None) -> list[Boundary]:
        """One message's time and the armed flag; the boundaries crossed (already recorded)."""
        crossed = self.boundaries.observe(time_s, armed)
        for b in crossed:
            self._end(b) if b.kind == "end" else self._begin(b)
        if self.flight_id is not None and abs(time_s - self._touched_s) >= TOUCH_EVERY_S:
            self._touched_s = time_s
            self.service.store.touch_flight(self.flight_id, time_s)
        return crossed

    def pack_frame(self, frame: PackFrame) -> None:
        """A pack's sample (telemetry thread): kept for the flight's health point."""
        self.samples.add(frame)
        t = frame.time_s
        self.serials.drain(t)
        if self._pending and t - self._pending[0][2] >= HEALTH_AFTER_END_S:
            self.make_health_points()
        if self.flight_id is None and not self._pending:
            self.samples.trim_before(t - GROUND_WINDOW_S)

    def make_health_points(self) -> int:
        """The pending flights' health points, from what was heard (stored in the packs' records);
        how many were stored. A pack whose rated capacity the vehicle description does not give is
        skipped with a warning."""
        made = 0
        packs_store = getattr(self.service, "packs", None)
        specs = self.service.described_packs()
        assignments = {k: v["pack_id"] for k, v in packs_store.assignments().items()} if packs_store else {}
        for fid, start, end in self._pending:
            for pack in list(self.samples.rows):
                a = self.samples.arrays(pack, start - GROUND_WINDOW_S, end + HEALTH_AFTER_END_S)
                spec = specs.get(pack)
                if a.shape[0] < 2 or spec is None or packs_store is None:
                    if spec is None and a.shape[0] >= 2:
                        log.warning("flight %d: pack %s is not in the vehicle description: no rated capacity, "
                                    "no health point", fid, pack)
                    continue
                ident = identify(pack, self.serials.at(pack, end), assignments)
                if ident.warning:
                    log.warning("flight %d: %s", fid, ident.warning)
                try:
                    hp = pack_health_point(ident.pack_id, a[:, 0], a[:, 1], a[:, 2], a[:, 3], chemistry=spec.chemistry,
                                           nominal_capacity_ah=spec.capacity_mah / 1000.0,
                                           cells_series=spec.cells_series, fit_curve=True,
                                           full_cell_v=spec.full_cell_voltage)
                except ValueError as exc:
                    log.warning("flight %d: pack %s: no health point: %s", fid, pack, exc)
                    continue
                packs_store.add_live_point(fid, pack, ident.source, hp,
                                           {"start_s": start, "end_s": end})
                self.service.events.publish("pack_health", flight_id=fid, pack_id=hp.pack_id, slot=pack,
                                            capacity_ah=hp.capacity_ah, resistance_25c_ohm=hp.resistance_25c_ohm)
                made += 1
        self._pending.clear()
        return made

    def silent(self, silent_s: float) -> None:
        """The vehicle has been silent ``silent_s`` wall seconds (message time stands still while it
        is): past the setting, the open flight ends at its last heard time."""
        limit = self.service.config.flight_end_after_link_lost_s
        if self.flight_id is not None and silent_s > limit:
            last = self.boundaries.last_time_s
            self.boundaries.in_flight = False
            self._end(Boundary("end", last if last is not None else math.nan,
                               f"link lost for {silent_s:.0f} s (longer than {limit:g} s)"))

    def _end(self, b: Boundary) -> None:
        if self.flight_id is None:
            return
        fid, store = self.flight_id, self.service.store
        if self._flight_start_s is not None and math.isfinite(b.time_s):
            self._pending.append((fid, self._flight_start_s, b.time_s))
        closed = store.end_flight_faults(fid)
        store.end_flight(fid, b.time_s if math.isfinite(b.time_s) else None, b.reason)
        self.flight_id = None
        log.info("flight %d ended at t=%.1f s: %s (%d fault(s) closed with it)", fid, b.time_s, b.reason, len(closed))
        self.service.events.publish("flight", id=fid, status="ended", time_s=b.time_s, reason=b.reason,
                                    faults_closed=closed)
        self._publish()
        try:
            self.on_end(fid, b)
        except Exception:  # noqa: BLE001 - a listener's failure never stops the telemetry thread
            log.exception("after flight %d ended", fid)

    def _begin(self, b: Boundary) -> None:
        # nothing from an earlier flight is active in a new one; the operator's faults declared on
        # the ground since (a motor known damaged before take-off) join it
        if self._pending:  # the previous flight's rest after landing ends here
            self.make_health_points()
        if b.reason.startswith("vehicle reboot"):
            self.samples = PackSamples()  # the old clock's samples are not comparable
            self.serials.restart_clock()
        fid, closed, carried = self.service.store.begin_flight(b.time_s, b.reason)
        self._flight_start_s = b.time_s
        self.flight_id, self._touched_s = fid, b.time_s
        log.info("flight %d began at t=%.1f s: %s", fid, b.time_s, b.reason)
        self.service.events.publish("flight", id=fid, status="began", time_s=b.time_s, reason=b.reason,
                                    faults_closed=closed, faults_carried=carried)
        self._publish()
        self.on_begin(fid, b, set(carried))

    def _publish(self) -> None:
        self.service.state.update(flight={"id": self.flight_id, "open": self.flight_id is not None})
