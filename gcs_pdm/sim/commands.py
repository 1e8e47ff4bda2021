"""COMMAND_LONG / SET_MODE handling of the simulated vehicle: arm, mission start, modes, RTL,
set current item, message intervals, message requests (AUTOPILOT_VERSION and the telemetry messages), and
PARAM_REQUEST_READ of the battery capacity parameters. Every COMMAND_LONG gets a COMMAND_ACK (MAV_RESULT_UNSUPPORTED
for the commands this vehicle does not know)."""
from __future__ import annotations

import logging

from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.sim.model import MODE_RTL, PLANE_MODES, VehicleModel
from gcs_pdm.sim.telemetry import DEFAULT_RATES, Telemetry

log = logging.getLogger(__name__)

_MODE_BY_NUMBER = {number: name for name, number in PLANE_MODES.items()}
_FORCE_DISARM_MAGIC = 21196
_MSG_NAME_BY_ID = {cls.id: cls.msgname for cls in mavlink2.mavlink_map.values()}


class CommandHandler:
    def __init__(self, model: VehicleModel, telemetry: Telemetry, system_id: int = 1, component_id: int = 1):
        self.model = model
        self.telemetry = telemetry
        self.system_id = system_id
        self.component_id = component_id
        self.mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._reply: list = []

    def handle(self, msg) -> list:
        mtype = msg.get_type()
        if mtype == "SET_MODE":
            if msg.target_system == self.system_id:
                name = _MODE_BY_NUMBER.get(int(msg.custom_mode))
                if name is not None:
                    self.model.set_mode(name)
            return []
        if mtype == "PARAM_REQUEST_READ":
            return self._param_value(msg)
        if mtype != "COMMAND_LONG":
            return []
        if msg.target_system not in (0, self.system_id) or msg.target_component not in (0, self.component_id):
            return []
        self._reply: list = []
        result, text = self._command(int(msg.command), msg)
        out = [self.mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())]
        if text:
            out.append(self.mav.statustext_encode(mavlink2.MAV_SEVERITY_WARNING, text.encode()[:50]))
        return out + self._reply

    def _param_value(self, msg) -> list:
        """PARAM_REQUEST_READ by name: ArduPilot's battery capacity parameters (BATT_CAPACITY for the
        first monitor, BATTn_CAPACITY for the n-th), as a GCS reads them; other names go unanswered,
        as an autopilot leaves a name it does not have."""
        if msg.target_system not in (0, self.system_id):
            return []
        name = msg.param_id.decode(errors="replace") if isinstance(msg.param_id, bytes) else str(msg.param_id)
        name = name.rstrip("\x00")
        monitor = 1 if name == "BATT_CAPACITY" else (int(name[4]) if len(name) == 14 and name.startswith("BATT")
                                                       and name[4].isdigit() and name.endswith("_CAPACITY") else 0)
        capacities = self.model.battery_capacities_mah()
        if monitor < 1 or monitor - 1 not in capacities:
            return []
        return [self.mav.param_value_encode(name.encode(), capacities[monitor - 1], mavlink2.MAV_PARAM_TYPE_INT32,
                                            len(capacities), monitor - 1)]

    def autopilot_version(self):
        """What MAVSDK and QGroundControl ask first: MAVLink 2 and the INT mission protocol."""
        caps = (mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT)
        version = (4 << 24) | (5 << 16) | (0 << 8) | 255  # "4.5.0 official", ArduPlane-like
        return self.mav.autopilot_version_encode(caps, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
                                                 0x51D000000001)

    def _command(self, cmd: int, msg) -> tuple[int, str]:
        ok, fail = mavlink2.MAV_RESULT_ACCEPTED, mavlink2.MAV_RESULT_FAILED
        m = self.model
        if cmd == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
            if msg.param1 >= 0.5:
                good, why = m.arm()
            else:
                good, why = m.disarm(force=int(msg.param2) == _FORCE_DISARM_MAGIC)
            return (ok if good else fail), why
        if cmd == mavlink2.MAV_CMD_MISSION_START:
            good, why = m.start_mission()
            return (ok if good else fail), why
        if cmd == mavlink2.MAV_CMD_DO_SET_MODE:
            name = _MODE_BY_NUMBER.get(int(msg.param2))
            if name is None:
                return mavlink2.MAV_RESULT_DENIED, f"Mode {int(msg.param2)} not supported"
            m.set_mode(name)
            return ok, ""
        if cmd == mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            m.set_mode(MODE_RTL)
            return ok, ""
        if cmd == mavlink2.MAV_CMD_DO_SET_MISSION_CURRENT:
            return (ok if m.set_current(int(msg.param1)) else fail), ""
        if cmd == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = _MSG_NAME_BY_ID.get(int(msg.param1))
            if name not in DEFAULT_RATES:
                return mavlink2.MAV_RESULT_DENIED, ""
            interval_us = msg.param2
            if interval_us < 0:
                self.telemetry.set_rate(name, 0.0)
            elif interval_us == 0:
                self.telemetry.set_rate(name, self.telemetry.config.rates_hz.get(name, DEFAULT_RATES[name]))
            else:
                self.telemetry.set_rate(name, 1e6 / interval_us)
            return ok, ""
        if cmd == mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES or (
                cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION):
            self._reply.append(self.autopilot_version())
            return ok, ""
        if cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            name = _MSG_NAME_BY_ID.get(int(msg.param1))
            if name not in DEFAULT_RATES:
                return mavlink2.MAV_RESULT_DENIED, ""
            self._reply.extend(self.telemetry.build(name, m.state()))
            return ok, ""
        return mavlink2.MAV_RESULT_UNSUPPORTED, ""
