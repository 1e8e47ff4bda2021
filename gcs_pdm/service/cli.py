"""``gcs-pdm serve`` and ``gcs-pdm demo``."""
from __future__ import annotations

import argparse
import logging
import sqlite3

from gcs_pdm.command_errors import EXIT_NOTHING, error


def register(subparsers) -> None:
    p = subparsers.add_parser("serve")
    p.add_argument("--config", help="TOML or JSON settings file (see docs/service.md); env GCS_PDM_* override it")
    p.add_argument("--mavlink", dest="mavlink_url",
                   help="MAVLink address (default udpin:127.0.0.1:14551; docs/operations.md says how to listen elsewhere)")
    p.add_argument("--target-system", dest="target_system", type=_target_system, metavar="N|auto",
                   help="the vehicle's MAVLink system id (default 1, ArduPilot's and PX4's); "
                        "auto: the first autopilot heard (others are reported, never tracked)")
    p.add_argument("--http", help="HTTP host:port (default 127.0.0.1:8000)")
    p.add_argument("--policy", choices=("auto", "advise"))
    p.add_argument("--data-dir", dest="data_dir")
    p.add_argument("--objectives", help="scenario JSON with the waypoints' rewards and the limits to plan with")
    p.add_argument("--vehicle", metavar="FILE|PRESET",
                   help="vehicle description (docs/vehicles.md); default: a provisional one derived from the first "
                        "telemetry (said in /status and the log)")
    p.set_defaults(func=_serve)
    d = subparsers.add_parser("demo")
    d.add_argument("--speedup", type=float, default=60.0, help="simulated seconds per wall second (default 60)")
    d.add_argument("--http-port", type=int, default=8000, help="status page port (0: any free port)")
    d.add_argument("--data-dir", help="keep the database and tlog here (default: a temporary directory)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--policy", choices=("auto", "advise"), default="auto",
                   help="advise: plans are proposed and a scripted operator approves them over HTTP")
    d.add_argument("--params", default="learned",
                   help="parameter set the service flies with: learned (fixtures/params/learned_sim.json), "
                        "paper_si, previous_si")
    d.add_argument("--vehicle", default=None, metavar="FILE|PRESET",
                   help="fly another vehicle description (e.g. quad-4s: a survey, a fault on one rotor, replan, "
                        "upload); default: the paper's Edge 540 and its Table III flight")
    d.add_argument("--timeout", type=float, default=600.0,
                   help="wall-clock limit of the flight, s (default 600; about 60 s on an idle 2-core machine)")
    d.add_argument("--real-time", action="store_true",
                   help="the vehicle flies on at its speed-up whatever the service does, as a real aircraft would "
                        "(default: its clock waits while the service catches up with the telemetry or decides, "
                        "so a slow or busy machine gets the same flight)")
    d.add_argument("--no-compare", action="store_true", help="skip flying the original mission without the service")
    d.add_argument("--export-tryout", metavar="DIR",
                   help="only write the Table III mission (.plan) and objectives (JSON) to DIR, for deploy/")
    d.set_defaults(func=_demo)


def _target_system(text: str) -> int | str:
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a system id (1..255) nor 'auto'") from None
    if not 1 <= value <= 255:
        raise argparse.ArgumentTypeError(f"system id {value} is out of range 1..255")
    return value


def _serve(args: argparse.Namespace) -> int:
    """Start-up failures are one line on stderr and exit 2 (systemd restarts; no traceback)."""
    from gcs_pdm.service.config import ConfigError, load_config

    def fail(message: str) -> int:
        return error("serve", message)

    host = port = None
    if args.http:
        host, _, port_text = args.http.rpartition(":")
        try:
            port = int(port_text)
        except ValueError:
            return fail(f"--http {args.http!r}: expected HOST:PORT")
    try:
        config = load_config(args.config, mavlink_url=args.mavlink_url, policy=args.policy, data_dir=args.data_dir,
                             http_host=host or None, http_port=port, target_system=args.target_system,
                             vehicle=args.vehicle)
    except ConfigError as exc:
        return fail(str(exc))
    from gcs_pdm.service.server import StartupError, serve
    from gcs_pdm.service.storage import Conflict, NotFound
    from gcs_pdm.process_gc import start_up_over
    from gcs_pdm.vehicle.description import VehicleError

    start_up_over()
    try:
        return serve(config, objectives=args.objectives)
    except VehicleError as exc:
        return fail(f"vehicle: {exc}")
    except StartupError as exc:
        return fail(str(exc))
    except NotFound as exc:  # e.g. parameter_set names no stored set
        return fail(f"not found: {exc.args[0]}")
    except Conflict as exc:
        return fail(str(exc))
    except OSError as exc:  # e.g. a data directory that cannot be created
        return fail(f"{exc.strerror or exc}{': ' + str(exc.filename) if exc.filename else ''}")
    except sqlite3.Error as exc:  # e.g. a read-only data directory or disk
        return fail(f"database {config.database}: {exc} (is the data directory writable, with room?)")


def _demo(args: argparse.Namespace) -> int:
    from gcs_pdm.service.demo import export_tryout, print_summary, run_demo

    if args.export_tryout:
        for what, value in export_tryout(args.export_tryout).items():
            print(f"{what}: {value}")
        return 0

    # The demo's own lines are the show; the libraries' INFO chatter would bury them.
    logging.getLogger().setLevel(logging.WARNING)
    if args.vehicle not in (None, "edge540"):
        from gcs_pdm.service.demo_vehicle import print_vehicle_summary, run_vehicle_demo
        from gcs_pdm.vehicle.description import VehicleError

        speedup = args.speedup if args.speedup != 60.0 else 8.0  # a small vehicle's short legs: 60x is a blur
        try:
            result = run_vehicle_demo(args.vehicle, speedup=speedup, http_port=args.http_port, data_dir=args.data_dir,
                                      seed=args.seed, timeout_s=args.timeout, policy=args.policy,
                                      hold_while_deciding=not args.real_time)
        except VehicleError as exc:
            return error("demo", str(exc))
        print_vehicle_summary(result)
        return 0 if result.landed else error("demo", "the vehicle did not land safely", EXIT_NOTHING)
    result = run_demo(speedup=args.speedup, http_port=args.http_port, data_dir=args.data_dir, seed=args.seed,
                      timeout_s=args.timeout, compare=not args.no_compare, params=args.params,
                      policy=args.policy, hold_while_deciding=not args.real_time)
    print_summary(result)
    if not result.landed:
        return error("demo", "the vehicle did not land safely", EXIT_NOTHING)
    return 0
