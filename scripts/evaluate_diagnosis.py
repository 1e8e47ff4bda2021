"""Evaluate the estimator and diagnoser on seeded flights; print the detection table (markdown)
and, as the last line, one JSON object with every figure.

Flights (all seeded; the simulated vehicle's hidden truth differs from the service's parameter set
``paper_si`` by up to 15 % per parameter, as in flight):

- fault-free: noisy telemetry with drop-outs, a burst outage and spikes;
- motor power loss: fwd/aft, magnitudes 0.15–0.8, injected at a random time;
- pack degradation: one pack with capacity ×0.65 or resistance ×2.5;
- infeasible after a fault: a long mission and a large motor fault, which the vehicle cannot finish.

A detection is the first raise of the injected type on the injected component after the injection
(for degradation present from take-off: any time); a false alarm is any other raise, except the
consequences the injected fault legitimately triggers (a degradation-rate deviation after it,
a predicted limit violation on a flight that did fail). A limit violation predicted on a flight the
vehicle finished counts as a false alarm. Recorded flights in ``fixtures/flights/`` (tlog + truth json)
are replayed too when present.

Run: ``python scripts/evaluate_diagnosis.py`` (1.5–5 minutes on one core; ``--quick`` for fewer flights,
``--fixtures-only`` / ``--no-fixtures`` for one half).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

from gcs_pdm.diagnosis.faults import (ADVISORY_TYPES, DEGRADATION_RATE_DEVIATION, MODEL_MISMATCH, MOTOR_POWER_LOSS,
                                      PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE, PREDICTED_LIMIT_VIOLATION)
from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.estimation.prediction import FutureLoad
from gcs_pdm.estimation.synthetic import PackDegradation, fly_synthetic
from gcs_pdm.models import kernel
from gcs_pdm.models.params import PACK_NAMES, default_set
from gcs_pdm.sim.truth import true_parameters

STAMP_RESOLUTION_S = 5.0
CONSEQUENCES = {PREDICTED_LIMIT_VIOLATION, DEGRADATION_RATE_DEVIATION}


def run_flight(flight, params, with_mission=True):
    p = DiagnosisPipeline(params)
    if with_mission:
        p.set_mission(FutureLoad(np.diff(flight.time_s, prepend=flight.time_s[0]), flight.shaft_power_w,
                                 float(np.mean(flight.ambient_c))), flight.time_s[0])
    soc_err, soc_z = [], []
    next_t = flight.time_s[0] + 60.0
    for fr in flight.frames:
        p.consume(fr)
        if fr.time_s >= next_t and p.estimator.ready():
            next_t += 10.0
            e = p.estimator.estimate()
            k = min(int(np.searchsorted(flight.time_s, e.time_s)), flight.time_s.size - 1)
            err = e.soc - flight.soc[k]
            soc_err.append(err)
            soc_z.append(np.abs(err) / e.soc_sd)
    return p, np.asarray(soc_err), np.asarray(soc_z)


def expected(flight):
    """(type, component, onset time or None for from take-off, true magnitude vs the parameter set)."""
    out = []
    model = default_set().pack_matrix()
    flown = flight.truth.pack_matrix()
    if flight.fault_motor and flight.fault_time_s is not None:
        out.append((MOTOR_POWER_LOSS, flight.fault_motor, flight.fault_time_s, flight.fault_magnitude))
    for d in flight.degradation:
        b = PACK_NAMES.index(d.pack)
        if d.capacity != 1.0:
            out.append((PACK_CAPACITY_LOSS, d.pack, None, 1.0 - flown[b, kernel.I_CB] / model[b, kernel.I_CB]))
        if d.resistance != 1.0:
            r = (flown[b, kernel.I_RS] + flown[b, kernel.I_RCP0]) / (model[b, kernel.I_RS] + model[b, kernel.I_RCP0])
            out.append((PACK_RESISTANCE_RISE, d.pack, None, r - 1.0))
    if flight.info.get("failed_at_s") is not None:
        out.append((PREDICTED_LIMIT_VIOLATION, "vehicle", flight.fault_time_s, None))
    return out


def score(flight, p):
    exp = expected(flight)
    hits, false_alarms = [], []
    matched = set()
    first_onset = min([e[2] for e in exp if e[2] is not None], default=None)
    for f in p.faults:
        match = None
        for j, (ty, comp, onset, mag) in enumerate(exp):
            if f.type == ty and f.component == comp and (onset is None or f.time_s >= onset) and j not in matched:
                match = j
                break
        if match is not None:
            matched.add(match)
            ty, comp, onset, mag = exp[match]
            hits.append({"type": ty, "component": comp, "delay_s": None if onset is None else f.time_s - onset,
                         "detected_at_s": f.time_s, "magnitude": f.magnitude, "true_magnitude": mag,
                         "lead_s": (flight.info["failed_at_s"] - f.time_s) if ty == PREDICTED_LIMIT_VIOLATION else None})
        elif f.type == PREDICTED_LIMIT_VIOLATION and flight.info.get("failed_at_s") is None:
            false_alarms.append(f.to_dict())  # the vehicle did finish: the warning was wrong
        elif f.type == MODEL_MISMATCH and f.component in {d.pack for d in flight.degradation}:
            continue  # a degraded pack no longer matches the set's model: right, but not the fault scored
        elif f.type in CONSEQUENCES and first_onset is not None and f.time_s >= first_onset:
            continue
        elif f.type in CONSEQUENCES and any(e[2] is None for e in exp):
            continue  # degradation present from take-off: its consequences may fire at any time
        else:
            false_alarms.append(f.to_dict())
    missed = [{"type": e[0], "component": e[1]} for j, e in enumerate(exp) if j not in matched]
    return hits, false_alarms, missed


def flights(quick: bool):
    n_free = 4 if quick else 10
    specs = []
    for k in range(n_free):
        specs.append(("fault-free", dict(duration_s=1200.0, initial_soc=float(np.random.default_rng(k).uniform(0.85, 1.0))),
                      2013 + k, 100 + k))
    mags = (0.15, 0.3, 0.5, 0.8)
    for k, (motor, m) in enumerate([(mo, m) for m in mags for mo in ("fwd", "aft")][: (4 if quick else 8)]):
        t_f = float(np.random.default_rng(200 + k).uniform(300.0, 700.0))
        specs.append(("motor power loss", dict(duration_s=1200.0, fault_motor=motor, fault_magnitude=m,
                                               fault_time_s=t_f), 2013 + k, 200 + k))
    degr = [PackDegradation("URA40", capacity=0.65), PackDegradation("LLF20", resistance=2.5),
            PackDegradation("ULA20", capacity=0.65), PackDegradation("LRF40", resistance=2.5),
            PackDegradation("LLF20", capacity=0.65), PackDegradation("URA40", resistance=2.5)]
    for k, d in enumerate(degr[: (2 if quick else 6)]):
        specs.append(("pack degradation", dict(duration_s=1200.0, degradation=(d,)), 2013 + k, 300 + k))
    for k, (motor, m) in enumerate([("fwd", 0.9), ("aft", 0.8), ("fwd", 0.7), ("aft", 0.9)][: (2 if quick else 4)]):
        specs.append(("infeasible after fault", dict(duration_s=1800.0, initial_soc=0.7, fault_motor=motor,
                                                     fault_magnitude=m, fault_time_s=300.0 + 60 * k), 2013 + k, 400 + k))
    return specs


def evaluate_fixtures(root: Path) -> dict:
    """Replay the simulated vehicle's recorded flights (``manifest.json`` beside the tlogs) through
    the pipeline and score them against the manifest's truth. No mission load is given (the
    prognostic checks stay silent here).

    The manifest's fault times are simulated time, which is the vehicle's boot clock, i.e. frame
    time. Frames without a time field are stamped with the latest timed message ("hold last",
    docs/mavlink.md), a resolution of up to ``STAMP_RESOLUTION_S`` in these recordings, so a
    detection may carry a stamp up to that much before the onset."""
    from gcs_pdm.mavlink.replay import replay_tlog

    manifest_path = root / "manifest.json"
    if not manifest_path.is_file():
        return {"flights": [], "note": f"no {manifest_path}"}
    manifest = json.loads(manifest_path.read_text())
    rows = []
    for fl in manifest.get("flights", []):
        tlog = root / fl["tlog"]
        if not tlog.is_file():
            continue
        p = DiagnosisPipeline(default_set())
        replay_tlog(tlog, frame_consumer=p)
        faults = p.faults
        hits, false_alarms, used = [], [], set()
        for inj in fl.get("faults", []):
            onset = float(inj["time_s"])
            match = next((f for f in faults if f.type == MOTOR_POWER_LOSS and f.component == inj["motor"]
                          and f.time_s >= onset - STAMP_RESOLUTION_S and id(f) not in used), None)
            if match is not None:
                used.add(id(match))
                hits.append({"type": MOTOR_POWER_LOSS, "component": inj["motor"], "delay_s": match.time_s - onset,
                             "magnitude": match.magnitude, "true_magnitude": float(inj["magnitude"]), "lead_s": None})
        first_onset = min((float(i["time_s"]) for i in fl.get("faults", [])), default=None)
        for f in faults:
            if id(f) in used:
                continue
            if f.type in CONSEQUENCES and first_onset is not None and f.time_s >= first_onset:
                continue
            false_alarms.append({k: f.to_dict()[k] for k in ("type", "component", "magnitude", "time_s")})
        est = p.estimator.estimate()
        final_soc = np.asarray(fl.get("final_soc", [np.nan] * 4), dtype=np.float64)
        rows.append({"flight": fl["name"], "duration_s": fl.get("duration_s"), "injected": len(fl.get("faults", [])),
                     "hits": hits, "false_alarms": false_alarms,
                     "final_soc_error": [round(float(x), 4) for x in est.soc - final_soc],
                     "final_soc_sd": [round(float(x), 4) for x in est.soc_sd]})
    return {"flights": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer flights (smoke run)")
    ap.add_argument("--fixtures", type=Path, default=Path("fixtures/flights"))
    ap.add_argument("--no-fixtures", action="store_true", help="synthetic flights only")
    ap.add_argument("--fixtures-only", action="store_true", help="recorded flights only")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    started = time.perf_counter()
    params = default_set()
    per_class: dict[str, dict] = {}
    all_hits, soc_err_all, soc_z_all = [], [], []
    fault_free_hours, fault_free_alarms, total_hours, total_alarms = 0.0, 0, 0.0, 0
    for cls, kw, truth_seed, seed in ([] if args.fixtures_only else flights(args.quick)):
        flight = fly_synthetic(true_parameters(truth_seed), np.random.default_rng(seed), **kw)
        p, soc_err, soc_z = run_flight(flight, params)
        hits, fa, missed = score(flight, p)
        # advisories (a pack no longer matching the set's model) are told, not faults: counted apart
        advisories = [f for f in fa if f["type"] in ADVISORY_TYPES]
        fa = [f for f in fa if f["type"] not in ADVISORY_TYPES]
        hours = flight.duration_s / 3600.0
        c = per_class.setdefault(cls, {"flights": 0, "hours": 0.0, "expected": 0, "detected": 0, "false_alarms": 0,
                                       "false_alarm_details": [], "advisories": []})
        c["advisories"] += [{"seed": seed, **{k: f[k] for k in ("type", "component", "magnitude", "time_s")}}
                            for f in advisories]
        c["flights"] += 1
        c["hours"] += hours
        c["expected"] += len(hits) + len(missed)
        c["detected"] += len(hits)
        c["false_alarms"] += len(fa)
        c["false_alarm_details"] += [{"seed": seed, **{k: f[k] for k in ("type", "component", "magnitude", "time_s")}}
                                     for f in fa]
        total_hours += hours
        total_alarms += len(fa)
        if cls == "fault-free":
            fault_free_hours += hours
            fault_free_alarms += len(fa)
        all_hits += hits
        if soc_err.size:
            soc_err_all.append(soc_err.ravel())
            soc_z_all.append(soc_z.ravel())
            c.setdefault("_soc_err", []).append(soc_err.ravel())
            c.setdefault("_soc_z", []).append(soc_z.ravel())
        logging.getLogger("evaluate").info("%s seed %d: %d hits, %d false, %d missed", cls, seed, len(hits), len(fa), len(missed))

    def by_type(ty):
        hs = [h for h in all_hits if h["type"] == ty]
        delays = [h["delay_s"] for h in hs if h["delay_s"] is not None]
        mag_err = [abs(h["magnitude"] - h["true_magnitude"]) for h in hs if h["true_magnitude"] is not None]
        lead = [h["lead_s"] for h in hs if h["lead_s"] is not None]
        at = [h["detected_at_s"] for h in hs if h["delay_s"] is None]
        return {"detections": len(hs),
                "mean_detected_at_s_present_from_takeoff": round(float(np.mean(at)), 1) if at else None,
                "mean_delay_s": round(float(np.mean(delays)), 1) if delays else None,
                "max_delay_s": round(float(np.max(delays)), 1) if delays else None,
                "mean_abs_magnitude_error": round(float(np.mean(mag_err)), 3) if mag_err else None,
                "max_abs_magnitude_error": round(float(np.max(mag_err)), 3) if mag_err else None,
                "mean_warning_before_failure_s": round(float(np.mean(lead)), 1) if lead else None}

    soc_err_all = np.concatenate(soc_err_all) if soc_err_all else np.zeros(0)
    soc_z_all = np.concatenate(soc_z_all) if soc_z_all else np.zeros(0)
    for c in per_class.values():
        e = np.concatenate(c.pop("_soc_err", [np.zeros(0)]))
        z = np.concatenate(c.pop("_soc_z", [np.zeros(0)]))
        c["soc_rmse"] = float(np.sqrt(np.mean(e ** 2))) if e.size else None
        c["soc_abs_error_p95"] = float(np.quantile(np.abs(e), 0.95)) if e.size else None
        c["soc_within_2sd"] = float(np.mean(z <= 2.0)) if z.size else None
    result = {
        "classes": {k: {kk: (round(vv, 4) if isinstance(vv, float) else vv) for kk, vv in v.items()}
                    for k, v in per_class.items()},
        "types": {ty: by_type(ty) for ty in (MOTOR_POWER_LOSS, PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE,
                                             PREDICTED_LIMIT_VIOLATION)},
        "false_alarms_per_flight_hour_fault_free": round(fault_free_alarms / fault_free_hours, 3) if fault_free_hours else None,
        "false_alarms_per_flight_hour_all": round(total_alarms / total_hours, 3) if total_hours else None,
        "flight_hours": round(total_hours, 2),
        "soc_rmse": round(float(np.sqrt(np.mean(soc_err_all ** 2))), 4) if soc_err_all.size else None,
        "soc_abs_error_p95": round(float(np.quantile(np.abs(soc_err_all), 0.95)), 4) if soc_err_all.size else None,
        "soc_within_2sd": round(float(np.mean(soc_z_all <= 2.0)), 3) if soc_z_all.size else None,
        "elapsed_s": None,
    }
    fixtures = evaluate_fixtures(args.fixtures) if args.fixtures.is_dir() and not args.no_fixtures else {"flights": []}
    fx = fixtures["flights"]
    if fx:
        fx_hits = [h for r in fx for h in r["hits"]]
        fx_hours = sum((r["duration_s"] or 0.0) for r in fx) / 3600.0
        fx_soc = np.array([e for r in fx for e in r["final_soc_error"]])
        fx_z = np.abs(fx_soc) / np.array([s for r in fx for s in r["final_soc_sd"]])
        result["fixtures"] = {
            "flights": len(fx), "flight_hours": round(fx_hours, 2),
            "injected": sum(r["injected"] for r in fx), "detected": len(fx_hits),
            "mean_delay_s": round(float(np.mean([h["delay_s"] for h in fx_hits])), 1) if fx_hits else None,
            "max_delay_s": round(float(np.max([h["delay_s"] for h in fx_hits])), 1) if fx_hits else None,
            "mean_abs_magnitude_error": round(float(np.mean([abs(h["magnitude"] - h["true_magnitude"]) for h in fx_hits])), 3)
            if fx_hits else None,
            "false_alarms": sum(len(r["false_alarms"]) for r in fx),
            "false_alarms_per_flight_hour": round(sum(len(r["false_alarms"]) for r in fx) / fx_hours, 3) if fx_hours else None,
            "final_soc_rmse": round(float(np.sqrt(np.nanmean(fx_soc ** 2))), 4),
            "final_soc_abs_error_max": round(float(np.nanmax(np.abs(fx_soc))), 4),
            "final_soc_within_2sd": round(float(np.nanmean(fx_z <= 2.0)), 3),
        }
    result["fixture_flights"] = fx
    result["elapsed_s"] = round(time.perf_counter() - started, 1)

    print("| flights | n | flight h | expected | detected | detection rate | false alarms | false alarms / h | SoC RMS error | SoC p95 abs error | SoC within 2σ |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for cls, c in per_class.items():
        rate = c["detected"] / c["expected"] if c["expected"] else float("nan")
        print(f"| {cls} | {c['flights']} | {c['hours']:.2f} | {c['expected']} | {c['detected']} | "
              f"{'—' if math.isnan(rate) else f'{rate:.0%}'} | {c['false_alarms']} | {c['false_alarms'] / c['hours']:.2f} | "
              f"{c['soc_rmse']:.3f} | {c['soc_abs_error_p95']:.3f} | {c['soc_within_2sd']:.0%} |")
    for cls, c in per_class.items():
        for a in c["advisories"]:
            print(f"advisory on a {cls} flight (seed {a['seed']}): {a['type']} {a['component']} at {a['time_s']:.0f} s, "
                  f"statistic {a['magnitude']:.2f}")
    print()
    print("| fault type | detections | mean delay s | max delay s | present from take-off: mean detection time s | mean abs magnitude error | max abs magnitude error | mean warning before failure s |")
    print("|---|---|---|---|---|---|---|---|")
    for ty, t in result["types"].items():
        cells = [t[k] if t[k] is not None else "—" for k in ("detections", "mean_delay_s", "max_delay_s",
                                                              "mean_detected_at_s_present_from_takeoff",
                                                              "mean_abs_magnitude_error", "max_abs_magnitude_error",
                                                              "mean_warning_before_failure_s")]
        print(f"| {ty} | " + " | ".join(str(x) for x in cells) + " |")
    print()
    if "fixtures" in result:
        fx = result["fixtures"]
        print(f"Recorded flights ({args.fixtures}): {fx['flights']} flights, {fx['flight_hours']} h; motor faults "
              f"{fx['detected']}/{fx['injected']} detected, mean delay {fx['mean_delay_s']} s (max {fx['max_delay_s']} s), "
              f"mean abs magnitude error {fx['mean_abs_magnitude_error']}; false alarms {fx['false_alarms']} "
              f"({fx['false_alarms_per_flight_hour']} per flight hour); final SoC error RMS {fx['final_soc_rmse']}, "
              f"max {fx['final_soc_abs_error_max']}, within 2σ {fx['final_soc_within_2sd']}")
        print()
    print(f"SoC error vs truth over all flights (every 10 s after the first minute): RMS {result['soc_rmse']}, "
          f"95th percentile |error| {result['soc_abs_error_p95']}, within 2σ {result['soc_within_2sd']}")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
