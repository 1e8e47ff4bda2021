"""What each autopilot does to a mission it stores, as data, and a comparison by meaning.

A vehicle does not keep a mission byte for byte. ArduPilot packs every item into a small storage
record (``AP_Mission``'s ``mavlink_int_to_mission_cmd`` / ``mission_cmd_to_mavlink_int``): altitude
in whole centimetres, a frame flag "relative altitude" instead of the frame number, only the
params the command uses (the others read back 0), some params as whole numbers or single bytes,
and item 0 is its home. PX4 (``MavlinkMissionManager::parse_mavlink_mission_item`` /
``format_mavlink_mission_item``) keeps positions as doubles and altitudes as floats but also drops
the params a positional command does not use and reports the INT or float frame variant of what
it was sent. So an upload is confirmed by comparing what the vehicle reads back with what it
*could* have made of the items sent: either the item as sent (a vehicle may store verbatim) or
the item as this autopilot normalises it. Anything else — a missing, extra or reordered item, a
changed command, a position moved by more than the 1e-7° integer step, an altitude beyond the
autopilot's storage step — is a mismatch, and the comparison names the item and the field.

The rules are data (:data:`ARDUPILOT_PLANE`, :data:`ARDUPILOT_COPTER`, :data:`PX4`,
:data:`GENERIC`), chosen from HEARTBEAT (``autopilot``, ``type``) by :func:`rules_for`.
docs/mavlink.md has the table.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from enum import Enum
from typing import Sequence

from gcs_pdm.missions import MissionItem

MAV_AUTOPILOT_GENERIC = 0
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_FIXED_WING = 1

PARAM_NAMES = ("param1", "param2", "param3", "param4")


class Stored(Enum):
    """How an autopilot keeps one param of one command (what it reads back for a sent value)."""

    KEPT = "kept"  # float32 as sent; NaN may read back as 0 where the autopilot has no NaN
    ZERO = "zero"  # not stored: reads back 0 whatever was sent
    WHOLE = "whole"  # stored as an unsigned 16-bit integer: truncated, NaN/negative -> 0
    BYTE = "byte"  # stored in one byte: truncated to 0..255
    SIGN = "sign"  # stored as a direction flag: -1 if sent < 0, else 1 (NaN -> 1)
    DEGREES_WRAPPED = "degrees_wrapped"  # stored in radians wrapped to [0, 2pi): reads back in [0, 360)


@dataclass(frozen=True)
class AutopilotRules:
    """One autopilot's storage semantics for mission items."""

    name: str
    # frame sent -> the frame the autopilot reports for it (same meaning, other number)
    frame_equivalents: dict[int, int] = field(default_factory=dict)
    item0_is_home: bool = False  # item 0 read back is the vehicle's home, whatever was sent
    autocontinue_stored: bool = True  # False: always reads back 1
    nan_reads_as_zero: bool = False  # a NaN sent in a KEPT param may read back 0
    altitude_step_m: float = 0.0  # storage resolution of z (0: float32 as sent)
    xy_step: int = 1  # tolerated difference of the 1e-7 degree integers
    # command -> how each of param1..param4 is stored; commands not listed keep all four
    params: dict[int, tuple[Stored, Stored, Stored, Stored]] = field(default_factory=dict)

    def canonical_frame(self, frame: int) -> int:
        return self.frame_equivalents.get(frame, frame)

    def stored_param(self, command: int, index: int, value: float) -> float:
        """The value this autopilot reads back for ``value`` sent as param ``index`` (0..3) of ``command``."""
        how = self.params.get(command, (Stored.KEPT,) * 4)[index]
        if how is Stored.KEPT:
            return 0.0 if (self.nan_reads_as_zero and math.isnan(value)) else _f32(value)
        if how is Stored.ZERO:
            return 0.0
        if how is Stored.SIGN:
            return -1.0 if value < 0 else 1.0
        if how is Stored.DEGREES_WRAPPED:
            return value if math.isnan(value) else _f32(value % 360.0)
        if math.isnan(value) or value < 0:
            return 0.0
        whole = float(int(value))
        return min(whole, 255.0) if how is Stored.BYTE else min(whole, 65535.0)


_K, _Z, _W, _B, _S, _D = Stored.KEPT, Stored.ZERO, Stored.WHOLE, Stored.BYTE, Stored.SIGN, Stored.DEGREES_WRAPPED

NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LOITER_TURNS, NAV_LOITER_TIME = 16, 17, 18, 19
NAV_RETURN_TO_LAUNCH, NAV_LAND, NAV_TAKEOFF, NAV_LOITER_TO_ALT = 20, 21, 22, 31
DO_LAND_START, DO_CHANGE_SPEED, DO_JUMP = 189, 178, 177

# ArduPilot stores a location as lat/lng (int 1e-7 deg), alt (int cm) and flags: the float and INT
# frames are one thing, and a command without location reads back frame 0.
_ARDUPILOT_FRAMES = {5: 0, 6: 3, 11: 10, 2: 0}
_ARDUPILOT_COMMON = {
    NAV_LOITER_UNLIM: (_Z, _Z, _K, _Z),  # radius kept (with its sign)
    NAV_LOITER_TURNS: (_B, _Z, _B, _K),  # turns and radius in a byte each; xtrack flag
    NAV_LOITER_TIME: (_W, _Z, _S, _K),  # seconds; param3 reads back +-1 (direction only)
    NAV_RETURN_TO_LAUNCH: (_Z, _Z, _Z, _Z),
    NAV_LAND: (_W, _Z, _Z, _S),  # abort altitude (plane); param4 reads back 1 unless sent < 0
    NAV_TAKEOFF: (_W, _Z, _Z, _Z),  # minimum pitch in whole degrees
    NAV_LOITER_TO_ALT: (_Z, _K, _Z, _K),
    DO_LAND_START: (_Z, _Z, _Z, _Z),
    DO_JUMP: (_W, _W, _Z, _Z),
    DO_CHANGE_SPEED: (_K, _K, _K, _Z),
}
ARDUPILOT_PLANE = AutopilotRules(
    name="ArduPilot (Plane)", frame_equivalents=_ARDUPILOT_FRAMES, item0_is_home=True,
    autocontinue_stored=False, nan_reads_as_zero=True, altitude_step_m=0.01,
    # Plane: acceptance radius and pass-by distance in one byte each; no hold time, no yaw
    params={**_ARDUPILOT_COMMON, NAV_WAYPOINT: (_Z, _B, _B, _Z)},
)
ARDUPILOT_COPTER = AutopilotRules(
    name="ArduPilot (Copter/Rover/Sub)", frame_equivalents=_ARDUPILOT_FRAMES, item0_is_home=True,
    autocontinue_stored=False, nan_reads_as_zero=True, altitude_step_m=0.01,
    params={**_ARDUPILOT_COMMON, NAV_WAYPOINT: (_W, _Z, _Z, _Z)},  # hold time in whole seconds
)
# PX4 reports positional items in the frame variant of the request (INT for MISSION_REQUEST_INT),
# keeps lat/lon as doubles and altitude as float, yaw in radians wrapped to [0, 2pi).
PX4 = AutopilotRules(
    name="PX4", frame_equivalents={5: 0, 6: 3, 11: 10},
    params={
        NAV_WAYPOINT: (_K, _K, _Z, _D),
        NAV_LOITER_UNLIM: (_Z, _Z, _K, _D),
        NAV_LOITER_TIME: (_K, _K, _K, _K),
        NAV_LAND: (_Z, _K, _Z, _D),
        NAV_TAKEOFF: (_Z, _Z, _Z, _D),
        NAV_LOITER_TO_ALT: (_K, _K, _Z, _K),
    },
)
# Unknown autopilot: only what MAVLink itself says is the same (INT vs float frame variants, float32
# on the wire, NaN = "default"); item 0 is skipped as before because the project's own simulated
# vehicle and most ArduPilot-derived stacks put home there.
GENERIC = AutopilotRules(name="generic MAVLink", frame_equivalents={5: 0, 6: 3, 11: 10}, item0_is_home=True)


def rules_for(autopilot: int | None, vehicle_type: int | None = None) -> AutopilotRules:
    """The rules for HEARTBEAT.autopilot (MAV_AUTOPILOT) and HEARTBEAT.type (MAV_TYPE)."""
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return ARDUPILOT_PLANE if vehicle_type in (None, MAV_TYPE_FIXED_WING) else ARDUPILOT_COPTER
    if autopilot == MAV_AUTOPILOT_PX4:
        return PX4
    return GENERIC


@dataclass(frozen=True)
class ItemDifference:
    """One real difference between the mission sent and the one read back."""

    seq: int
    field: str  # "item" for a missing or extra item, else the MISSION_ITEM_INT field name
    sent: object
    read_back: object
    note: str = ""

    def __str__(self) -> str:
        text = f"item {self.seq} {self.field}: sent {self.sent!r}, read back {self.read_back!r}"
        return f"{text} ({self.note})" if self.note else text


@dataclass(frozen=True)
class MissionComparison:
    rules: str
    differences: tuple[ItemDifference, ...]

    @property
    def equivalent(self) -> bool:
        return not self.differences

    def __bool__(self) -> bool:
        return self.equivalent

    def summary(self, limit: int = 3) -> str:
        if self.equivalent:
            return f"read-back equivalent under {self.rules} rules"
        shown = "; ".join(str(d) for d in self.differences[:limit])
        more = len(self.differences) - limit
        return shown + (f"; and {more} more" if more > 0 else "")


def missions_equivalent(sent: Sequence[MissionItem], read_back: Sequence[MissionItem],
                        rules: AutopilotRules | int | None = None) -> MissionComparison:
    """Compare an uploaded mission with its read-back by meaning under ``rules`` (or a MAV_AUTOPILOT)."""
    if not isinstance(rules, AutopilotRules):
        rules = rules_for(rules)
    diffs: list[ItemDifference] = []
    start = 1 if rules.item0_is_home else 0
    for seq in range(start, min(len(sent), len(read_back))):
        item_diffs = _item_differences(rules, sent[seq], read_back[seq])
        if item_diffs:
            moved = _matching_position(rules, read_back[seq], sent, start)
            if moved is not None:
                diffs.append(ItemDifference(seq, "item", f"item {seq}", f"sent item {moved}", "reordered"))
                continue
        diffs.extend(item_diffs)
    for seq in range(len(read_back), len(sent)):
        diffs.append(ItemDifference(seq, "item", _describe(sent[seq]), None, "missing on the vehicle"))
    for seq in range(len(sent), len(read_back)):
        diffs.append(ItemDifference(seq, "item", None, _describe(read_back[seq]), "extra on the vehicle"))
    return MissionComparison(rules.name, tuple(diffs))


def _matching_position(rules, back: MissionItem, sent: Sequence[MissionItem], start: int) -> int | None:
    for j in range(start, len(sent)):
        if j != back.seq and not _item_differences(rules, sent[j], back):
            return j
    return None


def _describe(item: MissionItem) -> str:
    return f"command {item.command} at ({item.x}, {item.y}, {item.z:g})"


def _item_differences(rules: AutopilotRules, sent: MissionItem, back: MissionItem) -> list[ItemDifference]:
    seq = back.seq
    if sent.command != back.command:
        return [ItemDifference(seq, "command", sent.command, back.command)]
    out = []
    if rules.canonical_frame(sent.frame) != rules.canonical_frame(back.frame):
        out.append(ItemDifference(seq, "frame", sent.frame, back.frame))
    if rules.autocontinue_stored and bool(sent.autocontinue) != bool(back.autocontinue):
        out.append(ItemDifference(seq, "autocontinue", sent.autocontinue, back.autocontinue))
    if sent.mission_type != back.mission_type:
        out.append(ItemDifference(seq, "mission_type", sent.mission_type, back.mission_type))
    for index, name in enumerate(PARAM_NAMES):
        value, got = getattr(sent, name), getattr(back, name)
        if not (_same_float(_f32(value), got) or _same_float(rules.stored_param(sent.command, index, value), got)):
            out.append(ItemDifference(seq, name, value, got))
    for name in ("x", "y"):
        if abs(getattr(sent, name) - getattr(back, name)) > rules.xy_step:
            out.append(ItemDifference(seq, name, getattr(sent, name), getattr(back, name), "moved"))
    if not _same_altitude(sent.z, back.z, rules.altitude_step_m):
        out.append(ItemDifference(seq, "z", sent.z, back.z, "altitude"))
    return out


def _same_float(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def _same_altitude(sent: float, back: float, step_m: float) -> bool:
    if _same_float(_f32(sent), back):
        return True
    if math.isnan(sent) or math.isnan(back):
        return False
    # float32 of an altitude of a few km has ~0.5 mm resolution; a storage step adds half of itself
    return abs(sent - back) <= step_m / 2 + 1e-6 * max(1.0, abs(sent)) + 1e-9


def _f32(value: float) -> float:
    return struct.unpack("<f", struct.pack("<f", value))[0]
