"""Mission items as the vehicle stores them (MAVLink ``MISSION_ITEM_INT``), built from degrees.

Pure core: the planner emits lists of :class:`MissionItem`; ``gcs_pdm.mavlink.mission_client``
uploads them and ``gcs_pdm.mavlink.mission_files`` reads and writes them as QGC WPL 110 or
QGroundControl ``.plan`` files. Latitude/longitude are kept as the wire's 1e-7 degree integers so
that a mission survives upload, download and file round trips bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

# MAV_CMD values used by the builders (common.xml).
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
# MAV_FRAME values.
MAV_FRAME_GLOBAL = 0
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_FRAME_GLOBAL_INT = 5
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
MAV_FRAME_GLOBAL_TERRAIN_ALT = 10
MAV_FRAME_GLOBAL_TERRAIN_ALT_INT = 11
MAV_MISSION_TYPE_MISSION = 0

GLOBAL_FRAMES = frozenset({
    MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_FRAME_GLOBAL_TERRAIN_ALT,
    MAV_FRAME_GLOBAL_INT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
})
# Local frames carry metres x 1e4 in MISSION_ITEM_INT's integer fields (mission protocol spec).
LOCAL_FRAMES = frozenset({1, 4, 7, 8, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21})

DEG_E7 = 10_000_000


def deg_to_e7(deg: float) -> int:
    """Degrees to the wire's 1e-7 degree integer (nearest, not truncated)."""
    return int(round(deg * DEG_E7))


def xy_scale(frame: int) -> int:
    """Factor between a MISSION_ITEM_INT x/y integer and its natural value for ``frame``."""
    if frame in GLOBAL_FRAMES:
        return DEG_E7
    if frame in LOCAL_FRAMES:
        return 10_000
    return 1


@dataclass(frozen=True, slots=True)
class MissionItem:
    """One mission item, field for field as in MAVLink ``MISSION_ITEM_INT``.

    ``x``/``y`` are latitude/longitude in 1e-7 degrees for global frames; ``z`` is altitude in m
    (relative to home for the ``*_RELATIVE_ALT*`` frames).
    """

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int = MAV_MISSION_TYPE_MISSION

    @property
    def lat_deg(self) -> float:
        return self.x / DEG_E7

    @property
    def lon_deg(self) -> float:
        return self.y / DEG_E7


def _global_item(command: int, lat_deg: float, lon_deg: float, alt_m: float, *, seq: int,
                 params: tuple[float, float, float, float], frame: int) -> MissionItem:
    return MissionItem(seq=seq, frame=frame, command=command, current=0, autocontinue=1,
                       param1=params[0], param2=params[1], param3=params[2], param4=params[3],
                       x=deg_to_e7(lat_deg), y=deg_to_e7(lon_deg), z=float(alt_m))


def takeoff(lat_deg: float, lon_deg: float, alt_m: float, *, seq: int = 0, pitch_deg: float = 15.0,
            frame: int = MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) -> MissionItem:
    """NAV_TAKEOFF to ``alt_m``; param1 is the minimum pitch a fixed-wing climbs out with."""
    return _global_item(MAV_CMD_NAV_TAKEOFF, lat_deg, lon_deg, alt_m, seq=seq,
                        params=(pitch_deg, 0.0, 0.0, float("nan")), frame=frame)


def waypoint(lat_deg: float, lon_deg: float, alt_m: float, *, seq: int = 0, hold_s: float = 0.0,
             acceptance_radius_m: float = 0.0, frame: int = MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) -> MissionItem:
    """NAV_WAYPOINT (pass-through, no yaw requirement)."""
    return _global_item(MAV_CMD_NAV_WAYPOINT, lat_deg, lon_deg, alt_m, seq=seq,
                        params=(hold_s, acceptance_radius_m, 0.0, float("nan")), frame=frame)


def land(lat_deg: float, lon_deg: float, alt_m: float = 0.0, *, seq: int = 0,
         frame: int = MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) -> MissionItem:
    """NAV_LAND at a position."""
    return _global_item(MAV_CMD_NAV_LAND, lat_deg, lon_deg, alt_m, seq=seq,
                        params=(0.0, 0.0, 0.0, float("nan")), frame=frame)


def return_to_launch(*, seq: int = 0) -> MissionItem:
    """NAV_RETURN_TO_LAUNCH (no position: the vehicle flies home)."""
    return MissionItem(seq=seq, frame=MAV_FRAME_MISSION, command=MAV_CMD_NAV_RETURN_TO_LAUNCH,
                       current=0, autocontinue=1, param1=0.0, param2=0.0, param3=0.0, param4=0.0,
                       x=0, y=0, z=0.0)


def renumber(items: list[MissionItem]) -> list[MissionItem]:
    """The same items with ``seq`` = list position and only the first marked current."""
    return [replace(item, seq=i, current=1 if i == 0 else 0) for i, item in enumerate(items)]


def same_items(a: list[MissionItem], b: list[MissionItem]) -> bool:
    """Equality that treats NaN params as equal (NaN means "unchanged/default" in MAVLink)."""
    if len(a) != len(b):
        return False
    for ia, ib in zip(a, b):
        for name in MissionItem.__slots__:
            va, vb = getattr(ia, name), getattr(ib, name)
            if va != vb and not (va != va and vb != vb):
                return False
    return True


def _f32(value: float) -> float:
    import struct
    return struct.unpack("<f", struct.pack("<f", value))[0]


def as_sent(item: MissionItem) -> MissionItem:
    """The item as it comes back from a vehicle: params and z are float32 on the wire."""
    return replace(item, param1=_f32(item.param1), param2=_f32(item.param2), param3=_f32(item.param3),
                   param4=_f32(item.param4), z=_f32(item.z))


def item_to_json(item: MissionItem) -> dict:
    """One item as JSON (the service stores and serves missions so): NaN params ("unchanged") become null."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(item).items()}


def item_from_json(d: dict) -> MissionItem:
    """The inverse of :func:`item_to_json` (a null param is NaN again); unknown keys are ignored."""
    vals = {f.name: d[f.name] for f in fields(MissionItem) if f.name in d}
    for k in ("param1", "param2", "param3", "param4"):
        if vals.get(k) is None:
            vals[k] = float("nan")
    return MissionItem(**vals)
