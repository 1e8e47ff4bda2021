"""Whether each validation and test flight stays inside the conditions the fit was trained on.

A learned circuit is an interpolation of its training flights. Outside their pack temperatures,
air temperatures or sustained currents its Arrhenius and kinetic terms extrapolate, and equally good
fits of the training flights part ways there (docs/fitting.md: chen2020_03 heats to 69.5 °C, 6.7 K above
any training flight, and fits that agree within a few mV on the training flights miss it by 50-260 mV).
So a battery fit says, per validation and test flight, where it leaves the training envelope, and a
learned set carries that envelope so the service says the same of the vehicle in flight
(``service.fit_envelope``).

Pure: arrays in, a JSON-ready record out. ``procedure.fit_battery`` feeds it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Collection, Mapping, Sequence

import numpy as np

#: a flight is outside when it goes this far past the training flights' extremes (sensor noise and a
#: pack's few kelvin of spread are not extrapolation)
TEMPERATURE_MARGIN_K = 2.0
#: ... or sustains this much more current than any training flight did
CURRENT_MARGIN_REL = 0.10
#: "sustained": the highest mean over this many seconds (a climb, not a single spike); seconds, not
#: samples, so a 10 Hz log and the service's 1 Hz status ticks mean the same thing
SUSTAINED_S = 60.0


@dataclass(frozen=True)
class FlightConditions:
    """What one flight (segment) put its pack through; None where the log has no such samples."""

    flight: str
    split: str
    pack_temperature_c: tuple[float, float] | None   # (lowest, highest) measured
    ambient_c: tuple[float, float] | None
    sustained_current_a: float | None                # highest mean over SUSTAINED_S seconds

    @classmethod
    def of(cls, flight: str, split: str, temperature_c: np.ndarray, ambient_c: np.ndarray,
           current_a: np.ndarray, time_s: np.ndarray) -> "FlightConditions":
        def span(x: np.ndarray) -> tuple[float, float] | None:
            x = np.asarray(x, dtype=np.float64)
            x = x[np.isfinite(x)]
            return (float(x.min()), float(x.max())) if x.size else None

        return cls(flight, split, span(temperature_c), span(ambient_c), sustained_current(time_s, current_a))

    def to_dict(self) -> dict:
        return {"flight": self.flight, "split": self.split,
                "pack_temperature_c": list(self.pack_temperature_c) if self.pack_temperature_c else None,
                "ambient_c": list(self.ambient_c) if self.ambient_c else None,
                "sustained_current_a": self.sustained_current_a}


def sustained_current(time_s: np.ndarray, current_a: np.ndarray, window_s: float = SUSTAINED_S) -> float | None:
    """The highest mean current over any ``window_s`` of the log (the whole log's mean if it is
    shorter), A; None without two finite samples. The charge is integrated by the trapezoid rule, so
    the sampling rate and gaps in it do not change what "sustained" means."""
    t = np.asarray(time_s, dtype=np.float64)
    i = np.asarray(current_a, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(i)
    t, i = t[ok], i[ok]
    if t.size < 2 or t[-1] <= t[0]:
        return None
    charge = np.concatenate(([0.0], np.cumsum(0.5 * (i[1:] + i[:-1]) * np.diff(t))))
    if t[-1] - t[0] <= window_s:
        return float(charge[-1] / (t[-1] - t[0]))
    ends = t[t >= t[0] + window_s]
    return float(np.max((np.interp(ends, t, charge) - np.interp(ends - window_s, t, charge)) / window_s))


def training_envelopes(provenance: Mapping | None) -> dict[str, dict]:
    """Each fitted pack's training envelope from a parameter set's provenance (``merge_results``
    stores it as ``packs.<name>.training_envelope``); {} for a set no fit made."""
    packs = (provenance or {}).get("packs") or {}
    return {name: dict(p["training_envelope"]) for name, p in packs.items()
            if isinstance(p, Mapping) and isinstance(p.get("training_envelope"), Mapping)}


def _union(spans: Sequence[tuple[float, float] | None]) -> tuple[float, float] | None:
    known = [s for s in spans if s is not None]
    return (min(s[0] for s in known), max(s[1] for s in known)) if known else None


#: the envelope's criteria, in the order their reasons are given
CRITERIA = ("pack_temperature_high", "pack_temperature_low", "ambient_high", "ambient_low", "current")


def _beyond(what: str, unit: str, value: tuple[float, float] | None, train: Sequence[float] | None,
            margins: Mapping[str, float], key: str) -> dict[str, str]:
    if value is None or train is None:
        return {}
    out = {}
    if value[1] > train[1] + margins[f"{key}_high"]:
        out[f"{key}_high"] = f"{what} reaches {value[1]:.1f} {unit}, above the training flights' {train[1]:.1f} {unit}"
    if value[0] < train[0] - margins[f"{key}_low"]:
        out[f"{key}_low"] = f"{what} goes down to {value[0]:.1f} {unit}, below the training flights' {train[0]:.1f} {unit}"
    return out


def outside_training(training: Mapping, pack_temperature_c: tuple[float, float] | None,
                     ambient_c: tuple[float, float] | None, sustained_current_a: float | None,
                     held: Collection[str] = ()) -> dict[str, str]:
    """Why conditions leave a fit's training envelope (``training``: the ``operating_envelope``
    record's "training", as a learned set's provenance carries it), by criterion (``CRITERIA``);
    {} when inside or not measured.

    The one rule for a validation or test flight (:func:`envelope_report`) and for the vehicle in
    flight (``service.fit_envelope``). The criteria in ``held`` (the live check's, outside at its
    last look) have no margin: a warning clears only back inside the training span itself, so a
    temperature that hovers at the margin does not make it flicker."""
    margins = {c: 0.0 if c in held else TEMPERATURE_MARGIN_K for c in CRITERIA if c != "current"}
    out = (_beyond("pack temperature", "°C", pack_temperature_c, training.get("pack_temperature_c"), margins,
                   "pack_temperature")
           | _beyond("air temperature", "°C", ambient_c, training.get("ambient_c"), margins, "ambient"))
    i_max = training.get("sustained_current_a")
    rel = 0.0 if "current" in held else CURRENT_MARGIN_REL
    if sustained_current_a is not None and i_max is not None and sustained_current_a > i_max * (1 + rel):
        out["current"] = (f"sustained current reaches {sustained_current_a:.1f} A, above the training flights' "
                          f"{i_max:.1f} A")
    return out


def envelope_report(conditions: Sequence[FlightConditions]) -> tuple[dict, list[str]]:
    """(``operating_envelope`` record of result.json, warnings) for one fit's flights: each validation
    and test flight's conditions against the union of the training flights', and a warning for each
    flight that leaves it."""
    training = [c for c in conditions if c.split == "train"]
    t_pack = _union([c.pack_temperature_c for c in training])
    t_air = _union([c.ambient_c for c in training])
    currents = [c.sustained_current_a for c in training if c.sustained_current_a is not None]
    i_max = max(currents) if currents else None
    training_record = {"pack_temperature_c": list(t_pack) if t_pack else None,
                       "ambient_c": list(t_air) if t_air else None, "sustained_current_a": i_max}
    flights, warnings = [], []
    for c in conditions:
        if c.split not in ("validation", "test"):
            continue
        outside = list(outside_training(training_record, c.pack_temperature_c, c.ambient_c, c.sustained_current_a).values())
        flights.append({**c.to_dict(), "inside": not outside, "outside": outside})
        if outside:
            warnings.append(f"{c.split} flight {c.flight}: outside the training conditions: {'; '.join(outside)}; "
                            f"its prediction extrapolates the learned circuit")
    record = {"rule": f"outside: more than {TEMPERATURE_MARGIN_K:g} K beyond the training flights' pack or air "
                      f"temperatures, or a {SUSTAINED_S:g}-s mean current more than "
                      f"{CURRENT_MARGIN_REL:.0%} above theirs",
              "training": training_record,
              "flights": flights}
    return record, warnings
