"""The one place pymavlink is configured: MAVLink 2 framing and the ``ardupilotmega`` dialect.

pymavlink picks its protocol version and dialect from environment variables read at import
time (default: MAVLink 1, dialect ``ardupilotmega`` or whatever the user's shell says), so this
module sets them before importing it and then re-selects the dialect in ``mavutil`` in case
another module imported pymavlink first. Everything in ``gcs_pdm.mavlink`` imports pymavlink
through here.
"""
from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

DIALECT = "ardupilotmega"
mavutil.set_dialect(DIALECT)

MAV_AUTOPILOT_INVALID = mavlink2.MAV_AUTOPILOT_INVALID
MAV_MODE_FLAG_SAFETY_ARMED = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED

# msgid -> pymavlink message class (field layout, CRC_EXTRA) for the pinned dialect.
MESSAGE_CLASSES: dict[int, type] = dict(mavlink2.mavlink_map)
MESSAGE_IDS_BY_NAME: dict[str, int] = {cls.msgname: msgid for msgid, cls in MESSAGE_CLASSES.items()}
CRC_EXTRA: dict[int, int] = {msgid: cls.crc_extra for msgid, cls in MESSAGE_CLASSES.items()}

__all__ = ["mavutil", "mavlink2", "DIALECT", "MESSAGE_CLASSES", "MESSAGE_IDS_BY_NAME", "CRC_EXTRA"]
