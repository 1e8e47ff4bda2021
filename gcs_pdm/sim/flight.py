"""Point-mass kinematics and guidance of the simulated aircraft (pure: floats in, floats out).

Positions are local east/north metres about home, altitude in metres above home. The aircraft is a
point that flies at an airspeed along a heading, turns at the rate its bank limit allows
(g tan(phi) / V), climbs and sinks within limits, and drifts with a constant wind. That is all the
truth the propulsion models need: airspeed, climb rate and altitude set the shaft power
(``gcs_pdm.models.powertrain.shaft_power``); the rest only has to look right on a map.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from gcs_pdm.models.powertrain import EDGE_540, G, Airframe


@dataclass(frozen=True)
class FlightLimits:
    """Handling limits of the point-mass aircraft."""

    max_bank_deg: float = 35.0
    max_climb_mps: float = 5.0
    max_sink_mps: float = 4.0
    airspeed_accel_mps2: float = 1.5
    vertical_accel_mps2: float = 1.5
    altitude_gain_per_s: float = 0.25  # climb-rate command per metre of altitude error
    acceptance_radius_m: float = 30.0  # ArduPlane WP_RADIUS default
    takeoff_accel_mps2: float = 3.0  # ground roll
    rotate_airspeed_mps: float = 16.0
    takeoff_climb_mps: float = 4.0
    rolling_friction: float = 0.05  # ground roll resistance / weight
    glide_slope_deg: float = 6.0  # landing approach
    flare_alt_m: float = 3.0
    flare_sink_mps: float = 0.8
    rollout_decel_mps2: float = 2.5
    failure_sink_mps: float = 3.0  # unpowered glide after a failure
    rtl_alt_m: float = 100.0


@dataclass
class Kinematics:
    """The aircraft's kinematic state; mutable, advanced in place by ``advance``."""

    east_m: float = 0.0
    north_m: float = 0.0
    alt_m: float = 0.0  # above home
    heading_rad: float = 0.0  # from north, clockwise
    airspeed_mps: float = 0.0
    climb_mps: float = 0.0
    on_ground: bool = True
    vel_east_mps: float = 0.0
    vel_north_mps: float = 0.0

    @property
    def groundspeed_mps(self) -> float:
        return math.hypot(self.vel_east_mps, self.vel_north_mps)


def wrap_pi(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def course_heading(course_rad: float, airspeed: float, wind_en: tuple[float, float]) -> float:
    """Heading that makes the ground track follow ``course_rad`` in a wind (crab angle)."""
    we, wn = wind_en
    if airspeed <= 1.0 or (we == 0.0 and wn == 0.0):
        return course_rad
    cross = we * math.cos(course_rad) - wn * math.sin(course_rad)
    return course_rad - math.asin(max(-1.0, min(1.0, cross / airspeed)))


def advance(k: Kinematics, dt: float, *, heading_cmd: float | None, airspeed_cmd: float, climb_cmd: float,
            limits: FlightLimits, wind_en: tuple[float, float] = (0.0, 0.0), airborne: bool = True,
            accel: float | None = None) -> None:
    """Move ``k`` by ``dt`` towards the commands within the limits (in place).

    ``heading_cmd`` None holds the heading. On the ground (``airborne`` False) the aircraft rolls
    along its heading, without wind drift, and cannot climb.
    """
    a = limits.airspeed_accel_mps2 if accel is None else accel
    dv = airspeed_cmd - k.airspeed_mps
    k.airspeed_mps = max(0.0, k.airspeed_mps + max(-a * dt, min(a * dt, dv)))
    if heading_cmd is not None and k.airspeed_mps > 1.0 and airborne:
        rate = G * math.tan(math.radians(limits.max_bank_deg)) / k.airspeed_mps
        err = wrap_pi(heading_cmd - k.heading_rad)
        k.heading_rad = wrap_pi(k.heading_rad + max(-rate * dt, min(rate * dt, err)))
    if airborne:
        climb_cmd = max(-limits.max_sink_mps, min(limits.max_climb_mps, climb_cmd))
        av = limits.vertical_accel_mps2 * dt
        k.climb_mps += max(-av, min(av, climb_cmd - k.climb_mps))
        k.climb_mps = max(-k.airspeed_mps, min(k.airspeed_mps, k.climb_mps))
    else:
        k.climb_mps = 0.0
    horizontal = math.sqrt(max(0.0, k.airspeed_mps ** 2 - k.climb_mps ** 2))
    we, wn = wind_en if airborne else (0.0, 0.0)
    k.vel_east_mps = horizontal * math.sin(k.heading_rad) + we
    k.vel_north_mps = horizontal * math.cos(k.heading_rad) + wn
    k.east_m += k.vel_east_mps * dt
    k.north_m += k.vel_north_mps * dt
    k.alt_m += k.climb_mps * dt
    if k.alt_m <= 0.0 and airborne and k.climb_mps < 0.0:
        k.alt_m = 0.0
        k.climb_mps = 0.0


def ground_roll_power(airspeed: float, accel: float, limits: FlightLimits, airframe: Airframe = EDGE_540) -> float:
    """Shaft power of the take-off roll: accelerating the mass against rolling friction.

    ``powertrain.shaft_power`` is a steady-flight polar and diverges at walking pace, so the roll up
    to the rotation speed is costed as m (a + mu g) v / eta instead (a few seconds of the flight).
    """
    force = airframe.mass_kg * (accel + limits.rolling_friction * G)
    return max(force * airspeed / airframe.eta_prop, airframe.min_shaft_power_w)


def altitude_command(alt_error_m: float, limits: FlightLimits) -> float:
    return alt_error_m * limits.altitude_gain_per_s
