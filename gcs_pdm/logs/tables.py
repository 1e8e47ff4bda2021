"""Flight-log tables: what a log is read into and the fitter reads, as plain arrays with their units.

A battery flight has ``time_s, current_a, voltage_v, temperature_c, ambient_c`` (pack current,
discharge positive; pack terminal voltage; pack temperature; ambient air temperature). A motor
flight has ``time_s, current_a`` (mean of the two motors), ``temperature_c`` (the bracket sensor)
and ``ambient_c``. Extra columns are ignored; a missing required column is a :class:`FlightDataError`
naming it. Reading files lives in :mod:`gcs_pdm.logs` (autopilot logs) and :mod:`gcs_pdm.fitting.logs`
(CSV, Parquet, tlog); this module is pure, below both.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

BATTERY = "battery"
MOTOR = "motor"
KINDS = (BATTERY, MOTOR)

REQUIRED_COLUMNS: dict[str, tuple[str, ...]] = {
    BATTERY: ("time_s", "current_a", "voltage_v", "ambient_c"),
    MOTOR: ("time_s", "current_a", "temperature_c", "ambient_c"),
}
#: columns a flight may lack: read as all missing (many real logs have no pack temperature; the fit
#: then learns the electrical part and reports the thermal part as not fitted)
OPTIONAL_COLUMNS: dict[str, tuple[str, ...]] = {BATTERY: ("temperature_c",), MOTOR: ()}


class FlightDataError(ValueError):
    """A flight log that cannot be used; the message names the flight and what is wrong."""


@dataclass(frozen=True)
class Flight:
    """One flight of one component (a pack, or the motor pair), as arrays of equal length.

    ``voltage_v`` is None for motor flights. Arrays may hold NaN (drop-outs) until cleaned.
    """

    name: str
    kind: str
    time_s: np.ndarray
    current_a: np.ndarray
    temperature_c: np.ndarray
    ambient_c: np.ndarray
    voltage_v: np.ndarray | None = None
    #: where it came from (file, pack, segment) — carried into the result's provenance
    source: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise FlightDataError(f"{self.name}: kind must be one of {KINDS}, got {self.kind!r}")
        if self.kind == BATTERY and self.voltage_v is None:
            raise FlightDataError(f"{self.name}: a battery flight needs voltage_v")
        n = len(self.time_s)
        for col in self.columns():
            if len(getattr(self, col)) != n:
                raise FlightDataError(f"{self.name}: column {col} has {len(getattr(self, col))} rows, time_s has {n}")

    def columns(self) -> tuple[str, ...]:
        return ("time_s", "current_a", "temperature_c", "ambient_c") + (("voltage_v",) if self.kind == BATTERY else ())

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def duration_s(self) -> float:
        t = self.time_s[np.isfinite(self.time_s)]
        return float(t.max() - t.min()) if t.size else 0.0

    def take(self, index: np.ndarray, name: str | None = None, **source: object) -> "Flight":
        """Rows ``index`` (a mask or integer index) as a new flight."""
        cols = {c: np.asarray(getattr(self, c))[index] for c in self.columns()}
        return Flight(name=name or self.name, kind=self.kind, source={**self.source, **source}, **cols)

    def with_columns(self, **cols: np.ndarray) -> "Flight":
        current = {c: getattr(self, c) for c in self.columns()}
        current.update(cols)
        return Flight(name=self.name, kind=self.kind, source=self.source, **current)

    @property
    def dt(self) -> np.ndarray:
        """Kernel time steps: dt[0] = 0, dt[k] = t_k - t_{k-1}."""
        return np.diff(self.time_s, prepend=self.time_s[0])


def flight_from_columns(name: str, kind: str, columns: Mapping[str, object], source: Mapping[str, object] | None = None,
                        ) -> Flight:
    """Build a flight from a column mapping (a DataFrame works); missing columns are named in the error."""
    if kind not in KINDS:
        raise FlightDataError(f"{name}: kind must be one of {KINDS}, got {kind!r}")
    have = set(columns.keys()) if hasattr(columns, "keys") else set(columns)
    missing = [c for c in REQUIRED_COLUMNS[kind] if c not in have]
    if missing:
        raise FlightDataError(f"{name}: missing required column(s) {', '.join(missing)} for a {kind} flight "
                              f"(need {', '.join(REQUIRED_COLUMNS[kind])}; have {', '.join(sorted(map(str, have))) or 'none'})")
    arrays = {}
    for c in OPTIONAL_COLUMNS[kind]:
        if c not in have:
            arrays[c] = np.full(len(np.asarray(columns["time_s"])), np.nan)
    for c in REQUIRED_COLUMNS[kind] + tuple(c for c in OPTIONAL_COLUMNS[kind] if c in have):
        try:
            arrays[c] = np.asarray(columns[c], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise FlightDataError(f"{name}: column {c} is not numeric ({exc})") from None
        if arrays[c].ndim != 1:
            raise FlightDataError(f"{name}: column {c} must be one-dimensional")
    if len(arrays["time_s"]) == 0:
        raise FlightDataError(f"{name}: no rows")
    return Flight(name=name, kind=kind, source=dict(source or {}),
                  time_s=arrays["time_s"], current_a=arrays["current_a"], temperature_c=arrays["temperature_c"],
                  ambient_c=arrays["ambient_c"], voltage_v=arrays.get("voltage_v"))
