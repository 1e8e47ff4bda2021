"""``gcs-pdm replay LOG.bin|LOG.ulg``: an autopilot's own log through the same frames as live.

The frames (:func:`gcs_pdm.logs.series.frames`) go, in message-time order, to the same consumer
a tlog replay feeds (the estimator/diagnoser pipeline, with the estimate traced), named by the
vehicle description the replay diagnoses: battery instance → its pack, ESC instance → its motor
(:func:`gcs_pdm.logs.series.described_names`). The summary says what the log lacked, what it had
that the description does not name, and what could not be diagnosed; the exit status is a tlog
replay's (docs/mavlink.md, "Replay"). The command that prints it is ``gcs_pdm.replay.cli``.
"""
from __future__ import annotations

import logging
import math
import time
from collections import Counter
from pathlib import Path

from gcs_pdm.frames import FRAME_KIND_OF

log = logging.getLogger(__name__)


def replay_log(path: str | Path, vehicle, frame_consumer=None) -> dict:
    """Replay ``path`` into ``frame_consumer``; ``vehicle`` (a description: the command resolves
    none to the paper's aircraft, edge540) names the packs and motors by instance.
    Raises FlightDataError when the file cannot be read."""
    from gcs_pdm.logs.reader import read_log
    from gcs_pdm.logs.series import described_names, frames

    started = time.perf_counter()
    series = read_log(path)
    pack_names, motor_names, unnamed = described_names(series, vehicle)
    for what, why in unnamed.items():
        log.warning("replay: %s: %s left out: %s", Path(path).name, what, why)
    out = frames(series, pack_names, motor_names)
    if frame_consumer is not None:
        _hand_over(out, frame_consumer)
    report = getattr(frame_consumer, "report", None)
    consumer_report = report() if callable(report) else None
    faults = list(consumer_report.get("faults", [])) if isinstance(consumer_report, dict) else []
    kinds = Counter(FRAME_KIND_OF[type(f)] for f in out)
    packs = {pack_names[i]: {"instance": i, "samples": int(b.time_s.size), "cells": b.cells}
             for i, b in sorted(series.batteries.items()) if i in pack_names}
    return {
        "path": str(path), "autopilot": series.autopilot, "readable": True, "frames": len(out),
        "frames_by_kind": dict(sorted(kinds.items())),
        "frame_time_span_s": (out[0].time_s, out[-1].time_s) if out else None,
        "packs": packs, "escs": sorted(series.escs),
        "motors": {motor_names[i]: i for i in sorted(series.escs) if i in motor_names},
        "left_out": unnamed, "modes": series.modes, "missing": series.missing,
        "not_diagnosed": _not_diagnosed(series, kinds, vehicle),
        "elapsed_s": time.perf_counter() - started, "consumer": consumer_report, "faults": faults,
    }


def _hand_over(frames: list, consume) -> None:
    """Every frame to ``consume``, except, as a tlog replay does (gcs_pdm.mavlink.replay), frames of
    types outside its ``consumed_frame_types`` that are not due for its ``next_due_s``: those are
    counted (``passed_over``) instead."""
    consumed = getattr(consume, "consumed_frame_types", None)
    if consumed is None:
        for frame in frames:
            consume(frame)
        return
    passed = 0
    for frame in frames:
        if type(frame) in consumed or frame.time_s >= getattr(consume, "next_due_s", math.inf):
            consume(frame)
        else:
            passed += 1
    if passed:
        consume.passed_over(passed)


def _not_diagnosed(series, kinds: Counter, vehicle) -> list[str]:
    """What could not be diagnosed and why, one sentence each (as a tlog replay's summary says it)."""
    out = []
    named = f"the description {vehicle.name}'s"
    if not kinds.get("pack"):
        out.append("packs: no battery messages in the log" if not series.batteries else
                   f"packs: none of the log's battery instances ({sorted(series.batteries)}) is one of {named} packs")
    if not kinds.get("motor"):
        out.append("motors: no ESC telemetry in the log" if not series.escs else
                   f"motors: none of the log's ESC instances ({sorted(series.escs)}) is one of {named} motors")
    if series.ambient is None:
        out.append("ambient temperature: none in the log")
    return out


def exit_status(summary: dict) -> int:
    """0: diagnosed; 1: read, but neither packs nor motors could be diagnosed (docs/mavlink.md)."""
    kinds = summary["frames_by_kind"]
    return 0 if kinds.get("pack") or kinds.get("motor") else 1
