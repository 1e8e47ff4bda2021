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
from typing import Mapping, Sequence

import numpy as np

#: a flight is outside when it goes this far past the training flights' extremes (sensor noise and a
#: pack's few kelvin of spread are not extrapolation)
TEMPERATURE_MARGIN_K = 2.0
#: ... or sustains this much more current than any training flight did
CURRENT_MARGIN_REL = 0.10
#: "sustained": the highest mean over this many samples (a climb burst, not a single spike)
SUSTAINED_SAMPLES = 60


@dataclass(frozen=True)
class FlightConditions:
    """What one flight (segment) put its pack through; None where the log has no such samples."""

    flight: str
    split: str
    pack_temperature_c: tuple[float, float] | None   # (lowest, highest) measured
    ambient_c: tuple[float, float] | None
    sustained_current_a: float | None                # highest mean over SUSTAINED_SAMPLES samples

    @classmethod
    def of(cls, flight: str, split: str, temperature_c: np.ndarray, ambient_c: np.ndarray,
           current_a: np.ndarray) -> "FlightConditions":
        def span(x: np.ndarray) -> tuple[float, float] | None:
            x = np.asarray(x, dtype=np.float64)
            x = x[np.isfinite(x)]
            return (float(x.min()), float(x.max())) if x.size else None

        cur = np.asarray(current_a, dtype=np.float64)
        cur = cur[np.isfinite(cur)]
        sustained = None
        if cur.size:
            w = min(SUSTAINED_SAMPLES, cur.size)
            sustained = float(np.max(np.convolve(cur, np.full(w, 1.0 / w), mode="valid")))
        return cls(flight, split, span(temperature_c), span(ambient_c), sustained)

    def to_dict(self) -> dict:
        return {"flight": self.flight, "split": self.split,
                "pack_temperature_c": list(self.pack_temperature_c) if self.pack_temperature_c else None,
                "ambient_c": list(self.ambient_c) if self.ambient_c else None,
                "sustained_current_a": self.sustained_current_a}


def _union(spans: Sequence[tuple[float, float] | None]) -> tuple[float, float] | None:
    known = [s for s in spans if s is not None]
    return (min(s[0] for s in known), max(s[1] for s in known)) if known else None


def _beyond(what: str, unit: str, span: tuple[float, float] | None, train: Sequence[float] | None,
            margin: float) -> list[str]:
    if span is None or train is None:
        return []
    out = []
    if span[1] > train[1] + margin:
        out.append(f"{what} reaches {span[1]:.1f} {unit}, above the training flights' {train[1]:.1f} {unit}")
    if span[0] < train[0] - margin:
        out.append(f"{what} goes down to {span[0]:.1f} {unit}, below the training flights' {train[0]:.1f} {unit}")
    return out


def outside_training(training: Mapping, pack_temperature_c: tuple[float, float] | None,
                     ambient_c: tuple[float, float] | None, sustained_current_a: float | None,
                     margin_scale: float = 1.0) -> list[str]:
    """Why conditions leave a fit's training envelope (``training``: the ``operating_envelope``
    record's "training", as a learned set's provenance carries it); [] when inside or unknown.

    The one rule for a validation or test flight (:func:`envelope_report`) and for the vehicle in
    flight (``service.fit_envelope``). ``margin_scale`` scales the margins: the live check clears
    a warning only once the pack is back inside the training span itself (0), so a temperature
    that hovers at the margin does not make the warning flicker."""
    out = (_beyond("pack temperature", "°C", pack_temperature_c, training.get("pack_temperature_c"),
                   TEMPERATURE_MARGIN_K * margin_scale)
           + _beyond("air temperature", "°C", ambient_c, training.get("ambient_c"), TEMPERATURE_MARGIN_K * margin_scale))
    i_max = training.get("sustained_current_a")
    if sustained_current_a is not None and i_max is not None \
            and sustained_current_a > i_max * (1 + CURRENT_MARGIN_REL * margin_scale):
        out.append(f"sustained current reaches {sustained_current_a:.1f} A, above the training flights' {i_max:.1f} A")
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
        outside = outside_training(training_record, c.pack_temperature_c, c.ambient_c, c.sustained_current_a)
        flights.append({**c.to_dict(), "inside": not outside, "outside": outside})
        if outside:
            warnings.append(f"{c.split} flight {c.flight}: outside the training conditions: {'; '.join(outside)}; "
                            f"its prediction extrapolates the learned circuit")
    record = {"rule": f"outside: more than {TEMPERATURE_MARGIN_K:g} K beyond the training flights' pack or air "
                      f"temperatures, or a {SUSTAINED_SAMPLES}-sample mean current more than "
                      f"{CURRENT_MARGIN_REL:.0%} above theirs",
              "training": training_record,
              "flights": flights}
    return record, warnings
