"""``gcs-pdm vehicle show|check|init``: print, validate and write vehicle descriptions."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gcs_pdm.command_errors import error
from gcs_pdm.vehicle.description import VehicleError, dumps, load
from gcs_pdm.vehicle.presets import resolve
from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("vehicle")
    vsub = p.add_subparsers(dest="vehicle_command", metavar="ACTION", required=True)
    show = vsub.add_parser("show", help="print a preset or a description file (TOML by default)")
    show.add_argument("vehicle", nargs="?", default=DEFAULT_PRESET, help=f"FILE or PRESET ({', '.join(PRESETS)})")
    show.add_argument("--json", action="store_true", help="print JSON instead of TOML")
    show.add_argument("--list", action="store_true", help="list the presets")
    show.set_defaults(func=_show)
    check = vsub.add_parser("check", help="validate a description file; errors name the field")
    check.add_argument("file")
    check.set_defaults(func=_check)
    init = vsub.add_parser("init", help="write a description: a preset's copy, or derived from a tlog or an autopilot log")
    src = init.add_mutually_exclusive_group()
    src.add_argument("--preset", default=None, help=f"start from a preset ({', '.join(PRESETS)})")
    src.add_argument("--from", dest="log", default=None, metavar="LOG",
                     help="derive a provisional description from a tlog (HEARTBEAT, BATTERY_STATUS, ESC telemetry, "
                          "PARAM_VALUE), an ArduPilot DataFlash .bin or a PX4 ULog .ulg")
    init.add_argument("--capacity-mah", action="append", default=[], metavar="[ID=]MAH",
                      help="a pack's rated capacity (mAh; ID = its BATTERY_STATUS id, default 0) when the log "
                           "gives none (no BATT_CAPACITY/BATn_CAPACITY parameter, too little discharge); repeatable")
    init.add_argument("--out", required=True, help="file to write (.toml or .json)")
    init.add_argument("--force", action="store_true", help="overwrite an existing file")
    init.set_defaults(func=_init)


def _show(args) -> int:
    if args.list:
        for name, d in PRESETS.items():
            print(f"{name:10s} {d.description}")
        return 0
    try:
        desc = resolve(args.vehicle)
    except VehicleError as exc:
        return error("vehicle show", str(exc))
    sys.stdout.write(dumps(desc, "json" if args.json else "toml"))
    return 0


def _check(args) -> int:
    from gcs_pdm.vehicle.model_inputs import model_inputs

    try:
        desc = load(args.file)
        inputs = model_inputs(desc)  # the parameter references resolve too
    except VehicleError as exc:
        return error("vehicle check", str(exc))
    print(f"{args.file}: ok — {desc.name}: {inputs.n_packs} pack(s), {inputs.n_motors} motor(s), "
          f"{desc.feed_kind()}, {desc.airframe.type}" + (" (provisional)" if desc.provisional else ""))
    return 0


def _capacities(items: list[str]) -> dict[int, float]:
    """``--capacity-mah [ID=]MAH`` values by battery id."""
    out = {}
    for item in items:
        pack, _, value = item.rpartition("=")
        try:
            out[int(pack or 0)] = float(value)
        except ValueError:
            raise VehicleError(f"--capacity-mah {item}: expected [ID=]MAH, e.g. 0=3300") from None
        if not out[int(pack or 0)] > 0:
            raise VehicleError(f"--capacity-mah {item}: the capacity must be > 0 mAh")
    return out


def _init(args) -> int:
    out = Path(args.out)
    if out.exists() and not args.force:
        return error("vehicle init", f"{out} exists (--force to overwrite)")
    try:
        if args.log:
            from gcs_pdm.logs.kind import NotALog, log_kind
            from gcs_pdm.logs.provisional_vehicle import observe_file

            try:
                log_kind(args.log)
            except (NotALog, OSError) as exc:
                return error("vehicle init", f"--from {exc}" if isinstance(exc, NotALog) else
                             f"--from {args.log}: {exc.strerror or exc}")

            desc, notes = observe_file(args.log, capacities=_capacities(args.capacity_mah))
            for n in notes:
                print(f"note: {n}", file=sys.stderr)
        else:
            desc = resolve(args.preset or DEFAULT_PRESET)
    except VehicleError as exc:
        return error("vehicle init", str(exc))
    out.write_text(dumps(desc, "json" if out.suffix.lower() == ".json" else "toml"))
    print(f"wrote {out} ({desc.name}); check it with `gcs-pdm vehicle check {out}`")
    return 0
