"""Seeded synthetic flights as telemetry frames, with their truth — test and evaluation data.

A flight is a shaft-power profile flown through ``topology.simulate_powertrain(record=True)`` on a
"true" parameter set, optionally with a motor fault switched on at a given time (the kernel holds a
fault constant over a call, so the flight is flown in two segments, the second starting from the
first one's final state) and optionally with degraded packs (capacity loss, resistance rise). The
recorded truth is turned into ``gcs_pdm.frames`` objects with sensor noise, quantisation, random
drop-outs, a burst outage and spikes, at uneven sample times, like a real telemetry stream.

Pure: numpy in, frames out; the caller passes the ``numpy.random.Generator``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gcs_pdm.frames import AirdataFrame, AmbientFrame, MotorFrame, PackFrame
from gcs_pdm.models import kernel, topology
from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES, ParameterSet, degraded
from gcs_pdm.models.powertrain import (Limits, PowertrainState, air_density, ambient_temperature, shaft_power,
                                       shaft_rpm)


@dataclass(frozen=True)
class SensorNoise:
    voltage_v: float = 0.03
    current_a: float = 0.25
    temperature_c: float = 0.3
    rpm: float = 25.0
    #: probability that any one frame is lost
    drop_rate: float = 0.03
    #: probability that a delivered value is a spike (wild outlier)
    spike_rate: float = 0.003
    #: one burst outage of all telemetry, s (0: none)
    outage_s: float = 8.0


@dataclass(frozen=True)
class PackDegradation:
    """A pack worse than its parameter set says: capacity scaled by ``capacity``, R_s and R_cp0 by
    ``resistance``."""

    pack: str
    capacity: float = 1.0
    resistance: float = 1.0


@dataclass
class SyntheticFlight:
    frames: list                 # time-ordered gcs_pdm.frames objects
    time_s: np.ndarray           # (n,) truth sample times
    shaft_power_w: np.ndarray    # (n,) demanded shaft power
    ambient_c: np.ndarray        # (n,)
    soc: np.ndarray              # (n, 4) true SoC
    pack_temp_c: np.ndarray      # (n, 4)
    motor_temp_c: np.ndarray     # (n, 2)
    fault_motor: str | None = None
    fault_magnitude: float = 0.0
    fault_time_s: float | None = None
    degradation: tuple = ()
    truth: ParameterSet | None = None
    info: dict = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])


def mission_profile(rng: np.random.Generator, duration_s: float = 1200.0, step_s: float = 0.5,
                    ground_temp_c: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A random but plausible flight: climb, cruise legs at varying speed and altitude, descent.

    Returns (time, shaft power W, ambient °C, rpm-density kg/m³), uneven steps around ``step_s``."""
    n = int(duration_s / step_s)
    dt = step_s * rng.uniform(0.8, 1.2, size=n)
    dt[0] = 0.0
    t = np.cumsum(dt)
    airspeed = np.empty(n)
    climb = np.zeros(n)
    # legs of 60–240 s, each with its own speed and climb/descent
    k = 0
    while k < n:
        length = int(rng.uniform(60, 240) / step_s)
        airspeed[k:k + length] = rng.uniform(20.0, 32.0)
        climb[k:k + length] = rng.choice([0.0, 0.0, 0.0, 1.5, -1.5])
        k += length
    climb[: int(60 / step_s)] = 4.0       # initial climb
    airspeed[: int(60 / step_s)] = 22.0
    climb[-int(60 / step_s):] = -2.0      # final descent
    alt = np.clip(np.cumsum(climb * dt), 0.0, 600.0)
    rho = air_density(alt, ground_temp_c)
    ambient = ambient_temperature(alt, ground_temp_c)
    power = shaft_power(airspeed, climb, rho)
    return t, power, ambient, rho


def degrade(params: ParameterSet, degradation: tuple[PackDegradation, ...]) -> ParameterSet:
    out = params
    for d in degradation:
        out = degraded(out, d.pack, d.capacity, d.resistance)
    return out


def fly_synthetic(truth: ParameterSet, rng: np.random.Generator, *, duration_s: float = 1200.0,
                  fault_motor: str | None = None, fault_magnitude: float = 0.0, fault_time_s: float | None = None,
                  degradation: tuple[PackDegradation, ...] = (), noise: SensorNoise = SensorNoise(),
                  initial_soc: float = 1.0, ground_temp_c: float = 20.0, step_s: float = 0.5,
                  pack_every: int = 2, limits: Limits = Limits()) -> SyntheticFlight:
    """Fly ``truth`` (plus ``degradation``) through a random mission and return noisy frames.

    Motor frames come every sample (≈2 Hz), pack frames every ``pack_every`` samples. The flight
    ends at the vehicle's first failure under ``limits`` (``info['failed_at_s']``)."""
    t, power, ambient, rho = mission_profile(rng, duration_s, step_s, ground_temp_c)
    flown = degrade(truth, degradation)
    n = t.size
    dt = np.diff(t, prepend=t[0])
    state = PowertrainState.full(flown, temp_c=ground_temp_c, soc=initial_soc)
    fault = np.zeros(2)
    if fault_motor is not None:
        fault[MOTOR_NAMES.index(fault_motor)] = fault_magnitude
    k_fault = n if fault_motor is None or fault_time_s is None else int(np.searchsorted(t, fault_time_s))
    segments = [(0, k_fault, np.zeros(2)), (k_fault, n, fault)]
    rec = {name: [] for name in ("pack_voltage", "pack_current", "pack_temp", "pack_soc", "motor_current",
                                 "motor_temp")}
    x0, tm0 = state.pack_state[None], np.asarray(state.motor_temp_c)[None]
    failed_at = None
    for a, b, f in segments:
        if b <= a or failed_at is not None:
            continue
        # the vehicle stops flying at its first failure (it would land or be lost): so does the log
        run = topology.simulate_powertrain(flown.pack_matrix()[None], flown.motor_vector()[None], x0, tm0,
                                         dt[a:b], power[a:b], ambient[a:b], f[None], record=True,
                                         limits=limits.as_tuple(), stop_on_failure=True)
        end = b - a if run.fail_step[0] < 0 else int(run.fail_step[0]) + 1
        for name in rec:
            rec[name].append(getattr(run, name)[0][:end])
        x0, tm0 = run.final_pack_state, run.final_motor_temp
        if run.fail_step[0] >= 0:
            failed_at = (a + int(run.fail_step[0]), kernel.FAILURE_NAMES[int(run.fail_cause[0])])
    truth_arrays = {name: np.concatenate(v) for name, v in rec.items()}
    n = truth_arrays["pack_soc"].shape[0]
    t, power, ambient, rho = t[:n], power[:n], ambient[:n], rho[:n]
    rpm = shaft_rpm(power, rho)

    frames: list = []
    outage = None
    if noise.outage_s > 0:
        start = rng.uniform(t[0] + 120.0, max(t[-1] - 120.0, t[0] + 121.0))
        outage = (start, start + noise.outage_s)

    def value(x: float, sigma: float, spike_scale: float) -> float | None:
        if rng.random() < noise.spike_rate:
            return float(x + rng.choice([-1.0, 1.0]) * spike_scale)
        return float(x + rng.normal(0.0, sigma))

    for k in range(n):
        tk = float(t[k])
        if outage is not None and outage[0] <= tk <= outage[1]:
            continue
        if k % 20 == 0:
            frames.append(AmbientFrame(tk, round(float(ambient[k]) + rng.normal(0, 0.2), 1)))
            frames.append(AirdataFrame(tk, None, None, None, None, None))
        for q, name in enumerate(MOTOR_NAMES):
            if rng.random() < noise.drop_rate:
                continue
            frames.append(MotorFrame(
                tk, name,
                current_a=value(truth_arrays["motor_current"][k, q], noise.current_a, 40.0),
                rpm=value(rpm[k], noise.rpm, 3000.0),
                temperature_c=round(value(truth_arrays["motor_temp"][k, q], noise.temperature_c, 50.0), 1)))
        if k % pack_every:
            continue
        for b, name in enumerate(PACK_NAMES):
            if rng.random() < noise.drop_rate:
                continue
            frames.append(PackFrame(
                tk, name,
                voltage_v=round(value(truth_arrays["pack_voltage"][k, b], noise.voltage_v, 5.0), 3),
                current_a=round(value(truth_arrays["pack_current"][k, b], noise.current_a, 40.0), 2),
                temperature_c=round(value(truth_arrays["pack_temp"][k, b], noise.temperature_c, 50.0), 1)))
    return SyntheticFlight(
        frames=frames, time_s=t, shaft_power_w=power, ambient_c=ambient, soc=truth_arrays["pack_soc"],
        pack_temp_c=truth_arrays["pack_temp"], motor_temp_c=truth_arrays["motor_temp"],
        fault_motor=fault_motor, fault_magnitude=fault_magnitude if fault_motor else 0.0,
        fault_time_s=float(t[k_fault]) if fault_motor and k_fault < n else None, degradation=tuple(degradation),
        truth=flown, info={"min_pack_voltage": float(np.min(truth_arrays["pack_voltage"])),
                           "limits": limits.as_tuple(),
                           "failed_at_s": None if failed_at is None else float(t[min(failed_at[0], n - 1)]),
                           "failure": None if failed_at is None else failed_at[1]},
    )
