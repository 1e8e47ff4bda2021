"""Build MAVLink packets and tlogs for tests with pymavlink's own encoder."""
from __future__ import annotations

import struct

from gcs_pdm.mavlink.dialect import mavlink2


class PacketFactory:
    """Encodes messages as a given system/component, MAVLink 2 by default, 1 on request."""

    def __init__(self, sysid: int = 1, compid: int = 1, mavlink1: bool = False, numbered: bool = False):
        """``numbered``: count the packets' sequence numbers as a real sender does (pymavlink's
        ``MAVLink.send`` counts, ``msg.pack`` alone does not: every packet then carries 0)."""
        dialect = mavlink2
        if mavlink1:
            from pymavlink.dialects.v10 import ardupilotmega as dialect
        self.mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.numbered = numbered

    def pack(self, msg) -> bytes:
        out = msg.pack(self.mav)
        if self.numbered:
            self.mav.seq = (self.mav.seq + 1) % 256
        return out

    # Shorthands for the telemetry the service maps.
    def heartbeat(self, armed: bool = True, custom_mode: int = 10):
        base = 0x80 if armed else 0
        return self.pack(self.mav.heartbeat_encode(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                   base | mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode,
                                                   mavlink2.MAV_STATE_ACTIVE))

    def battery(self, pack_id: int, millivolts: list[int], centiamps: int, centidegc: int):
        cells = (list(millivolts) + [65535] * 10)[:10]
        return self.pack(self.mav.battery_status_encode(pack_id, 0, 0, centidegc, cells, centiamps, -1, -1, -1))

    def esc(self, currents_ca, rpms, temps_c):
        return self.pack(self.mav.esc_telemetry_1_to_4_encode(temps_c, [2200] * 4, currents_ca, [0] * 4, rpms,
                                                              [0] * 4))

    def position(self, time_boot_ms: int, lat_e7: int = 473977419, lon_e7: int = 85455938):
        return self.pack(self.mav.global_position_int_encode(time_boot_ms, lat_e7, lon_e7, 500_000, 100_000,
                                                             1500, -200, 30, 9000))

    def pressure(self, time_boot_ms: int, centidegc: int = 2150):
        return self.pack(self.mav.scaled_pressure_encode(time_boot_ms, 1013.0, 0.5, centidegc))

    def hud(self, airspeed=18.0, throttle=55):
        return self.pack(self.mav.vfr_hud_encode(airspeed, 17.0, 90, throttle, 120.0, 1.5))


def tlog_record(timestamp_us: int, packet: bytes) -> bytes:
    return struct.pack(">Q", timestamp_us) + packet
