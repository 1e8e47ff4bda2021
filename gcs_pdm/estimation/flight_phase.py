"""Is the vehicle flying? The answer decides whether a time to cut-off can be predicted at all:
on the ground there is no flight load to extrapolate, and the status page must say so, not show a
number. Pure: ``flight_conditions.FlightConditions`` passes what it last heard.

The evidence follows the airframe:

* anything known to be disarmed is on the ground;
* EXTENDED_SYS_STATE ``landed_state`` (ArduCopter, PX4), when the vehicle sends it, is the
  autopilot's own verdict: on ground → not flying; in air, taking off, landing → flying;
* a fixed wing flies above ``FLYING_AIRSPEED_MPS`` (below it is a ground roll or a parked plane);
* a multirotor hovers at zero airspeed, so its evidence is power: an armed multirotor drawing at
  least ``HOVER_POWER_FRACTION`` of its description's hover shaft power is airborne (idling on the
  ground it spins its props at a few per cent of it), as is one climbing or in forward flight. A
  flight mode alone is not evidence: ArduCopter sits armed in AUTO or LOITER on the ground.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: below this airspeed a fixed wing is on the ground: no flight load to extrapolate
FLYING_AIRSPEED_MPS = 5.0
#: a multirotor drawing this share of its hover shaft power (electrical, so the motors' and
#: ESCs' losses only add to it) is holding itself up; ground idle is far below it
HOVER_POWER_FRACTION = 0.5
#: climb rate (m/s) that only an airborne vehicle shows (baro noise on the ground is ~0.1 m/s)
CLIMB_EVIDENCE_MPS = 0.5

MAV_LANDED_STATE_ON_GROUND = 1
LANDED_STATE_NAMES = {1: "on ground", 2: "in air", 3: "taking off", 4: "landing"}


@dataclass(frozen=True)
class FlightPhase:
    flying: bool
    #: what showed it (flying) or why there is no flight load to predict from (not flying)
    reason: str


def flight_phase(*, multirotor: bool, armed: bool | None, landed_state: int | None,
                 airspeed_mps: float | None, climb_mps: float | None, electrical_power_w: float | None,
                 hover_power_w: float | None) -> FlightPhase:
    """The flight phase from the latest telemetry (None: not heard). ``landed_state`` is
    EXTENDED_SYS_STATE's MAV_LANDED_STATE (0/None: not reported); ``hover_power_w`` the
    description's hover shaft power (multirotor only)."""
    if armed is False:
        return FlightPhase(False, "disarmed (HEARTBEAT)")
    if landed_state in LANDED_STATE_NAMES:
        said = LANDED_STATE_NAMES[landed_state]
        return FlightPhase(landed_state != MAV_LANDED_STATE_ON_GROUND, f"{said} (EXTENDED_SYS_STATE)")
    speed = airspeed_mps if airspeed_mps is not None and math.isfinite(airspeed_mps) else None
    if not multirotor:
        if speed is None:
            return FlightPhase(False, "no airspeed telemetry yet")
        if speed >= FLYING_AIRSPEED_MPS:
            return FlightPhase(True, f"airspeed {speed:.1f} m/s")
        return FlightPhase(False, f"on the ground: airspeed {speed:.1f} m/s below {FLYING_AIRSPEED_MPS:g} m/s")
    if speed is not None and speed >= FLYING_AIRSPEED_MPS:
        return FlightPhase(True, f"forward flight at {speed:.1f} m/s")
    if climb_mps is not None and math.isfinite(climb_mps) and climb_mps >= CLIMB_EVIDENCE_MPS:
        return FlightPhase(True, f"climbing at {climb_mps:.1f} m/s")
    power = electrical_power_w if electrical_power_w is not None and math.isfinite(electrical_power_w) else None
    if power is None or hover_power_w is None or not math.isfinite(hover_power_w):
        return FlightPhase(False, "no battery power telemetry yet to tell hover from the ground")
    if power >= HOVER_POWER_FRACTION * hover_power_w:
        return FlightPhase(True, f"drawing {power:.0f} W, hover needs about {hover_power_w:.0f} W")
    return FlightPhase(False, f"on the ground: drawing {power:.0f} W, below half the {hover_power_w:.0f} W "
                              f"hover needs")
