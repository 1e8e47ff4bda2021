"""Live, beside real autopilot software (issue 29): the service, told nothing about the vehicle,
alone beside ArduCopter SITL (a 4S 5 Ah pack plugged in partly charged) and ArduPlane SITL
(``../shared/sitl``), each flown for 90 s of vehicle time; the harness of
tests/test_sitl_arducopter.py and tests/test_sitl_arduplane.py.

    PYTHONPATH=$PWD python benchmarks/bench_sitl_live.py [--voltage 15.6] [--flight-s 90] [--speedup 4] [--no-plane]

Figures: what the service asked for and what came; the derived vehicle; the SoC against the truth
(copter: the simulator's starting charge less the charge the autopilot counts) 90 s after take-off
and at worst; the share of samples whose SoC was withheld; a plan asked for 30 s after take-off
(copter); wall seconds. Prints a line per flight and, last, one JSON object.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

import sitl_support as S  # noqa: E402
from test_sitl_arducopter import fly_copter  # noqa: E402
from test_sitl_arduplane import fly_plane  # noqa: E402


def _summary(fig: dict) -> dict:
    keep = ("pack", "vehicle", "soc_at_end", "truth_at_end", "soc_error_at_end", "soc_error_max", "soc_null_samples",
            "samples", "soc_vs_autopilot_max", "drawn_ah", "flight_s", "max_alt_m", "max_airspeed", "plan",
            "set_message_interval", "wall_s")
    out = {k: fig[k] for k in keep if k in fig}
    out["asks"] = {k: v["asks"] for k, v in fig.get("streams_at_start", {}).items()}
    out["streams_at_end"] = fig.get("streams_at_end")
    out["prediction_readiness"] = (fig.get("readiness") or {}).get("prediction")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--voltage", type=float, default=15.6, help="copter pack's voltage at plug-in (16.8 = full)")
    ap.add_argument("--flight-s", type=float, default=90.0)
    ap.add_argument("--speedup", type=float, default=4.0)
    ap.add_argument("--no-plane", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if not S.available("arducopter"):
        print(json.dumps({"skipped": f"no SITL binaries in {S.SITL}"}))
        return 0
    result = {}
    with tempfile.TemporaryDirectory(prefix="bench_sitl_") as tmp:
        copter = fly_copter(Path(tmp) / "copter", S.CopterPack(voltage=args.voltage), args.flight_s, args.speedup)
        result["arducopter"] = _summary(copter)
        soc = "withheld" if copter["soc_at_end"] is None else f"{copter['soc_at_end']:.3f}"
        print(f"arducopter: SoC {soc} vs truth {copter['truth_at_end']:.3f} after "
              f"{copter['flight_s']:.0f} s (error {copter['soc_error_at_end']}), {copter['wall_s']} s wall")
        if not args.no_plane and S.available("arduplane"):
            plane = fly_plane(Path(tmp) / "plane", args.flight_s, args.speedup)
            result["arduplane"] = _summary(plane)
            print(f"arduplane: SoC withheld in {plane['soc_null_samples']} of {plane['samples']} samples, "
                  f"{plane['wall_s']} s wall")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
