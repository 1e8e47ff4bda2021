"""Vehicle side of the MAVLink mission protocol (https://mavlink.io/en/services/mission.html).

Upload (GCS → vehicle): MISSION_COUNT → MISSION_REQUEST_INT(0) … MISSION_ITEM_INT … → MISSION_ACK.
The vehicle drives it: it requests item after item, re-requests the one it waits for when nothing
comes within ``item_s`` (spec: 250 ms), gives up after ``retries`` (spec: 5) with
MAV_MISSION_OPERATION_CANCELLED and keeps its old mission. Items out of sequence are ignored (the
spec's rule), a new MISSION_COUNT from the same GCS restarts the transfer, one from another GCS
while busy gets MAV_MISSION_DENIED. An item the vehicle cannot fly ends the upload with the error
code that names why (MAV_MISSION_UNSUPPORTED, …_UNSUPPORTED_FRAME, …_INVALID_PARAM5_X/6_Y) and the
old mission untouched. Only a complete, valid mission replaces the old one, at once.

Download (vehicle → GCS) is answered statelessly: MISSION_REQUEST_LIST → MISSION_COUNT,
MISSION_REQUEST_INT(seq) → MISSION_ITEM_INT (legacy MISSION_REQUEST → MISSION_ITEM), so a GCS may
re-request anything in any order. Fence and rally lists are empty (count 0).

MISSION_CLEAR_ALL → MISSION_ACK(ACCEPTED); MISSION_SET_CURRENT → MISSION_CURRENT (no ACK, as the
spec says), or an error STATUSTEXT for an item that does not exist.

Time is passed in (``now``, seconds of any monotonic clock: the shell uses wall time, because the
GCS's timeouts are wall time even when the flight runs faster).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.missions import GLOBAL_FRAMES, MissionItem
from gcs_pdm.sim.model import NAV_COMMANDS, SEVERITY_ERROR, SUPPORTED_COMMANDS, VehicleModel

log = logging.getLogger(__name__)

MISSION = mavlink2.MAV_MISSION_TYPE_MISSION
ALL = mavlink2.MAV_MISSION_TYPE_ALL
MAX_ITEMS = 724  # ArduPilot's storage on a small board; larger uploads get MAV_MISSION_NO_SPACE


@dataclass(frozen=True)
class ServerTimeouts:
    item_s: float = 0.25
    retries: int = 5


@dataclass
class _Upload:
    gcs: tuple[int, int]
    count: int
    items: list
    deadline: float
    retries: int = 0


def validate_item(item: MissionItem) -> int:
    """MAV_MISSION_ACCEPTED, or the MAV_MISSION_RESULT that says why the vehicle cannot fly ``item``."""
    if item.seq == 0:
        return mavlink2.MAV_MISSION_ACCEPTED  # home: whatever the GCS sends, as ArduPilot
    if item.command not in SUPPORTED_COMMANDS:
        return mavlink2.MAV_MISSION_UNSUPPORTED
    if item.command in NAV_COMMANDS and not (item.x == 0 and item.y == 0):
        if item.frame not in GLOBAL_FRAMES:
            return mavlink2.MAV_MISSION_UNSUPPORTED_FRAME
        if not -900_000_000 <= item.x <= 900_000_000:
            return mavlink2.MAV_MISSION_INVALID_PARAM5_X
        if not -1_800_000_000 <= item.y <= 1_800_000_000:
            return mavlink2.MAV_MISSION_INVALID_PARAM6_Y
    elif item.command in NAV_COMMANDS and item.frame not in GLOBAL_FRAMES and item.frame != 2:
        return mavlink2.MAV_MISSION_UNSUPPORTED_FRAME
    return mavlink2.MAV_MISSION_ACCEPTED


def arduplane_stored(item: MissionItem, config) -> MissionItem:
    """``item`` as stock ArduPlane reads it back (observed in ../shared/logs/, README there): item 0
    is home, frame 6 reads back as 3 and 5/2 as 0, NaN params as 0, NAV_LAND's param4 as 1,
    altitude in whole centimetres, autocontinue 1."""
    from dataclasses import replace
    if item.seq == 0:
        return MissionItem(seq=0, frame=0, command=16, current=0, autocontinue=1, param1=0.0, param2=0.0,
                           param3=0.0, param4=0.0, x=round(config.home_lat_deg * 1e7),
                           y=round(config.home_lon_deg * 1e7), z=float(config.home_alt_m))
    params = [0.0 if p != p else p for p in (item.param1, item.param2, item.param3, item.param4)]
    if item.command == 21:  # MAV_CMD_NAV_LAND
        params[3] = -1.0 if params[3] < 0 else 1.0
    frame = {6: 3, 5: 0, 2: 0, 11: 10}.get(item.frame, item.frame)
    return replace(item, frame=frame, autocontinue=1, param1=params[0], param2=params[1], param3=params[2],
                   param4=params[3], z=round(item.z * 100) / 100)


def item_from_message(msg) -> MissionItem:
    if msg.get_type() == "MISSION_ITEM":  # legacy: degrees as float
        from gcs_pdm.missions import xy_scale
        scale = xy_scale(msg.frame)
        x, y = int(round(msg.x * scale)), int(round(msg.y * scale))
    else:
        x, y = int(msg.x), int(msg.y)
    return MissionItem(seq=msg.seq, frame=msg.frame, command=msg.command, current=msg.current,
                       autocontinue=msg.autocontinue, param1=msg.param1, param2=msg.param2, param3=msg.param3,
                       param4=msg.param4, x=x, y=y, z=msg.z, mission_type=getattr(msg, "mission_type", MISSION))


class MissionServer:
    """The vehicle's mission protocol endpoint over a :class:`VehicleModel`'s mission store."""

    def __init__(self, model: VehicleModel, system_id: int = 1, component_id: int = 1,
                 timeouts: ServerTimeouts | None = None):
        self.model = model
        self.system_id = system_id
        self.component_id = component_id
        self.timeouts = timeouts or ServerTimeouts()
        self.mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.upload: _Upload | None = None
        self.stats = {"uploads": 0, "rejected": 0, "cancelled": 0, "rerequests": 0, "downloads": 0}
        # Store items the way stock ArduPlane does (docs/mavlink.md), to test read-back comparison.
        self.store_like_arduplane = False

    def for_me(self, msg) -> bool:
        ts = getattr(msg, "target_system", None)
        if ts is None:
            return False
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.system_id) and tc in (0, self.component_id)

    def handle(self, msg, now: float) -> list:
        """Replies to one received message (empty if it is not a mission message for this vehicle)."""
        mtype = msg.get_type()
        handler = self._HANDLERS.get(mtype)
        if handler is None or not self.for_me(msg):
            return []
        return handler(self, msg, now, (msg.get_srcSystem(), msg.get_srcComponent()))

    def poll(self, now: float) -> list:
        """Re-requests and give-ups due at ``now``."""
        up = self.upload
        if up is None or now < up.deadline:
            return []
        up.retries += 1
        if up.retries > self.timeouts.retries:
            self.upload = None
            self.stats["cancelled"] += 1
            log.warning("mission upload abandoned at item %d of %d: no answer", len(up.items), up.count)
            return [self._ack(up.gcs, mavlink2.MAV_MISSION_OPERATION_CANCELLED)]
        self.stats["rerequests"] += 1
        up.deadline = now + self.timeouts.item_s
        return [self._request(up)]

    # ---- helpers ----------------------------------------------------------------------------

    def _ack(self, gcs, result: int, mission_type: int = MISSION):
        return self.mav.mission_ack_encode(gcs[0], gcs[1], result, mission_type)

    def _request(self, up: _Upload):
        return self.mav.mission_request_int_encode(up.gcs[0], up.gcs[1], len(up.items), MISSION)

    # ---- upload -----------------------------------------------------------------------------

    def _on_count(self, msg, now, gcs) -> list:
        mtype = getattr(msg, "mission_type", MISSION)
        if mtype != MISSION:
            result = mavlink2.MAV_MISSION_ACCEPTED if msg.count == 0 else mavlink2.MAV_MISSION_UNSUPPORTED
            return [self._ack(gcs, result, mtype)]
        if self.upload is not None and self.upload.gcs != gcs:
            return [self._ack(gcs, mavlink2.MAV_MISSION_DENIED)]
        if msg.count == 0:
            self.upload = None
            self.model.clear_mission()
            return [self._ack(gcs, mavlink2.MAV_MISSION_ACCEPTED)]
        if msg.count > MAX_ITEMS:
            self.upload = None
            self.stats["rejected"] += 1
            return [self._ack(gcs, mavlink2.MAV_MISSION_NO_SPACE)]
        self.upload = _Upload(gcs, int(msg.count), [], now + self.timeouts.item_s)
        return [self._request(self.upload)]

    def _on_item(self, msg, now, gcs) -> list:
        up = self.upload
        mtype = getattr(msg, "mission_type", MISSION)
        if up is None or up.gcs != gcs or mtype != MISSION:
            return []
        if msg.seq != len(up.items):
            return []  # out of sequence: ignored; the timeout re-requests the one awaited
        item = item_from_message(msg)
        result = validate_item(item)
        if result != mavlink2.MAV_MISSION_ACCEPTED:
            self.upload = None
            self.stats["rejected"] += 1
            log.warning("mission upload rejected at item %d (command %d, frame %d): result %d",
                        item.seq, item.command, item.frame, result)
            return [self._ack(gcs, result)]
        up.items.append(arduplane_stored(item, self.model.config) if self.store_like_arduplane else item)
        up.retries = 0
        if len(up.items) < up.count:
            up.deadline = now + self.timeouts.item_s
            return [self._request(up)]
        self.upload = None
        flagged = [it.seq for it in up.items if it.current and it.seq >= 1]
        self.model.set_mission(up.items, current=flagged[0] if len(flagged) == 1 else None)
        self.stats["uploads"] += 1
        return [self._ack(gcs, mavlink2.MAV_MISSION_ACCEPTED)]

    def _on_ack(self, msg, now, gcs) -> list:
        if self.upload is not None and self.upload.gcs == gcs and msg.type != mavlink2.MAV_MISSION_ACCEPTED:
            log.info("mission upload cancelled by the GCS (result %d)", msg.type)
            self.upload = None
            self.stats["cancelled"] += 1
        return []

    # ---- download ---------------------------------------------------------------------------

    def _on_request_list(self, msg, now, gcs) -> list:
        mtype = getattr(msg, "mission_type", MISSION)
        count = len(self.model.mission) if mtype == MISSION else 0
        self.stats["downloads"] += 1
        return [self.mav.mission_count_encode(gcs[0], gcs[1], count, mtype)]

    def _on_request(self, msg, now, gcs) -> list:
        mtype = getattr(msg, "mission_type", MISSION)
        mission = self.model.mission if mtype == MISSION else []
        if not 0 <= msg.seq < len(mission):
            return [self._ack(gcs, mavlink2.MAV_MISSION_INVALID_SEQUENCE, mtype)]
        it = mission[msg.seq]
        current = 1 if it.seq == self.model.current_seq else 0
        if msg.get_type() == "MISSION_REQUEST":
            from gcs_pdm.missions import xy_scale
            scale = xy_scale(it.frame)
            return [self.mav.mission_item_encode(gcs[0], gcs[1], it.seq, it.frame, it.command, current,
                                                 it.autocontinue, it.param1, it.param2, it.param3, it.param4,
                                                 it.x / scale, it.y / scale, it.z, mtype)]
        return [self.mav.mission_item_int_encode(gcs[0], gcs[1], it.seq, it.frame, it.command, current,
                                                 it.autocontinue, it.param1, it.param2, it.param3, it.param4,
                                                 it.x, it.y, it.z, mtype)]

    # ---- clear / set current -----------------------------------------------------------------

    def _on_clear(self, msg, now, gcs) -> list:
        mtype = getattr(msg, "mission_type", MISSION)
        if mtype in (MISSION, ALL):
            self.upload = None
            self.model.clear_mission()
        return [self._ack(gcs, mavlink2.MAV_MISSION_ACCEPTED, mtype)]

    def _on_set_current(self, msg, now, gcs) -> list:
        if self.model.set_current(int(msg.seq)):
            return []  # the model's "current" event goes out as MISSION_CURRENT
        return [self.mav.statustext_encode(SEVERITY_ERROR, f"Mission set current: no item {msg.seq}".encode()[:50])]

    _HANDLERS = {
        "MISSION_COUNT": _on_count,
        "MISSION_ITEM_INT": _on_item,
        "MISSION_ITEM": _on_item,
        "MISSION_ACK": _on_ack,
        "MISSION_REQUEST_LIST": _on_request_list,
        "MISSION_REQUEST_INT": _on_request,
        "MISSION_REQUEST": _on_request,
        "MISSION_CLEAR_ALL": _on_clear,
        "MISSION_SET_CURRENT": _on_set_current,
    }
