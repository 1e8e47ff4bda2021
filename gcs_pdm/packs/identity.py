"""Which pack is in a slot (pure), in this order:

1. the autopilot's word: a serial number (SMART_BATTERY_INFO, ``BATT*_SERIAL_NUM``, ULog
   ``battery_status.serial_number``);
2. the operator's assignment ("pack P-17 is in slot battery0");
3. the slot's name, with a warning: packs rotated between slots or aircraft are then mixed up.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

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
