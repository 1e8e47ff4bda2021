"""``gcs-pdm replay LOG.bin|LOG.ulg``: an autopilot's own log through the same frames as live.

The frames (:func:`gcs_pdm.logs.series.frames`) go, in message-time order, to the same consumer
a tlog replay feeds (the estimator/diagnoser pipeline), and the summary says what the log lacked.
"""
from __future__ import annotations

import json
import time
from collections import Counter
from pathlib import Path

from gcs_pdm.fitting.tables import FlightDataError
from gcs_pdm.frames import FRAME_KIND_OF


def replay_log(path: str | Path, frame_consumer=None) -> dict:
    from gcs_pdm.logs.reader import read_log
    from gcs_pdm.logs.series import frames

    started = time.perf_counter()
    series = read_log(path)
    out = frames(series)
    if frame_consumer is not None:
        for frame in out:
            frame_consumer(frame)
    report = getattr(frame_consumer, "report", None)
    consumer_report = report() if callable(report) else None
    faults = list(consumer_report.get("faults", [])) if isinstance(consumer_report, dict) else []
    kinds = Counter(FRAME_KIND_OF[type(f)] for f in out)
    return {
        "path": str(path), "autopilot": series.autopilot, "frames": len(out),
        "frames_by_kind": dict(sorted(kinds.items())),
        "frame_time_span_s": (out[0].time_s, out[-1].time_s) if out else None,
        "packs": {name: {"instance": b.instance, "samples": int(b.time_s.size), "cells": b.cells}
                  for name, b in series.packs().items()},
        "escs": sorted(series.escs), "modes": series.modes, "missing": series.missing,
        "elapsed_s": time.perf_counter() - started, "consumer": consumer_report, "faults": faults,
    }


def print_replay(path: Path, frame_consumer=None, as_json: bool = False) -> int:
    import sys

    try:
        summary = replay_log(path, frame_consumer)
    except FlightDataError as exc:
        print(f"gcs-pdm replay: error: {exc}", file=sys.stderr)
        return 2
    if as_json:
        print(json.dumps(summary, default=str))
        return 0
    print(f"{summary['path']}: {summary['autopilot']} log, {summary['frames']} frames in {summary['elapsed_s']:.3f} s; "
          f"frame time span {summary['frame_time_span_s']}")
    print("  frames by kind: " + ", ".join(f"{k}={v}" for k, v in summary["frames_by_kind"].items()))
    print(f"  packs: {summary['packs']}; ESC instances: {summary['escs']}")
    for what, why in summary["missing"].items():
        print(f"  missing: {what}: {why}")
    print(f"  faults raised: {summary['faults'] if summary['consumer'] is not None else 'n/a (no estimator attached)'}")
    return 0
