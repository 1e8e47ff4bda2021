"""Multirotor power from momentum theory (docs/vehicles.md gives the parameters and their sources).

For a vehicle of mass m on n rotors of diameter D (disc area A = n π D²/4) at air density ρ:

* hover: thrust T = m g; induced velocity v_h = √(T / (2 ρ A)); ideal power T v_h. The figure of
  merit FM (ideal / actual rotor power, 0.6–0.75 for small propellers) covers profile and
  non-ideal losses: P_hover = T v_h / FM.
* forward flight at airspeed V (level, small disc tilt): the body's parasite drag D = ½ ρ V² f
  (f the equivalent flat-plate area) tilts the thrust, T = √((m g)² + D²); the induced velocity
  solves Glauert's v⁴ + V² v² = v_T⁴ (v_T the hover induced velocity at thrust T), so
  v² = (√(V⁴ + 4 v_T⁴) − V²) / 2. Rotor power = T v / κ + P_profile (1 + 3 V²/V_tip²) + D V,
  with the induced factor κ and the hover profile power split from FM: at hover,
  T v_h (1/FM − 1) is profile power (the classic simplification κ = 1).
* climb at rate w adds m g w (the work against gravity; a descent gives none back).

Shaft power is what the motors deliver; the kernel turns it into current with the motor model.
"""
from __future__ import annotations

import numpy as np

G = 9.80665
SEA_LEVEL_DENSITY = 1.225


def disc_area(n_rotors: int, rotor_diameter_m: float) -> float:
    return n_rotors * np.pi * rotor_diameter_m ** 2 / 4.0


def hover_power(mass_kg: float, n_rotors: int, rotor_diameter_m: float, figure_of_merit: float,
                density: float | np.ndarray = SEA_LEVEL_DENSITY) -> np.ndarray:
    """Shaft power (W) to hover."""
    thrust = mass_kg * G
    v_h = np.sqrt(thrust / (2.0 * np.asarray(density, dtype=np.float64) * disc_area(n_rotors, rotor_diameter_m)))
    return thrust * v_h / figure_of_merit


def shaft_power(airspeed: np.ndarray | float, climb_rate: np.ndarray | float, mass_kg: float, n_rotors: int,
                rotor_diameter_m: float, figure_of_merit: float, drag_area_m2: float, tip_speed_mps: float,
                density: np.ndarray | float = SEA_LEVEL_DENSITY) -> np.ndarray:
    """Shaft power (W) at an airspeed (m/s) and climb rate (m/s, up positive)."""
    v = np.maximum(np.asarray(airspeed, dtype=np.float64), 0.0)
    w = np.asarray(climb_rate, dtype=np.float64)
    rho = np.asarray(density, dtype=np.float64)
    area = disc_area(n_rotors, rotor_diameter_m)
    weight = mass_kg * G
    drag = 0.5 * rho * v * v * drag_area_m2
    thrust = np.sqrt(weight * weight + drag * drag)
    v_t2 = thrust / (2.0 * rho * area)                      # v_T²
    v_i = np.sqrt((np.sqrt(v ** 4 + 4.0 * v_t2 * v_t2) - v * v) / 2.0)
    hover_ideal = weight * np.sqrt(weight / (2.0 * rho * area))
    profile = hover_ideal * (1.0 / figure_of_merit - 1.0) * (1.0 + 3.0 * (v / tip_speed_mps) ** 2)
    return thrust * v_i + profile + drag * v + weight * np.maximum(w, 0.0)
