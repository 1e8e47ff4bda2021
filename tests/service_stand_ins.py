"""Stand-ins for a live loop's link and mission client in tests that feed it frames directly
(``LiveLoop.process``): a link that records what the service sends and relays no messages, and a
vehicle with no mission."""
from __future__ import annotations


class FakeLink:
    def __init__(self):
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        self.mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=195)
        self.sent = []
        self.received = 0
        self.target_system, self.target_component = 1, 1

    def add_frame_listener(self, cb):
        pass

    def wait_for_vehicle(self, timeout=10.0):
        return 1, 1

    def send(self, msg):
        self.sent.append(msg)


class NoMissions:
    def download(self):
        return []


def fly_rested_pack(loop, slot: str, cells: int, capacity_ah: float, resistance_ohm: float, until_s: float,
                    chemistry: str = "lipo", rated_ah: float | None = None) -> None:
    """One flight of one pack, a frame a second: rested 120 s, armed, a climb (25 A) and a cruise
    (12 A), disarmed at 1000 s, rested until ``until_s``; the voltage is the rested voltage of the
    chemistry's curve (the one the service reads capacity on) at the charge drawn, less the
    resistance's drop."""
    import numpy as np

    from gcs_pdm.frames import PackFrame, StatusFrame
    from gcs_pdm.packs.cell_curves import capacity_reading, rested_cell_voltage

    reading = capacity_reading(chemistry, rated_ah or capacity_ah)
    drawn = 0.0
    for t in np.arange(0.0, until_s, 1.0):
        armed = 120 <= t < 1000
        i = 0.0 if not armed or t < 130 or t > 990 else (25.0 if t < 190 else 12.0)
        drawn += i / 3600.0
        ocv = rested_cell_voltage(reading, capacity_ah, drawn) * cells
        loop.process(StatusFrame(float(t), armed, "AUTO", 4))
        loop.process(PackFrame(float(t), slot, float(ocv - i * resistance_ohm), i, 25.0))
