"""Mission files: QGC WPL 110 text and QGroundControl ``.plan`` JSON, read and written exactly.

Coordinates stay 1e-7 degree integers end to end: WPL is written with exactly seven decimals
from the integer (no float arithmetic) and read back through ``Decimal``; ``.plan`` stores JSON
doubles, and ``round(x / 1e7 * 1e7) == x`` holds for every int32, so both round-trip bit for bit.
Params and ``z`` are written with ``repr`` (shortest exact double) and so also round-trip.
"""
from __future__ import annotations

import json
import math
from decimal import Decimal, InvalidOperation
from pathlib import Path

from gcs_pdm.missions import MissionItem, xy_scale

WPL_HEADER = "QGC WPL 110"


class MissionFileError(ValueError):
    """A mission file that cannot be read; the message names the file and the line/item."""


def _fixed(value: int, scale: int) -> str:
    """An integer divided by a power of ten, as an exact decimal string."""
    if scale == 1:
        return str(value)
    digits = len(str(scale)) - 1
    sign = "-" if value < 0 else ""
    whole, frac = divmod(abs(value), scale)
    return f"{sign}{whole}.{frac:0{digits}d}"


def _float_text(value: float) -> str:
    return "nan" if math.isnan(value) else repr(float(value))


def _scaled_int(text: str, scale: int) -> int:
    return int((Decimal(text) * scale).to_integral_value())


def format_wpl(items: list[MissionItem]) -> str:
    """Mission items as QGC WPL 110 text (tab separated, one item per line)."""
    lines = [WPL_HEADER]
    for it in items:
        scale = xy_scale(it.frame)
        cols = [str(it.seq), str(it.current), str(it.frame), str(it.command),
                _float_text(it.param1), _float_text(it.param2), _float_text(it.param3), _float_text(it.param4),
                _fixed(it.x, scale), _fixed(it.y, scale), _float_text(it.z), str(it.autocontinue)]
        lines.append("\t".join(cols))
    return "\n".join(lines) + "\n"


def parse_wpl(text: str, source: str = "<text>") -> list[MissionItem]:
    """Parse QGC WPL 110 text. Blank lines are ignored; anything else malformed is an error."""
    lines = text.splitlines()
    if not lines or not lines[0].strip().startswith("QGC WPL 110"):
        raise MissionFileError(f"{source}: first line must be '{WPL_HEADER}'")
    items: list[MissionItem] = []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cols = line.split()
        if len(cols) != 12:
            raise MissionFileError(f"{source}:{lineno}: expected 12 columns, found {len(cols)}")
        try:
            frame = int(cols[2])
            scale = xy_scale(frame)
            items.append(MissionItem(
                seq=int(cols[0]), current=int(cols[1]), frame=frame, command=int(cols[3]),
                param1=float(cols[4]), param2=float(cols[5]), param3=float(cols[6]), param4=float(cols[7]),
                x=_scaled_int(cols[8], scale), y=_scaled_int(cols[9], scale), z=float(cols[10]),
                autocontinue=int(float(cols[11])),
            ))
        except (ValueError, InvalidOperation) as exc:
            raise MissionFileError(f"{source}:{lineno}: {exc}") from exc
    return items


def write_wpl(path: str | Path, items: list[MissionItem]) -> None:
    Path(path).write_text(format_wpl(items), encoding="utf-8")


def read_wpl(path: str | Path) -> list[MissionItem]:
    return parse_wpl(Path(path).read_text(encoding="utf-8"), source=str(path))


# --- QGroundControl .plan -------------------------------------------------------------------

def _json_param(value: float):
    return None if math.isnan(value) else value  # QGC writes NaN params as null


def _param_from_json(value) -> float:
    return float("nan") if value is None else float(value)


def plan_dict(items: list[MissionItem], home: tuple[float, float, float] | None = None,
              firmware_type: int = 3, vehicle_type: int = 1) -> dict:
    """A QGC ``.plan`` document (fileType Plan, mission version 2) holding ``items``.

    ``firmware_type`` 3 = MAV_AUTOPILOT_ARDUPILOTMEGA, ``vehicle_type`` 1 = MAV_TYPE_FIXED_WING.
    """
    plan_items = []
    for it in items:
        scale = xy_scale(it.frame)
        plan_items.append({
            "type": "SimpleItem",
            "autoContinue": bool(it.autocontinue),
            "command": it.command,
            "doJumpId": it.seq + 1,
            "frame": it.frame,
            "params": [_json_param(it.param1), _json_param(it.param2), _json_param(it.param3),
                       _json_param(it.param4), it.x / scale if scale != 1 else it.x,
                       it.y / scale if scale != 1 else it.y, _json_param(it.z)],
            # Not part of QGC's schema; kept so that seq/current/mission_type survive a round trip.
            "gcsPdm": {"seq": it.seq, "current": it.current, "missionType": it.mission_type},
        })
    if home is None:
        first = next((it for it in items if xy_scale(it.frame) != 1 and (it.x or it.y)), None)
        home = (first.x / 1e7, first.y / 1e7, 0.0) if first else (0.0, 0.0, 0.0)
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "gcs-pdm",
        "mission": {
            "version": 2,
            "firmwareType": firmware_type,
            "vehicleType": vehicle_type,
            "cruiseSpeed": 15,
            "hoverSpeed": 5,
            "plannedHomePosition": list(home),
            "items": plan_items,
        },
        "geoFence": {"version": 2, "circles": [], "polygons": []},
        "rallyPoints": {"version": 2, "points": []},
    }


def items_from_plan(doc: dict, source: str = "<plan>") -> list[MissionItem]:
    """Mission items of a ``.plan`` document. Complex items (surveys…) are refused by name."""
    if doc.get("fileType") != "Plan":
        raise MissionFileError(f"{source}: fileType is {doc.get('fileType')!r}, expected 'Plan'")
    raw_items = doc.get("mission", {}).get("items", [])
    items: list[MissionItem] = []
    for index, raw in enumerate(raw_items):
        if raw.get("type") != "SimpleItem":
            raise MissionFileError(f"{source}: item {index} is a {raw.get('type')!r}; only SimpleItem is supported "
                                   "(flatten complex items in QGroundControl before export)")
        try:
            params = raw["params"]
            frame = int(raw["frame"])
            scale = xy_scale(frame)
            extra = raw.get("gcsPdm", {})
            x = round(float(params[4] or 0.0) * scale)
            y = round(float(params[5] or 0.0) * scale)
            items.append(MissionItem(
                seq=int(extra.get("seq", index)), frame=frame, command=int(raw["command"]),
                current=int(extra.get("current", 1 if index == 0 else 0)),
                autocontinue=int(bool(raw.get("autoContinue", True))),
                param1=_param_from_json(params[0]), param2=_param_from_json(params[1]),
                param3=_param_from_json(params[2]), param4=_param_from_json(params[3]),
                x=x, y=y, z=_param_from_json(params[6]),
                mission_type=int(extra.get("missionType", 0)),
            ))
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            raise MissionFileError(f"{source}: item {index}: {exc!r}") from exc
    return items


def write_plan(path: str | Path, items: list[MissionItem], home: tuple[float, float, float] | None = None) -> None:
    Path(path).write_text(json.dumps(plan_dict(items, home), indent=2) + "\n", encoding="utf-8")


def read_plan(path: str | Path) -> list[MissionItem]:
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise MissionFileError(f"{path}: not JSON: {exc}") from exc
    return items_from_plan(doc, source=str(path))
