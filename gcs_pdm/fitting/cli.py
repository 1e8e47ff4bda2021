"""``gcs-pdm fit battery|motor|synthetic``: learn parameters from flight logs (the paper's §IV).

    gcs-pdm fit battery --train F… --val F… --test F… --out DIR [--pack LLF20|ULA20|LRF40|URA40|all]
                        [--model extended|paper]
    gcs-pdm fit motor   --train F… --val F… --test F… --out DIR
    gcs-pdm fit battery|motor --vehicle FILE|PRESET …   (a described vehicle's packs/motors:
                        DIR/parameters.json of its packs and DIR/vehicle.toml pointing at it)
    gcs-pdm fit synthetic --out DIR [--flights 12] [--seed 1]     (CSV logs with known truth)

Flight files are CSV/Parquet tables (one pack or the motors) or tlogs (all four packs and the
motors). With tlogs, ``--pack all`` fits every pack into ``DIR/<pack>/`` and writes the merged
learned set to ``DIR/parameters.json``. An autopilot's own log (ArduPilot DataFlash ``.bin``, PX4
ULog ``.ulg``; gcs_pdm.logs) names its vehicle: without ``--vehicle`` the description is derived
from the first training log (as ``gcs-pdm vehicle init --from LOG`` derives it) and its packs are
fitted by battery instance, as with ``--vehicle``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


#: `gcs-pdm fit battery|set` with no --model (kept equal to procedure.DEFAULT_MODEL by a test; a
#: literal here so the CLI's --help does not import the fitting stack)
DEFAULT_MODEL = "extended"


def register(subparsers) -> None:
    p = subparsers.add_parser("fit")
    sub = p.add_subparsers(dest="fit_command", metavar="WHAT")
    for what in ("battery", "motor"):
        q = sub.add_parser(what, help=f"fit the {what} parameters")
        q.add_argument("--train", nargs="+", type=Path, required=True, help="training flights (CSV, Parquet, tlog, ArduPilot .bin or PX4 .ulg)")
        q.add_argument("--val", nargs="+", type=Path, required=True, help="validation flights (select among LM solutions)")
        q.add_argument("--test", nargs="+", type=Path, required=True, help="test flights (errors reported)")
        q.add_argument("--out", type=Path, required=True, help="output directory")
        q.add_argument("--vehicle", default=None, metavar="FILE|PRESET",
                       help="fit this vehicle description's packs (docs/vehicles.md): each from its own "
                            "BATTERY_STATUS id / DataFlash instance, ranges scaled to its cells and capacity "
                            "(motor: its motors' ESC indices); writes DIR/parameters.json and DIR/vehicle.toml "
                            "pointing at it")
        if what == "battery":
            q.add_argument("--pack", default=None,
                           help="pack to fit: tlogs hold all four (default all); tables hold one (its fixed values "
                                "and reference come from this pack, default LLF20); with --vehicle one of its packs")
        if what == "battery":
            q.add_argument("--model", default=DEFAULT_MODEL, choices=("extended", "paper"),
                           help="battery model variant (docs/model.md): extended (default) or paper (eqs. 1-7)")
        q.add_argument("--starts", type=int, default=None,
                       help="annealing starts = LM runs (default 10; 4 for the extended variant)")
        q.add_argument("--sa-generations", type=int, default=None, help="annealing generations per start")
        q.add_argument("--sa-proposals", type=int, default=None, help="proposals per chain and generation")
        q.add_argument("--lm-max-nfev", type=int, default=None, help="LM residual evaluations per run")
        q.add_argument("--seed", type=int, default=0)
        q.add_argument("--workers", type=int, default=2, help="threads running the kernel (default 2)")
        q.add_argument("--reference", default="previous_si", help="built-in set whose errors are reported alongside")
        q.add_argument("--base", default="previous_si", help="built-in set giving the values that are not learned")
        q.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
        q.add_argument("--quiet", action="store_true", help="no progress display")
        q.set_defaults(func=run, fit_what=what)
    s = sub.add_parser("synthetic", help="write synthetic flight logs (CSV) with known true parameters")
    s.add_argument("--out", type=Path, required=True)
    s.add_argument("--flights", type=int, default=12)
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--truth-seed", type=int, default=7)
    s.add_argument("--clean", action="store_true", help="noise only, no injected damage")
    s.set_defaults(func=run_synthetic)
    st = sub.add_parser("set", help="fit all four packs and the motors from tlogs; write the learned parameter set")
    st.add_argument("--train", nargs="+", type=Path, required=True)
    st.add_argument("--val", nargs="+", type=Path, required=True)
    st.add_argument("--test", nargs="+", type=Path, required=True)
    st.add_argument("--out", type=Path, required=True, help="directory: <part>/result.json etc. and parameters.json")
    st.add_argument("--set-out", type=Path, default=None, help="also write the learned set to this JSON file")
    st.add_argument("--name", default="learned")
    st.add_argument("--note", default="", help="free text stored in the set's provenance")
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--model", default=DEFAULT_MODEL, choices=("extended", "paper"), help="battery model variant")
    st.add_argument("--starts", type=int, default=None)
    st.add_argument("--sa-generations", type=int, default=None)
    st.add_argument("--sa-proposals", type=int, default=None)
    st.add_argument("--lm-max-nfev", type=int, default=None)
    st.add_argument("--workers", type=int, default=2)
    st.add_argument("--base", default="previous_si")
    st.add_argument("--reference", default="previous_si")
    st.add_argument("--no-plots", action="store_true")
    st.add_argument("--quiet", action="store_true")
    st.set_defaults(func=run_set)
    ls = sub.add_parser("learn-synthetic", help="learn a whole parameter set from synthetic flights of the simulated "
                                                "vehicle (gcs_pdm.sim.truth) and write it as JSON")
    ls.add_argument("--out", type=Path, required=True, help="parameter set JSON to write")
    ls.add_argument("--flights", type=int, default=12)
    ls.add_argument("--seed", type=int, default=1, help="flight generator seed")
    ls.add_argument("--fit-seed", type=int, default=0)
    ls.add_argument("--truth-seed", type=int, default=None, help="gcs_pdm.sim.truth seed (default: the vehicle's)")
    ls.add_argument("--quiet", action="store_true")
    ls.set_defaults(func=run_learn_synthetic)
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])


class _ProgressLine:
    """A one-line progress display on stderr (rewritten in place on a terminal)."""

    def __init__(self, prefix: str, quiet: bool):
        self.prefix, self.quiet, self.last = prefix, quiet, (-1, "")
        self.tty = sys.stderr.isatty()

    def __call__(self, fraction: float, stage: str) -> None:
        if self.quiet:
            return
        key = (int(fraction * 20), stage.split(" ")[0])
        if key == self.last and fraction < 1.0:
            return
        self.last = key
        line = f"{self.prefix}{fraction:6.1%}  {stage}"
        print(("\r" + line.ljust(70)) if self.tty else line, end="" if self.tty else "\n", file=sys.stderr, flush=True)
        if self.tty and fraction >= 1.0:
            print(file=sys.stderr)


def _settings(args):
    from gcs_pdm.fitting.procedure import FitSettings
    from gcs_pdm.fitting.search import SearchSettings

    import dataclasses

    given = {"seed": args.seed}
    for k in ("starts", "sa_generations", "sa_proposals", "lm_max_nfev"):
        if getattr(args, k) is not None:
            given[k] = getattr(args, k)
    defaults = FitSettings()
    # the flags tune the search of the variant being fitted (each variant keeps its own defaults)
    return FitSettings(search=SearchSettings(**given), base=args.base, reference=args.reference, workers=args.workers,
                       model=getattr(args, "model", "paper") if getattr(args, "fit_what", None) != "motor" else "paper",
                       extended_search=dataclasses.replace(defaults.extended_search, **given))


def _summary(res) -> dict:
    e = res.errors
    out = {"component": res.component, "pack": res.pack, "model": res.model, "seconds": round(res.seconds, 2)}
    if res.model is not None and not res.thermal.get("fitted", True):
        out["thermal_not_fitted"] = res.thermal.get("reason", "")
    if res.initial_soc_support is not None:
        out["initial_soc_support"] = {f["flight"]: f["support"] for f in res.initial_soc_support["flights"]}
    if res.operating_envelope is not None:
        out["outside_training_conditions"] = [f["flight"] for f in res.operating_envelope["flights"] if not f["inside"]]
    if res.model is not None:  # a battery fit
        out["left_out_training_flights"] = [x["flight"] for x in res.left_out]
    if res.candidate_agreement is not None:
        # None when only one candidate fitted well enough to compare: unknown, not "all determined"
        out["undetermined_flights"] = ([f["flight"] for f in res.candidate_agreement["flights"] if f["determined"] is False]
                                       if res.candidate_agreement["measured"] else None)
    for which in ("learned", "reference"):
        t = e[which]["test"]["overall"]
        if "voltage" in t:
            out[f"{which}_test_voltage_rmse_v"] = round(t["voltage"]["rmse"], 4)
        rmse_f = t.get("temperature", {}).get("rmse_f")
        if rmse_f is not None and rmse_f == rmse_f:  # a log without pack temperature has none (NaN)
            out[f"{which}_test_temperature_rmse_f"] = round(t["temperature"]["rmse_f"], 3)
    return out


def _print_warnings(res, label: str | None) -> None:
    """The result's own warnings (e.g. poorly supported initial SoCs) on stderr, one a line."""
    for w in res.warnings:
        print(f"fit: warning: {label + ': ' if label else ''}{w}", file=sys.stderr)


def run_vehicle(args: argparse.Namespace, settings, desc=None) -> int:
    """``fit battery --vehicle X``: each of the description's packs (or ``--pack``), a parameter set of
    its packs and the description pointing at it (gcs_pdm/fitting/vehicle.py). ``desc``: a description
    already at hand (derived from an autopilot log) instead of ``--vehicle``."""
    from gcs_pdm.fitting.logs import read_flights, write_outputs
    from gcs_pdm.logs.tables import BATTERY, MOTOR, FlightDataError
    from gcs_pdm.vehicle.description import VehicleError
    from gcs_pdm.fitting.vehicle import fit_motors, fit_packs, start_soc_warnings, write_fitted
    from gcs_pdm.vehicle.presets import resolve

    try:
        desc = desc if desc is not None else resolve(args.vehicle)
    except VehicleError as exc:
        print(f"gcs-pdm fit {args.fit_command}: error: {exc}", file=sys.stderr)
        return 2
    pack_arg = getattr(args, "pack", None)
    packs = desc.pack_names if pack_arg in (None, "all") else (pack_arg,)
    if any(p not in desc.pack_names for p in packs):
        print(f"gcs-pdm fit {args.fit_command}: error: --pack {pack_arg}: vehicle {desc.name} has packs {', '.join(desc.pack_names)}", file=sys.stderr)
        return 2
    splits = {"train": args.train, "validation": args.val, "test": args.test}

    def read(paths, pack):
        kind = BATTERY if args.fit_what == "battery" else MOTOR
        return [f for path in paths for f in read_flights(path, kind, pack=pack or "all", vehicle=desc)]

    try:
        if args.fit_what == "battery":
            merged, results = fit_packs(desc, read, splits, settings, packs,
                                        progress=lambda name: _ProgressLine(f"fit battery {name}: ", args.quiet))
        else:
            merged, results = fit_motors(desc, read, splits, settings, _ProgressLine("fit motor: ", args.quiet))
    except (FlightDataError, VehicleError, ValueError) as exc:
        print(f"gcs-pdm fit {args.fit_command}: error: {exc}", file=sys.stderr)
        return 2
    for name, res in results.items():
        write_outputs(res, args.out / name if len(results) > 1 else args.out, plots=not args.no_plots)
        _print_warnings(res, name)
        warnings = (start_soc_warnings(res, next(p for p in desc.packs if p.name == name))
                    if args.fit_what == "battery" and settings.model == "paper" else [])
        for w in warnings:
            print(f"fit: warning: {name}: {w}", file=sys.stderr)
        print(json.dumps({**_summary(res), "vehicle": desc.name, **({"warnings": warnings} if warnings else {})}))
    set_path, desc_path = write_fitted(desc, merged, tuple(results) if args.fit_what == "battery" else (),
                                       args.out, motors=args.fit_what == "motor")
    if settings.model == "extended" and args.fit_what == "battery":
        print("fit: note: the service's estimator, planner and simulated vehicle read the paper variant; for them "
              "these packs keep their starting circuit (fit with --model paper for a circuit they use)", file=sys.stderr)
    print(f"fit: results in {args.out}; parameter set {set_path}; description {desc_path} "
          f"(gcs-pdm vehicle check {desc_path})", file=sys.stderr)
    return 0


def run(args: argparse.Namespace) -> int:
    from gcs_pdm.fitting.logs import AUTOPILOT_LOG_SUFFIXES, read_flights, write_outputs
    from gcs_pdm.fitting.procedure import fit_battery, fit_motor, merge_results
    from gcs_pdm.logs.tables import FlightDataError
    from gcs_pdm.models.params import builtin
    from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

    kind = args.fit_what
    try:
        settings = _settings(args)
        builtin(settings.base), builtin(settings.reference)
    except (KeyError, TypeError, ValueError) as exc:
        print(f"gcs-pdm fit {args.fit_command}: error: {exc}", file=sys.stderr)
        return 2
    if getattr(args, "vehicle", None) is not None:
        return run_vehicle(args, settings)
    if args.train[0].suffix.lower() in AUTOPILOT_LOG_SUFFIXES:
        # an autopilot's own log names its vehicle: derived as replay and `vehicle init` derive it
        # (one derivation for tlog, .bin and .ulg), its packs by battery instance
        from gcs_pdm.vehicle.description import VehicleError
        from gcs_pdm.logs.provisional_vehicle import observe_file

        try:
            desc, notes = observe_file(args.train[0])
        except VehicleError as exc:
            print(f"gcs-pdm fit {args.fit_command}: error: no --vehicle, and none could be derived from {args.train[0]}: {exc}", file=sys.stderr)
            return 2
        for note in notes:
            print(f"fit: vehicle (derived from {args.train[0].name}): {note}", file=sys.stderr)
        return run_vehicle(args, settings, desc)
    # no --vehicle, and no autopilot log to derive one from: the paper's aircraft, the edge540 preset
    # (its packs at BATTERY_STATUS ids 0-3 of a tlog), fitted into a set of the paper's layout
    paper = PRESETS[DEFAULT_PRESET]
    pack_arg = getattr(args, "pack", None)
    if pack_arg not in (None, "all") + paper.pack_names:
        print(f"gcs-pdm fit {args.fit_command}: error: --pack {pack_arg}: expected one of {', '.join(paper.pack_names)} or all (another vehicle's packs: "
              "--vehicle FILE|PRESET)", file=sys.stderr)
        return 2
    any_tlog = any(p.suffix.lower() == ".tlog" for p in args.train + args.val + args.test)
    if kind == "battery":
        packs = (paper.pack_names if pack_arg in (None, "all") else (pack_arg,)) if any_tlog else (pack_arg or paper.pack_names[0],)
        if not any_tlog and "all" in packs:
            print(f"gcs-pdm fit {args.fit_command}: error: a table holds one pack; name it with --pack (or give tlogs for --pack all)", file=sys.stderr)
            return 2
    else:
        packs = (None,)
    results = {}
    try:
        for pack in packs:
            def load(paths):
                flights = []
                for path in paths:
                    fl = read_flights(path, kind, pack=pack or "all", vehicle=paper)
                    flights += fl
                return flights
            train, val, test = load(args.train), load(args.val), load(args.test)
            prog = _ProgressLine(f"fit {kind}{' ' + pack if pack else ''}: ", args.quiet)
            if kind == "battery":
                res = fit_battery(train, val, test, settings, pack=pack, progress=prog)
            else:
                res = fit_motor(train, val, test, settings, progress=prog)
            out = args.out / pack if len(packs) > 1 else args.out
            write_outputs(res, out, plots=not args.no_plots)
            results[pack] = res
            _print_warnings(res, pack)
            print(json.dumps(_summary(res)))
    except FlightDataError as exc:
        print(f"gcs-pdm fit {args.fit_command}: error: {exc}", file=sys.stderr)
        return 2
    if kind == "battery" and len(results) > 1:
        merged = merge_results(builtin(settings.base), results, name="learned",
                               provenance={"source": "gcs-pdm fit battery", "files": {
                                   "train": [str(p) for p in args.train], "validation": [str(p) for p in args.val],
                                   "test": [str(p) for p in args.test]}})
        (args.out / "parameters.json").write_text(merged.to_json(indent=2))
    print(f"fit: results in {args.out}", file=sys.stderr)
    return 0


def run_synthetic(args: argparse.Namespace) -> int:
    from gcs_pdm.fitting.logs import write_table
    from gcs_pdm.fitting.synthetic import NO_DAMAGE, Damage, generate_flights, synthetic_truth

    truth = synthetic_truth(args.truth_seed)
    args.out.mkdir(parents=True, exist_ok=True)
    flights = generate_flights(truth, args.flights, seed=args.seed, damage=NO_DAMAGE if args.clean else Damage())
    for f in flights:
        for pack, fl in f.packs.items():
            write_table(fl, args.out / f"{f.name}_{pack}.csv")
        write_table(f.motor, args.out / f"{f.name}_motor.csv")
    (args.out / "truth.json").write_text(truth.to_json(indent=2))
    print(f"fit synthetic: {args.flights} flights x 5 logs and truth.json in {args.out}", file=sys.stderr)
    return 0


def run_learn_synthetic(args: argparse.Namespace) -> int:
    from gcs_pdm.fitting.learn_synthetic import learn_from_synthetic
    from gcs_pdm.fitting.procedure import FitSettings
    from gcs_pdm.fitting.search import SearchSettings
    from gcs_pdm.sim.truth import DEFAULT_TRUTH_SEED, true_parameters

    truth = true_parameters(args.truth_seed if args.truth_seed is not None else DEFAULT_TRUTH_SEED)
    merged, results = learn_from_synthetic(truth, flights=args.flights, seed=args.seed,
                                           settings=FitSettings(search=SearchSettings(seed=args.fit_seed), model="paper"),
                                           progress=_ProgressLine("learn: ", args.quiet))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(merged.to_json(indent=2))
    for part, res in results.items():
        print(json.dumps({"part": part, **_summary(res)}))
    print(f"fit learn-synthetic: wrote {args.out}", file=sys.stderr)
    return 0


def run_set(args: argparse.Namespace) -> int:
    from gcs_pdm.fitting.learn_set import learn_from_tlogs
    from gcs_pdm.fitting.logs import write_outputs
    from gcs_pdm.logs.tables import FlightDataError
    from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

    try:
        settings = _settings(args)
        # a whole set of the paper's layout: its tlogs are the paper's aircraft's, the edge540 preset
        merged, results = learn_from_tlogs(args.train, args.val, args.test, settings, PRESETS[DEFAULT_PRESET],
                                           name=args.name,
                                           provenance={"source": "gcs-pdm fit set", "note": args.note} if args.note
                                           else {"source": "gcs-pdm fit set"},
                                           progress=_ProgressLine("fit set: ", args.quiet))
    except (FlightDataError, KeyError, ValueError) as exc:
        print(f"gcs-pdm fit {args.fit_command}: error: {exc}", file=sys.stderr)
        return 2
    for part, res in results.items():
        write_outputs(res, args.out / part, plots=not args.no_plots)
        _print_warnings(res, part)
        print(json.dumps({"part": part, **_summary(res)}))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "parameters.json").write_text(merged.to_json(indent=2))
    if args.set_out is not None:
        args.set_out.parent.mkdir(parents=True, exist_ok=True)
        args.set_out.write_text(merged.to_json(indent=2))
    print(f"fit set: results in {args.out}", file=sys.stderr)
    return 0
