"""The provisional vehicle description of a tlog: the I/O shell that feeds a tlog's messages to
the pure derivation (``gcs_pdm.vehicle.provisional.ProvisionalObserver``), as
``gcs_pdm.logs.provisional_vehicle`` does for an autopilot's own log."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from gcs_pdm.mavlink.tlog import tlog_message_columns, tlog_message_dicts
from gcs_pdm.vehicle.description import VehicleDescription, VehicleError
from gcs_pdm.vehicle.provisional import OBSERVED_MESSAGES, ProvisionalObserver


def observe_tlog(path: str | Path, name: str | None = None,
                 capacities: Mapping[int, float] | None = None) -> tuple[VehicleDescription, list[str]]:
    """The provisional description of a tlog: its BATTERY_STATUS messages (most of what it reads)
    folded as columns at once, the rest message by message (the project's own tlog scanner decodes
    only these, with the fields pymavlink's ``to_dict()`` gives)."""
    path = Path(path)
    if not path.exists():
        raise VehicleError(f"{path}: no such file")
    obs = ProvisionalObserver()
    for msg_name, fields in tlog_message_dicts(path, [n for n in OBSERVED_MESSAGES if n != "BATTERY_STATUS"]):
        obs.observe(msg_name, fields)
    obs.observe_batteries(tlog_message_columns(path, "BATTERY_STATUS"))
    return obs.derive(name or f"provisional-{path.stem}", capacities)
