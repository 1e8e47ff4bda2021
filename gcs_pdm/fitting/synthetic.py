"""Synthetic flight logs with known "true" parameters, for tests, the benchmark and demos.

A flight is flown through the real models: a random but plausible mission profile (ground idle,
climb-out, cruise legs at varying airspeed with climbs and descents, descent, landing, idle) gives
shaft power (``powertrain.shaft_power`` at the ISA density), the one kernel's closed-loop powertrain
(``topology.simulate_powertrain(record=True)``) gives every pack's current, voltage and temperature
and both motors' current and temperature. Then what real logs have is added, seeded: sensor noise
and quantisation, and optionally (:class:`Damage`) drop-outs, short gaps, duplicated and
backwards timestamps, spikes, a stuck temperature sensor and a stretch of sign-flipped current.

The motor log is the mean motor current and one bracket temperature (the mean of the two motors'
temperatures: the sensor sits between them), as in the paper.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gcs_pdm.logs.tables import BATTERY, MOTOR, Flight
from gcs_pdm.models import kernel, topology
from gcs_pdm.models.params import PACK_NAMES, ParameterSet, builtin, motor_from_vector, perturbed
from gcs_pdm.models.powertrain import Limits, air_density, ambient_temperature, shaft_power


@dataclass(frozen=True)
class Noise:
    """Sensor noise (1 sigma) and quantisation of the logged values."""

    voltage_v: float = 0.03
    current_a: float = 0.10
    temperature_c: float = 0.25
    ambient_c: float = 0.20
    voltage_step: float = 0.001
    current_step: float = 0.01
    temperature_step: float = 0.01


@dataclass(frozen=True)
class Damage:
    """Inconsistencies injected into every log of a flight (counts per log)."""

    dropout_fraction: float = 0.01
    gaps: int = 2
    gap_s: tuple[float, float] = (4.0, 20.0)
    duplicated_rows: int = 5
    backwards_swaps: int = 3
    voltage_spikes: int = 5
    temperature_spikes: int = 3
    stuck_temperature_s: int = 40
    sign_flip_s: int = 20


NO_DAMAGE = Damage(0.0, 0, (0.0, 0.0), 0, 0, 0, 0, 0, 0)


@dataclass(frozen=True)
class SyntheticFlight:
    name: str
    packs: dict[str, Flight]       # one battery log per pack
    motor: Flight                  # mean motor current, bracket temperature
    soc0: np.ndarray               # (4,) true initial state of charge per pack
    truth: ParameterSet
    clean: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # noise-free signals


def synthetic_truth(seed: int = 7, spread: float = 0.2, base: str = "paper_si") -> ParameterSet:
    """Hidden "true" parameters for synthetic tests: every learnable parameter of ``base`` moved by up
    to ``spread`` (log-uniform, seeded). The motor's R_w and I_0, which the fitter does not learn
    (data-sheet values), stay those of ``base``."""
    b = builtin(base)
    p = perturbed(b, np.random.default_rng(seed), rel=spread, name=f"synthetic_truth_{seed}")
    m = b.motor_vector().copy()
    mv = p.motor_vector()
    for k in (kernel.M_CT, kernel.M_H, kernel.M_PIRON):
        m[k] = mv[k]
    return p.replace(motor=motor_from_vector(m))


def mission_profile(rng: np.random.Generator, duration_s: float = 1800.0, dt: float = 1.0,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time_s, airspeed m/s, climb m/s, altitude m) of a plausible flight: idle, climb-out, legs, landing.

    Airspeed 0 marks the ground (motors idling). Returns time, airspeed, climb, altitude.
    """
    n = int(round(duration_s / dt)) + 1
    t = np.arange(n) * dt
    idle0 = int(rng.uniform(20, 45) / dt)
    idle1 = int(rng.uniform(15, 30) / dt)
    airspeed = np.zeros(n)
    climb = np.zeros(n)
    air = slice(idle0, n - idle1)
    n_air = n - idle0 - idle1
    # cruise legs: piecewise-constant commands smoothed by the airframe's response (~5 s)
    k = 0
    cmd_v = np.empty(n_air)
    cmd_c = np.empty(n_air)
    alt_target = rng.uniform(80, 250)
    alt = 0.0
    while k < n_air:
        leg = int(rng.uniform(30, 180) / dt)
        v = rng.uniform(18.0, 28.0)
        c = rng.choice([0.0, 0.0, 0.0, 0.0, 2.0, 3.0, -2.0, -3.0])
        cmd_v[k:k + leg] = v
        cmd_c[k:k + leg] = c
        k += leg
    # climb-out first, descent at the end, altitude kept within [30, 400] m
    alts = np.empty(n_air)
    for i in range(n_air):
        remaining = (n_air - i) * dt
        if alt < alt_target and i * dt < 120:
            c = 5.0
        elif remaining < alt / 2.5 + 20:
            c = -2.5 if alt > 0 else 0.0
        else:
            c = cmd_c[i]
            if (alt > 400 and c > 0) or (alt < 30 and c < 0):
                c = 0.0
        cmd_c[i] = c
        alt = max(alt + c * dt, 0.0)
        alts[i] = alt
    a = 1.0 - np.exp(-dt / 5.0)
    vs = np.empty(n_air)
    cs = np.empty(n_air)
    v_f, c_f = 16.0, 0.0
    for i in range(n_air):
        v_f += a * (cmd_v[i] - v_f)
        c_f += a * (cmd_c[i] - c_f)
        vs[i], cs[i] = v_f, c_f
    airspeed[air] = vs
    climb[air] = cs
    altitude = np.zeros(n)
    altitude[air] = alts
    return t, airspeed, climb, altitude


def _add_noise(x: np.ndarray, sigma: float, step: float, rng: np.random.Generator) -> np.ndarray:
    y = x + rng.normal(0.0, sigma, size=x.shape) if sigma > 0 else x.copy()
    return np.round(y / step) * step if step > 0 else y


def _damage(cols: dict[str, np.ndarray], measured: tuple[str, ...], d: Damage, rng: np.random.Generator,
            ) -> dict[str, np.ndarray]:
    cols = {k: v.copy() for k, v in cols.items()}
    n = cols["time_s"].size
    # spikes, stuck sensor and a sign slip first, on the regular time base
    if "voltage_v" in cols and d.voltage_spikes:
        idx = rng.choice(np.arange(50, n - 50), d.voltage_spikes, replace=False)
        cols["voltage_v"][idx] += rng.choice([-1.0, 1.0], idx.size) * rng.uniform(2.0, 6.0, idx.size)
    if d.temperature_spikes:
        idx = rng.choice(np.arange(50, n - 50), d.temperature_spikes, replace=False)
        cols["temperature_c"][idx] += rng.uniform(10.0, 30.0, idx.size)
    if d.stuck_temperature_s:
        a = int(rng.integers(n // 4, n // 2))
        cols["temperature_c"][a:a + d.stuck_temperature_s] = cols["temperature_c"][a]
    if d.sign_flip_s:
        a = int(rng.integers(n // 2, 3 * n // 4))
        cols["current_a"][a:a + d.sign_flip_s] *= -1.0
    # drop-outs: single missing values in any column but time
    for k in cols:
        if k != "time_s" and d.dropout_fraction > 0:
            miss = rng.random(n) < d.dropout_fraction
            miss[:15] = False  # keep the first samples: the initial state comes from them
            cols[k][miss] = np.nan
    keep = np.ones(n, dtype=bool)
    for _ in range(d.gaps):
        length = int(rng.uniform(*d.gap_s))
        a = int(rng.integers(60, n - 60 - length))
        keep[a:a + length] = False
    cols = {k: v[keep] for k, v in cols.items()}
    n = cols["time_s"].size
    if d.duplicated_rows:
        idx = np.sort(rng.choice(np.arange(20, n - 20), d.duplicated_rows, replace=False))
        order = np.sort(np.concatenate([np.arange(n), idx]))
        cols = {k: v[order] for k, v in cols.items()}
        n = cols["time_s"].size
    for _ in range(d.backwards_swaps):
        a = int(rng.integers(20, n - 20))
        for k in cols:
            cols[k][[a, a + 1]] = cols[k][[a + 1, a]]
    return cols


def generate_flight(truth: ParameterSet, seed: int, *, name: str | None = None, duration_s: float = 1800.0,
                    dt: float = 1.0, soc0: float | np.ndarray | None = None, ground_temp_c: float | None = None,
                    noise: Noise = Noise(), damage: Damage | None = Damage()) -> SyntheticFlight:
    """One flight of the whole vehicle flown with ``truth``: four battery logs and one motor log."""
    rng = np.random.default_rng(seed)
    name = name or f"syn{seed:04d}"
    t, airspeed, climb, altitude = mission_profile(rng, duration_s, dt)
    ground = float(rng.uniform(5.0, 32.0)) if ground_temp_c is None else float(ground_temp_c)
    amb = ambient_temperature(altitude, ground)
    rho = air_density(altitude, ground)
    power = np.where(airspeed > 0, shaft_power(airspeed, climb, rho), 0.0)
    if soc0 is None:
        soc0 = rng.uniform(0.85, 1.0, size=4)
    soc0 = np.broadcast_to(np.asarray(soc0, dtype=np.float64), (4,)).copy()
    pm = truth.pack_matrix()
    t_pack0 = ground + rng.uniform(0.0, 6.0, size=4)
    # logging starts with the motors spun up at idle: both R-C pairs settled at the no-load current
    x0 = kernel.initial_pack_state(pm, soc0, t_pack0, truth.motor.I_0)
    t_motor0 = np.full(2, ground + rng.uniform(0.0, 4.0))
    step = np.diff(t, prepend=t[0])
    run = topology.simulate_powertrain(pm[None], truth.motor_vector()[None], x0[None], t_motor0[None], step, power, amb,
                                     limits=Limits().as_tuple(), stop_on_failure=True, record=True)
    if run.fail_step[0] >= 0:
        # the pilot lands when a pack reaches its cut-off: the log ends there
        end = int(run.fail_step[0])
        t, amb = t[:end], amb[:end]
    else:
        end = t.size
    pack_current, pack_voltage = run.pack_current[0, :end], run.pack_voltage[0, :end]
    pack_temp, motor_current, motor_temp = run.pack_temp[0, :end], run.motor_current[0, :end], run.motor_temp[0, :end]
    packs: dict[str, Flight] = {}
    clean: dict[str, dict[str, np.ndarray]] = {}
    for b, pack in enumerate(PACK_NAMES):
        truth_cols = {"time_s": t, "current_a": pack_current[:, b], "voltage_v": pack_voltage[:, b],
                      "temperature_c": pack_temp[:, b], "ambient_c": amb}
        clean[pack] = truth_cols
        cols = {"time_s": t.copy(),
                "current_a": _add_noise(truth_cols["current_a"], noise.current_a, noise.current_step, rng),
                "voltage_v": _add_noise(truth_cols["voltage_v"], noise.voltage_v, noise.voltage_step, rng),
                "temperature_c": _add_noise(truth_cols["temperature_c"], noise.temperature_c, noise.temperature_step, rng),
                "ambient_c": _add_noise(amb, noise.ambient_c, noise.temperature_step, rng)}
        if damage is not None:
            cols = _damage(cols, ("voltage_v", "temperature_c"), damage, rng)
        packs[pack] = Flight(name=f"{name}_{pack}", kind=BATTERY, source={"synthetic": name, "pack": pack, "seed": seed},
                             **cols)
    motor_truth = {"time_s": t, "current_a": motor_current.mean(axis=1),
                   "temperature_c": motor_temp.mean(axis=1), "ambient_c": amb}
    clean["motor"] = motor_truth
    cols = {"time_s": t.copy(),
            "current_a": _add_noise(motor_truth["current_a"], noise.current_a, noise.current_step, rng),
            "temperature_c": _add_noise(motor_truth["temperature_c"], noise.temperature_c, noise.temperature_step, rng),
            "ambient_c": _add_noise(amb, noise.ambient_c, noise.temperature_step, rng)}
    if damage is not None:
        cols = _damage(cols, ("temperature_c",), damage, rng)
    motor = Flight(name=f"{name}_motor", kind=MOTOR, source={"synthetic": name, "seed": seed}, **cols)
    return SyntheticFlight(name=name, packs=packs, motor=motor, soc0=soc0, truth=truth, clean=clean)


def generate_flights(truth: ParameterSet, n: int, seed: int = 0, **kw) -> list[SyntheticFlight]:
    """``n`` independent flights, seeds ``seed``, ``seed + 1``, …"""
    return [generate_flight(truth, seed + i, **kw) for i in range(n)]
