"""Cleaning flight logs before fitting: every repair counted, every rejection explained.

Order of the repairs (each one counted in :class:`CleaningReport` under the key shown):

1. rows without a finite time are dropped (``nan_time_rows``);
2. unit mistakes that can be detected: a pack voltage whose median is above 200 is in mV
   (``voltage_mv_to_v``); a temperature column whose median is above 200 is in kelvin
   (``<column>_kelvin_to_c``);
3. timestamps: rows are sorted by time (``backwards_timestamps`` counts the rows that went back in
   time) and a repeated timestamp keeps its first row (``duplicate_timestamps``);
4. sign: this aircraft never charges its packs in flight (no regeneration; a spinning motor draws at
   least its no-load current), so a whole log with a negative median current has the wrong sign
   convention (``current_sign_flipped_log``) and isolated negative samples below
   ``-negative_current_a`` are sign slips (``current_sign_flipped_samples``);
5. values no pack, motor or weather can have become missing (``out_of_range_<column>``);
6. spikes: a sample further than ``spike_sigmas`` robust deviations (and more than the column's
   absolute floor) from the median of its ``spike_window`` neighbours becomes missing
   (``spikes_<column>``) — a Hampel filter, which leaves genuine steps (throttle changes) alone;
7. stuck sensors: ``stuck_samples`` or more identical consecutive readings of a measured output
   (voltage, temperature) are missing (``stuck_runs_<column>``, ``stuck_samples_<column>``); on a
   coarse sensor (more than ``coarse_equal_fraction`` of consecutive readings equal, e.g. whole-degree
   ESC temperatures; ``coarse_sensor_<column>``) only runs of ``stuck_samples_coarse``;
8. missing values: measured outputs stay missing and are left out of the error (``missing_<column>``);
   model inputs (current, ambient) are interpolated in time (``interpolated_<column>``);
9. gaps: a gap up to ``max_bridge_s`` is bridged (the kernel integrates uneven steps exactly, with
   the current logged after the gap held over it — the kernel's zero-order hold); a longer gap splits
   the flight into segments ``name#1``, ``name#2``… (``split_gaps``), each with its own initial
   state; segments shorter than ``min_duration_s`` are dropped (``short_segments_dropped``).

A flight is rejected (:class:`RejectedFlight`, with the reason) when fewer than ``min_rows`` rows
have a time, when more than ``max_missing_fraction`` of a measured output is missing after the
repairs, or when no segment is long enough. Pure: arrays in, arrays out.
"""
from __future__ import annotations

import logging
import warnings
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from gcs_pdm.logs.tables import BATTERY, Flight

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CleaningSettings:
    max_bridge_s: float = 30.0
    min_duration_s: float = 300.0
    min_rows: int = 30
    max_missing_fraction: float = 0.3
    negative_current_a: float = 0.5
    spike_window: int = 7
    spike_sigmas: float = 6.0
    stuck_samples: int = 20
    #: a coarse sensor (most consecutive readings equal, e.g. whole-degree ESC temperatures) is only
    #: called stuck after this many identical readings
    stuck_samples_coarse: int = 300
    coarse_equal_fraction: float = 0.3
    #: physically possible values, per column
    ranges: tuple[tuple[str, float, float], ...] = (
        ("voltage_v", 5.0, 30.0),
        ("current_a", -300.0, 300.0),
        ("temperature_c", -40.0, 120.0),
        ("ambient_c", -50.0, 60.0),
    )
    #: a spike must also exceed this absolute deviation (so noise-free stretches are not flagged)
    spike_floor: tuple[tuple[str, float], ...] = (
        ("voltage_v", 0.5), ("current_a", 20.0), ("temperature_c", 3.0), ("ambient_c", 3.0),
    )


@dataclass
class CleaningReport:
    """What was repaired in one input flight; ``counts`` holds only non-zero repairs."""

    name: str
    rows_in: int
    rows_out: int = 0
    counts: Counter = field(default_factory=Counter)
    segments: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"name": self.name, "rows_in": self.rows_in, "rows_out": self.rows_out,
                "repairs": {k: int(v) for k, v in sorted(self.counts.items()) if v}, "segments": list(self.segments)}


@dataclass(frozen=True)
class RejectedFlight:
    name: str
    reason: str
    report: CleaningReport

    def to_dict(self) -> dict:
        return {"name": self.name, "reason": self.reason, "repairs": self.report.to_dict()["repairs"]}


@dataclass
class CleanResult:
    flights: list[Flight]
    report: CleaningReport
    rejected: RejectedFlight | None = None


def _rolling_median_mad(x: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Centred rolling median and MAD ignoring NaN (edges use the nearest full window)."""
    n = x.size
    half = window // 2
    if n < window:
        med = np.full(n, np.nanmedian(x))
        return med, np.full(n, np.nanmedian(np.abs(x - med)))
    win = np.lib.stride_tricks.sliding_window_view(np.pad(x, half, mode="edge"), window)
    with warnings.catch_warnings():  # an all-missing window gives NaN, which flags nothing
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(win, axis=1)
        mad = np.nanmedian(np.abs(win - med[:, None]), axis=1)
    return med, mad


def _runs_of_equal(x: np.ndarray) -> list[tuple[int, int, int]]:
    """(start, stop, length) of runs of identical consecutive finite values; missing values inside a
    run do not break it (a stuck sensor with drop-outs is still stuck)."""
    idx = np.flatnonzero(np.isfinite(x))
    v = x[idx]
    runs = []
    k = 1
    while k < v.size:
        if v[k] == v[k - 1]:
            start = k - 1
            while k < v.size and v[k] == v[k - 1]:
                k += 1
            runs.append((int(idx[start]), int(idx[k - 1]) + 1, k - start))
        else:
            k += 1
    return runs


def _interpolate(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    if ok.all() or not ok.any():
        return x
    return np.interp(t, t[ok], x[ok])


def clean_flight(flight: Flight, settings: CleaningSettings = CleaningSettings()) -> CleanResult:
    """Repair what can be repaired; split at long gaps; reject (with the reason) what cannot be used."""
    s = settings
    rep = CleaningReport(name=flight.name, rows_in=len(flight))
    c = rep.counts
    cols = {k: np.array(getattr(flight, k), dtype=np.float64) for k in flight.columns()}
    measured = ("voltage_v", "temperature_c") if flight.kind == BATTERY else ("temperature_c",)
    if flight.kind == BATTERY and not np.isfinite(cols["temperature_c"]).any():
        # no pack temperature at all (common in real logs): the voltage alone is still usable
        measured = ("voltage_v",)
        c["no_temperature"] += 1
    inputs = ("current_a", "ambient_c")

    def reject(reason: str) -> CleanResult:
        log.warning("rejected flight %s: %s", flight.name, reason)
        return CleanResult([], rep, RejectedFlight(flight.name, reason, rep))

    # 1. rows without time
    ok = np.isfinite(cols["time_s"])
    c["nan_time_rows"] += int((~ok).sum())
    cols = {k: v[ok] for k, v in cols.items()}
    if cols["time_s"].size < s.min_rows:
        return reject(f"only {cols['time_s'].size} rows with a time (need {s.min_rows})")

    # 2. detectable unit mistakes
    if "voltage_v" in cols and np.nanmedian(cols["voltage_v"]) > 200.0:
        cols["voltage_v"] = cols["voltage_v"] / 1000.0
        c["voltage_mv_to_v"] += 1
    for k in ("temperature_c", "ambient_c"):
        if np.isfinite(cols[k]).any() and np.nanmedian(cols[k]) > 200.0:
            cols[k] = cols[k] - 273.15
            c[f"{k}_kelvin_to_c"] += 1

    # 3. timestamps: sort (stable, so equal times keep log order), then keep the first of duplicates
    t = cols["time_s"]
    c["backwards_timestamps"] += int((np.diff(t) < 0).sum())
    order = np.argsort(t, kind="stable")
    cols = {k: v[order] for k, v in cols.items()}
    keep = np.ones(cols["time_s"].size, dtype=bool)
    keep[1:] = np.diff(cols["time_s"]) > 0
    c["duplicate_timestamps"] += int((~keep).sum())
    cols = {k: v[keep] for k, v in cols.items()}
    t = cols["time_s"]

    # 4. sign
    cur = cols["current_a"]
    if np.isfinite(cur).any() and np.nanmedian(cur) < -s.negative_current_a:
        cur = -cur
        c["current_sign_flipped_log"] += 1
    slips = cur < -s.negative_current_a
    c["current_sign_flipped_samples"] += int(slips.sum())
    cols["current_a"] = np.where(slips, -cur, cur)

    # 5. impossible values
    for k, lo, hi in s.ranges:
        if k in cols:
            bad = np.isfinite(cols[k]) & ((cols[k] < lo) | (cols[k] > hi))
            c[f"out_of_range_{k}"] += int(bad.sum())
            cols[k][bad] = np.nan

    # 6. spikes (Hampel)
    floors = dict(s.spike_floor)
    for k in measured + inputs:
        x = cols[k]
        med, mad = _rolling_median_mad(x, s.spike_window)
        dev = np.abs(x - med)
        spike = np.isfinite(dev) & (dev > s.spike_sigmas * 1.4826 * mad) & (dev > floors.get(k, 0.0))
        c[f"spikes_{k}"] += int(spike.sum())
        x[spike] = np.nan

    # 7. stuck sensors on measured outputs
    for k in measured:
        x = cols[k][np.isfinite(cols[k])]
        coarse = x.size > 1 and float(np.mean(np.diff(x) == 0)) > s.coarse_equal_fraction
        if coarse:
            c[f"coarse_sensor_{k}"] += 1
        limit = s.stuck_samples_coarse if coarse else s.stuck_samples
        for a, b, length in _runs_of_equal(cols[k]):
            if length >= limit:
                c[f"stuck_runs_{k}"] += 1
                c[f"stuck_samples_{k}"] += length
                cols[k][a:b] = np.nan

    # 8. missing values
    for k in measured:
        missing = ~np.isfinite(cols[k])
        c[f"missing_{k}"] += int(missing.sum())
        if missing.mean() > s.max_missing_fraction:
            return reject(f"{missing.mean():.0%} of {k} missing after cleaning (limit {s.max_missing_fraction:.0%})")
    for k in inputs:
        missing = ~np.isfinite(cols[k])
        if missing.all():
            return reject(f"no valid {k}")
        if missing.mean() > s.max_missing_fraction:
            return reject(f"{missing.mean():.0%} of {k} missing (limit {s.max_missing_fraction:.0%})")
        c[f"interpolated_{k}"] += int(missing.sum())
        cols[k] = _interpolate(t, cols[k])

    # 9. gaps
    gaps = np.flatnonzero(np.diff(t) > s.max_bridge_s) + 1
    c["split_gaps"] += int(gaps.size)
    c["bridged_gaps"] += int(((np.diff(t) > 1.5 * np.median(np.diff(t))) & (np.diff(t) <= s.max_bridge_s)).sum())
    bounds = np.concatenate([[0], gaps, [t.size]])
    out: list[Flight] = []
    base = flight.with_columns(**cols)
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        seg_name = flight.name if gaps.size == 0 else f"{flight.name}#{i + 1}"
        if b - a < s.min_rows or t[b - 1] - t[a] < s.min_duration_s:
            c["short_segments_dropped"] += 1
            continue
        seg = base.take(np.arange(a, b), name=seg_name, segment=i + 1 if gaps.size else None)
        # a segment must have measured outputs at its start for the initial state
        if not all(np.isfinite(getattr(seg, k)).any() for k in measured):
            c["short_segments_dropped"] += 1
            continue
        out.append(seg)
    if not out:
        return reject(f"no segment of at least {s.min_duration_s:.0f} s between gaps longer than {s.max_bridge_s:.0f} s")
    rep.rows_out = int(sum(len(f) for f in out))
    rep.segments = [f.name for f in out]
    for k, v in c.items():
        if v and k not in ("bridged_gaps",) and not k.startswith("missing_"):
            log.info("%s: %s = %d", flight.name, k, v)
    return CleanResult(out, rep)


def clean_flights(flights: list[Flight], settings: CleaningSettings = CleaningSettings(),
                  ) -> tuple[list[Flight], list[CleaningReport], list[RejectedFlight]]:
    """Clean many flights: (usable segments, one report per input flight, rejected flights)."""
    usable: list[Flight] = []
    reports: list[CleaningReport] = []
    rejected: list[RejectedFlight] = []
    for f in flights:
        r = clean_flight(f, settings)
        reports.append(r.report)
        usable.extend(r.flights)
        if r.rejected is not None:
            rejected.append(r.rejected)
    return usable, reports, rejected
