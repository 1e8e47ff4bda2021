"""``gcs-pdm sim``: run the simulated MAVLink vehicle on a UDP link, or record a flight to a tlog."""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("sim", description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--connect", default="udpout:127.0.0.1:14550",
                   help="pymavlink address: udpout:host:port (send to a GCS) or udpin:host:port (listen)")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall second")
    speed.add_argument("--lockstep", action="store_true",
                       help="as fast as the CPU allows while armed (real time while waiting on the ground)")
    p.add_argument("--mission", help="mission to load at boot: QGC WPL 110 (.waypoints/.txt) or .plan file")
    p.add_argument("--no-autostart", action="store_true",
                   help="wait for ARM + MISSION_START (or AUTO) instead of taking off once a mission is loaded")
    p.add_argument("--start-delay", type=float, default=5.0, help="s on the ground before an automatic take-off")
    p.add_argument("--vehicle", default=None, metavar="FILE|PRESET",
                   help="fly a vehicle description (docs/vehicles.md) instead of the paper's aircraft: its packs, "
                        "motors, airframe and telemetry layout (--params, --truth-seed and --degrade do not apply)")
    p.add_argument("--chemistry-curves", action="store_true",
                   help="with --vehicle: each pack rests on its chemistry's curve (docs/estimation.md), not on its "
                        "parameter set's linear one")
    p.add_argument("--seed", type=int, default=0, help="sensor noise and drop-out seed")
    p.add_argument("--truth-seed", type=int, default=None, help="seed of the hidden true parameters")
    p.add_argument("--params", help="true parameter set as JSON (instead of the hidden seeded truth)")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="motor:<fwd|aft>:<m>@<t:s|wp:n|leg:a-b[:frac]>, e.g. motor:aft:0.8@leg:2-3 (repeatable)")
    p.add_argument("--degrade", action="append", default=[], metavar="SPEC",
                   help="<PACK>:capacity=<f>,resistance=<f>, e.g. LRF40:capacity=0.8,resistance=1.5 (repeatable)")
    p.add_argument("--soc", type=float, default=1.0, help="initial state of charge of every pack")
    p.add_argument("--ground-temp", type=float, default=20.0, help="ambient temperature at the ground, °C")
    p.add_argument("--home", default="37.0870,-76.3800,0", help="home lat,lon,alt(m AMSL)")
    p.add_argument("--wind", default="0,0",
                   help="mean wind: SPEED@DIR (m/s, the direction it blows FROM in degrees, as ArduPilot's WIND "
                        "says it: 8@270 is a westerly) or east,north m/s (the direction it blows towards)")
    p.add_argument("--gust", type=float, default=None, metavar="SIGMA",
                   help="gusts: 1-sigma m/s of each wind component (a 5 s Gauss-Markov process); "
                        "default 15%% of the mean wind speed, 0 for a steady wind")
    p.add_argument("--airspeed", type=float, default=None,
                   help="cruise airspeed m/s (default 25, or the vehicle description's cruise speed)")
    p.add_argument("--rate", action="append", default=[], metavar="MSG=HZ",
                   help="telemetry rate, e.g. BATTERY_STATUS=5 (repeatable)")
    p.add_argument("--drop-rate", type=float, default=0.01, help="probability of losing a periodic message")
    p.add_argument("--tlog", help="record everything sent and received to this tlog")
    p.add_argument("--record", metavar="TLOG",
                   help="no network: fly the mission in lock-step, write the tlog and a truth JSON beside it")
    p.add_argument("--duration", type=float, default=None, help="stop after this many wall seconds")
    p.set_defaults(func=run)


def _pair(text: str, what: str, n: int) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise SystemExit(f"--{what}: expected {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n:
        raise SystemExit(f"--{what}: expected {n} comma-separated numbers, got {text!r}")
    return values


def parse_wind(text: str) -> tuple[float, float]:
    """``SPEED@FROM_DEG`` or ``east,north`` → the air's velocity (east, north), m/s."""
    from gcs_pdm.models.wind import wind_from_speed_direction

    if "@" in text:
        speed, _, direction = text.partition("@")
        try:
            speed_mps, from_deg = float(speed), float(direction)
        except ValueError:
            raise SystemExit(f"--wind: expected SPEED@DIR (e.g. 8@270) or east,north, got {text!r}") from None
        if not (speed_mps >= 0 and np.isfinite(speed_mps) and np.isfinite(from_deg)):
            raise SystemExit(f"--wind: speed must be >= 0 and the direction finite, got {text!r}")
        return wind_from_speed_direction(speed_mps, from_deg)
    east, north = _pair(text, "wind", 2)
    return east, north


def _gust(args: argparse.Namespace, wind_en: tuple[float, float]) -> float:
    gust = getattr(args, "gust", None)
    if gust is None:
        return 0.15 * float(np.hypot(*wind_en))
    if not (gust >= 0 and np.isfinite(gust)):
        raise SystemExit(f"--gust: must be a finite number >= 0, got {gust!r}")
    return float(gust)


def build_config(args: argparse.Namespace):
    from gcs_pdm.models.params import ParameterSet
    from gcs_pdm.sim.faults import FaultSpecError, parse_degradation, parse_fault
    from gcs_pdm.sim.model import SimConfig
    from gcs_pdm.sim.telemetry import DEFAULT_RATES, TelemetryConfig
    from gcs_pdm.sim.truth import DEFAULT_TRUTH_SEED

    desc = None
    if getattr(args, "vehicle", None):
        from gcs_pdm.vehicle.description import VehicleError
        from gcs_pdm.vehicle.presets import resolve

        try:
            desc = resolve(args.vehicle)
        except VehicleError as exc:
            raise SystemExit(f"sim: {exc}") from None
        if args.params or args.degrade or args.truth_seed is not None:
            raise SystemExit("sim: --params, --truth-seed and --degrade do not apply to --vehicle")
    elif getattr(args, "chemistry_curves", False):
        raise SystemExit("sim: --chemistry-curves needs --vehicle (the paper's aircraft flies its fitted set as it is)")
    try:
        motors = desc.motor_names if desc is not None else None
        faults = tuple(parse_fault(f, motors) if motors else parse_fault(f) for f in args.fault)
        degradations = tuple(parse_degradation(d) for d in args.degrade)
    except FaultSpecError as exc:
        raise SystemExit(f"sim: {exc}") from None
    mission = ()
    if args.mission:
        from gcs_pdm.mavlink import mission_files
        path = Path(args.mission)
        mission = tuple(mission_files.read_plan(path) if path.suffix == ".plan" else mission_files.read_wpl(path))
    params = ParameterSet.from_json(Path(args.params).read_text()) if args.params else None
    lat, lon, alt = _pair(args.home, "home", 3)
    wind_en = parse_wind(args.wind)
    gust = _gust(args, wind_en)
    rates = dict(DEFAULT_RATES)
    for r in args.rate:
        name, _, hz = r.partition("=")
        if name not in DEFAULT_RATES:
            raise SystemExit(f"--rate: unknown message {name!r}; known: {', '.join(sorted(DEFAULT_RATES))}")
        rates[name] = float(hz)
    if desc is not None:
        from gcs_pdm.sim.model import vehicle_config

        config = vehicle_config(desc, seed=args.seed, home_lat_deg=lat, home_lon_deg=lon, home_alt_m=alt,
                                ground_temp_c=args.ground_temp, initial_soc=args.soc, faults=faults,
                                wind_en_mps=wind_en, wind_gust_mps=gust, mission=mission,
                                autostart=not args.no_autostart, start_delay_s=args.start_delay,
                                chemistry_curves=getattr(args, "chemistry_curves", False))
        if args.airspeed is not None:
            config = replace(config, cruise_airspeed_mps=args.airspeed)
        return config, TelemetryConfig(rates_hz=rates, drop_rate=args.drop_rate, event_heartbeat_restarts_period=True)
    config = SimConfig(
        seed=args.seed, truth_seed=args.truth_seed if args.truth_seed is not None else DEFAULT_TRUTH_SEED,
        params=params, home_lat_deg=lat, home_lon_deg=lon, home_alt_m=alt, ground_temp_c=args.ground_temp,
        initial_soc=args.soc, faults=faults, degradations=degradations, wind_en_mps=wind_en,
        wind_gust_mps=gust,
        cruise_airspeed_mps=args.airspeed if args.airspeed is not None else 25.0, mission=mission, autostart=not args.no_autostart,
        start_delay_s=args.start_delay)
    return config, TelemetryConfig(rates_hz=rates, drop_rate=args.drop_rate, event_heartbeat_restarts_period=True)


def run(args: argparse.Namespace) -> int:
    config, telemetry = build_config(args)
    if args.record:
        from gcs_pdm.sim.record import fly
        if not config.mission:
            print("gcs-pdm sim: error: --record needs --mission", file=sys.stderr)
            return 2
        rec = fly(config, telemetry, args.record)
        n_packs = len(config.vehicle.packs)
        true_set = config.truth()  # None: the description's own values are the truth
        truth = {"parameters": config.vehicle.to_dict() if true_set is None else true_set.to_dict(),
                 "faults": rec.fault_log, "reached": rec.reached,
                 "initial_soc": [float(x) for x in np.broadcast_to(config.initial_soc, (n_packs,))],
                 "failed": rec.final.failed, "failure": rec.final.failure, "duration_s": rec.final.time_s,
                 "energy_j": rec.final.energy_j}
        Path(args.record).with_suffix(".truth.json").write_text(json.dumps(truth, indent=1))
        print(f"recorded {rec.final.time_s:.0f} s of flight, {rec.tlog_bytes} bytes to {args.record}"
              + (f"; FAILED: {rec.final.failure}" if rec.final.failed else ""))
        return 0
    from gcs_pdm.sim.vehicle import SimulatedVehicle
    vehicle = SimulatedVehicle(config, args.connect, speedup=None if args.lockstep else args.speedup,
                               telemetry=telemetry, tlog_path=args.tlog).start()
    started = time.monotonic()
    next_print = started
    try:
        while vehicle.running:
            time.sleep(0.5)
            s = vehicle.state
            line = (f"t={s.time_s:7.1f}s {s.mode:<6} item {s.current_seq:>2} alt {s.alt_m:6.1f} m "
                    f"{s.airspeed_mps:4.1f} m/s  packs {' '.join(f'{v:5.2f}' for v in s.pack_voltage_v)} V "
                    f"motors {'/'.join(f'{i:5.1f}' for i in s.motor_current_a)} A "
                    f"{'/'.join(f'{t:5.1f}' for t in s.motor_temp_c)} C" + (f"  FAILED: {s.failure}" if s.failed else ""))
            if time.monotonic() >= next_print:
                print(line, flush=True)
                next_print += 5.0
            if args.duration is not None and time.monotonic() - started > args.duration:
                break
    except KeyboardInterrupt:
        pass
    finally:
        vehicle.stop()
    if vehicle.error is not None:
        print(f"gcs-pdm sim: error: the vehicle stopped on an error: {vehicle.error}", file=sys.stderr)
        return 1
    return 0
