"""The telemetry mapping a vehicle description implies (``gcs_pdm.mavlink.mapping`` configuration).

Packs are keyed by BATTERY_STATUS.id, motors by their ESC index (ESC_TELEMETRY_1_TO_4 carries
indices 0-3, ESC_TELEMETRY_5_TO_8 indices 4-7, ...). A reading the description says does not exist
is left out of the rule, so its frames carry None instead of the zero an ESC sends for it.
"""
from __future__ import annotations

import copy

from gcs_pdm.mavlink.mapping import default_mapping
from gcs_pdm.vehicle.description import VehicleDescription

_ESC_MESSAGE = ("ESC_TELEMETRY_1_TO_4", "ESC_TELEMETRY_5_TO_8", "ESC_TELEMETRY_9_TO_12", "ESC_TELEMETRY_13_TO_16",
                "ESC_TELEMETRY_17_TO_20", "ESC_TELEMETRY_21_TO_24", "ESC_TELEMETRY_25_TO_28", "ESC_TELEMETRY_29_TO_32")
_READING_FIELD = {"current": "current_a", "rpm": "rpm", "temperature": "temperature_c"}


def frame_mapping(desc: VehicleDescription) -> dict:
    """The default mapping with this vehicle's pack ids and ESC indices (for ``FrameMapper``)."""
    mapping = default_mapping()
    battery = mapping["BATTERY_STATUS"][0]
    battery["key"]["map"] = {str(p.mavlink_battery_id): p.name for p in desc.packs}
    esc_rule = mapping.pop("ESC_TELEMETRY_1_TO_4")[0]
    for motor in desc.motors:
        message = _ESC_MESSAGE[motor.esc_index // 4]
        readings = motor.readings.model_dump()
        fields = {k: v for k, v in esc_rule["fields"].items()
                  if readings[next(r for r, f in _READING_FIELD.items() if f == k)]}
        rules = mapping.setdefault(message, [])
        # one rule per distinct set of readings: motors that report the same things share it
        rule = next((r for r in rules if r["fields"].keys() == fields.keys()), None)
        if rule is None:
            rule = copy.deepcopy(esc_rule)
            rule["fields"] = fields
            rule["key"]["map"] = {}
            rules.append(rule)
        rule["key"]["map"][str(motor.esc_index % 4)] = motor.name
    return mapping


def waiting_mapping() -> dict:
    """The mapping while no description exists yet: packs and motors are not mapped at all (a
    BATTERY_STATUS id or an ESC index means nothing until the description names it)."""
    mapping = default_mapping()
    for message in [m for m in mapping if m == "BATTERY_STATUS" or m.startswith("ESC_TELEMETRY_")]:
        del mapping[message]
    return mapping


def envelope(desc: VehicleDescription):
    """The physical envelope of the description's packs (``gcs_pdm.mavlink.plausibility``)."""
    from gcs_pdm.mavlink.plausibility import PhysicalEnvelope

    return PhysicalEnvelope.from_packs({p.name: p.cells_series for p in desc.packs})
