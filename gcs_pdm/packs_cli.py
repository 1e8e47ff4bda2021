"""``gcs-pdm packs``: ingest a fleet's logs, list the packs, show one pack's trend and forecast,
assign a pack to a slot."""
from __future__ import annotations

import json
from pathlib import Path

from gcs_pdm.command_errors import error


def register(subparsers) -> None:
    p = subparsers.add_parser("packs", description="each pack's health across flights (docs/packs.md)")
    p.add_argument("--config", help="the service's settings file: its database and retirement thresholds")
    p.add_argument("--database", help="SQLite file (default: the service's, <data_dir>/gcs_pdm.sqlite3)")
    sub = p.add_subparsers(dest="packs_command", metavar="ACTION", required=True)
    ing = sub.add_parser("ingest", help="make health points from logs (tlog, .bin, .ulg): a process pool or Dask")
    ing.add_argument("logs", nargs="+", metavar="LOG|DIR")
    ing.add_argument("--workers", type=int, default=None, help="local worker processes (default: the CPUs; 1: in process)")
    ing.add_argument("--scheduler", metavar="tcp://HOST:8786", help="run on this Dask cluster instead")
    ing.add_argument("--capacity-ah", type=float, default=None,
                     help="rated capacity of packs whose logs do not say it (else they are skipped, counted)")
    ing.add_argument("--chemistry", default="lipo",
                     help="the packs' chemistry, what their capacity is read on (default lipo, as a vehicle "
                          "description's; liion reads it on the electrodes' curves, docs/packs.md)")
    ing.add_argument("--assign", action="append", default=[], metavar="SLOT=PACK",
                     help="the pack that flew in a slot in these logs (when the log has no serial)")
    ing.add_argument("--no-progress", action="store_true", help="no progress bar")
    ing.add_argument("--json", action="store_true", help="the summary as JSON")
    ls = sub.add_parser("list", help="the packs known, with their latest health and forecast")
    ls.add_argument("--json", action="store_true")
    sh = sub.add_parser("show", help="one pack: its flights, trend and retirement forecast")
    sh.add_argument("pack")
    sh.add_argument("--json", action="store_true")
    asg = sub.add_parser("assign", help="say which pack is in a slot (live flights and later ingests use it)")
    asg.add_argument("slot")
    asg.add_argument("pack")
    p.set_defaults(func=_run)


def _config(args):
    from gcs_pdm.service.config import load_config

    cfg = load_config(args.config)
    return Path(args.database) if args.database else cfg.database, cfg


def _run(args) -> int:
    from gcs_pdm.packs.records import PackRecords

    db, cfg = _config(args)
    records = PackRecords(db)
    thresholds = {"capacity_fraction": cfg.pack_retire_capacity_fraction,
                  "resistance_factor": cfg.pack_retire_resistance_factor}
    try:
        if args.packs_command == "ingest":
            return _ingest(args, records)
        if args.packs_command == "assign":
            records.assign(args.slot, args.pack, "gcs-pdm packs assign")
            print(f"slot {args.slot}: pack {args.pack}")
            return 0
        if args.packs_command == "list":
            rows = [records.summary(pid, **thresholds) for pid in records.pack_ids()]
            if args.json:
                print(json.dumps([{k: r[k] for k in ("pack_id", "flights", "identity", "warning", "equivalent_cycles",
                                                     "latest")} | {"retirement": r["trend"]["retirement"]}
                                  for r in rows], indent=1))
                return 0
            if not rows:
                print(f"no packs in {db} (gcs-pdm packs ingest LOG... makes them)")
                return 0
            print(f"{'pack':<24} {'flights':>7} {'cycles':>7} {'capacity Ah':>14} {'R25 mOhm':>12}  retirement")
            for r in rows:
                print(_line(r))
            return 0
        if args.packs_command == "show":
            try:
                r = records.summary(args.pack, **thresholds)
            except KeyError:
                return error("packs show", f"no pack {args.pack!r} in {db}")
            if args.json:
                print(json.dumps(r, indent=1))
                return 0
            _print_pack(r)
            return 0
    finally:
        records.close()
    return 2


def _fmt(x, sd, scale=1.0, digits=3):
    if x is None:
        return "unknown"
    return f"{x * scale:.{digits}g}" + (f"±{sd * scale:.1g}" if sd is not None else "")


def _forecast_text(f: dict) -> str:
    if f["cycles"] is None:
        return f"unknown ({f['why']})"
    lo = f"{f['low']:.0f}" if f["low"] is not None else "?"
    hi = f"{f['high']:.0f}" if f["high"] is not None else "beyond reach"
    return f"{f['threshold']} at {f['cycles']:.0f} cycles ({lo}-{hi}, {f['interval']:.0%})"


def _line(r: dict) -> str:
    lat = r["latest"]
    return (f"{r['pack_id']:<24} {r['flights']:>7} {r['equivalent_cycles']:>7.1f} "
            f"{_fmt(lat['capacity_ah'], lat['capacity_sd_ah']):>14} "
            f"{_fmt(lat['resistance_25c_ohm'], lat['resistance_sd_ohm'], 1e3):>12}  "
            f"{_forecast_text(r['trend']['retirement'])}")


def _print_pack(r: dict) -> None:
    print(f"pack {r['pack_id']}: {r['flights']} flight(s), {r['equivalent_cycles']:.1f} equivalent cycles; "
          f"known by {', '.join(r['identity'])}; slots {', '.join(r['slots'])}")
    if r["warning"]:
        print(f"warning: {r['warning']}")
    print(f"{'cycles':>7} {'capacity Ah':>14} {'R25 mOhm':>12} {'drawn Ah':>9} {'DoD':>5} {'peak C':>7}")
    for h in r["history"]:
        peak = f"{h['peak_temperature_c']:.1f}" if h["peak_temperature_c"] is not None else "-"
        dod = f"{h['depth_of_discharge']:.0%}" if h["depth_of_discharge"] is not None else "-"
        print(f"{h['cycles']:>7.2f} {_fmt(h['capacity_ah'], h['capacity_sd_ah']):>14} "
              f"{_fmt(h['resistance_25c_ohm'], h['resistance_sd_ohm'], 1e3):>12} {h['charge_ah']:>9.3f} {dod:>5} "
              f"{peak:>7}")
    t = r["trend"]
    print(f"capacity: {_forecast_text(t['capacity_forecast'])}")
    print(f"resistance: {_forecast_text(t['resistance_forecast'])}")
    print(f"retirement: {_forecast_text(t['retirement'])}")


def _ingest(args, records) -> int:
    from gcs_pdm.packs.ingest import IngestSettings, find_logs, run_ingest

    assignments = []
    for a in args.assign:
        slot, sep, pack = a.partition("=")
        if not sep or not slot or not pack:
            return error("packs ingest", f"--assign {a!r}: expected SLOT=PACK")
        assignments.append((slot, pack))
    from gcs_pdm.packs.cell_curves import capacity_reading

    try:
        capacity_reading(args.chemistry, 1.0)
    except ValueError as exc:
        return error("packs ingest", f"--chemistry: {exc}")
    paths = find_logs(args.logs)
    if not paths:
        return error("packs ingest", "no logs found (tlog, .bin, .ulg)")
    settings = IngestSettings(default_capacity_ah=args.capacity_ah, assignments=tuple(assignments),
                              chemistry=args.chemistry)
    bad = []

    def store(result):
        records.add_log_result(result)
        if result["status"] == "bad":
            bad.append(result)

    summary = run_ingest(paths, settings, workers=args.workers, scheduler=args.scheduler, known=records.known_log,
                         on_result=store, progress=not args.no_progress and not args.json)
    summary["bad_logs"] = [{"path": b["path"], "error": b["error"]} for b in bad]
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(f"{summary['logs']} log(s): {summary['ingested']} ingested ({summary['records']} health points), "
              f"{summary['skipped_known']} already ingested, {summary['bad']} bad ({summary['engine']})")
        for b in bad:
            print(f"  bad: {b['path']}: {b['error']}")
    return 0
