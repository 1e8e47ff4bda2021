"""Which pack is in a slot (pure), in this order:

1. the autopilot's word: a serial number (SMART_BATTERY_INFO or BATTERY_INFO ``serial_number``,
   ``BATT*_SERIAL_NUM``, ULog ``battery_status.serial_number``);
2. the operator's assignment ("pack P-17 is in slot battery0");
3. the slot's name, with a warning: packs rotated between slots or aircraft are then mixed up.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

#: the MAVLink messages whose ``serial_number`` names the pack in battery ``id``: SMART_BATTERY_INFO
#: (common.xml, char[16]) and BATTERY_INFO (char[32]; in the development dialect, which pymavlink
#: 2.4.50's ardupilotmega does not include: read when a dialect decodes it)
SERIAL_MESSAGES = ("SMART_BATTERY_INFO", "BATTERY_INFO")

AUTOPILOT, OPERATOR, SLOT = "autopilot serial", "operator assignment", "slot name"


@dataclass(frozen=True)
class PackIdentity:
    pack_id: str
    source: str
    warning: str | None = None


def identify(slot: str, serial: str | None, assignments: Mapping[str, str] | None = None) -> PackIdentity:
    if serial:
        return PackIdentity(str(serial), AUTOPILOT)
    assigned = (assignments or {}).get(slot)
    if assigned:
        return PackIdentity(str(assigned), OPERATOR)
    return PackIdentity(slot, SLOT, f"no serial number from the autopilot and no operator assignment for slot "
                                    f"{slot}: its flights are kept under the slot's name (assign the pack to tell "
                                    f"packs apart)")


def serial_text(raw) -> str | None:
    """A MAVLink char[] serial as text; None for "not provided" (all NULs, or blank)."""
    if isinstance(raw, (bytes, bytearray)):
        raw = raw.decode("ascii", "replace")
    text = str(raw or "").split("\x00", 1)[0].strip()
    return text or None
