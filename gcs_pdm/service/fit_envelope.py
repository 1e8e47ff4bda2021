"""Is the vehicle inside the conditions its packs' models were fitted on? (docs/service.md, "Fit envelope")

A learned circuit interpolates its training flights. A fit says which of its validation and test
flights leave their pack and air temperatures or sustained current (``fitting.envelope``), and the
learned set carries that training envelope per pack (provenance ``packs.<name>.training_envelope``).
This watch applies the same rule to the vehicle in flight, once a second of message time: a pack
hotter or colder than any training flight, or drawing more current for a minute, is flown on an
extrapolated model (the fixtures' hot cut-off flight, 6.7 K past its training flights, is where fits
equally good on the training flights part by 50-260 mV: docs/fitting.md). It is said in ``/status``
(``fit_envelope``, and a warning banner), never acted on: the predictions are the same, the
operator knows what they rest on and that a refit with such flights would help.

No I/O: the telemetry intake feeds it the estimate and the active set's provenance.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Mapping, Sequence

from gcs_pdm.fitting.envelope import SUSTAINED_SAMPLES, outside_training

#: message seconds of a "sustained" current: the fit's SUSTAINED_SAMPLES at the logs' 1 Hz
SUSTAINED_S = float(SUSTAINED_SAMPLES)
#: a window this much shorter than SUSTAINED_S still counts (status ticks are not exactly 1 s apart)
WINDOW_SLACK = 0.9


def training_envelopes(provenance: Mapping[str, Any] | None) -> dict[str, dict]:
    """Each learned pack's training envelope from a parameter set's provenance ({} for a set no fit
    made: the paper's, an import without one)."""
    packs = (provenance or {}).get("packs") or {}
    return {name: dict(p["training_envelope"]) for name, p in packs.items()
            if isinstance(p, Mapping) and isinstance(p.get("training_envelope"), Mapping)}


class FitEnvelopeWatch:
    """Per pack: the charge drawn over the last minute (its sustained current) and whether it was
    outside at the last check (it is cleared only back inside the training span itself)."""

    def __init__(self, window_s: float = SUSTAINED_S) -> None:
        self.window_s = float(window_s)
        self._charge: dict[str, deque[tuple[float, float]]] = {}
        self._outside: dict[str, bool] = {}

    def sustained_current(self, pack: str, t: float, charge_c: float) -> float | None:
        """Mean current of ``pack`` over the last ``window_s`` of message time, A; None until that
        much has been seen (or after message time went backwards: its history is dropped)."""
        hist = self._charge.setdefault(pack, deque())
        if not math.isfinite(charge_c) or (hist and t < hist[-1][0]):
            hist.clear()
            return None
        hist.append((t, charge_c))
        # keep the newest sample at least window_s old, and everything after it
        while len(hist) >= 2 and t - hist[1][0] >= self.window_s * WINDOW_SLACK:
            hist.popleft()
        t0, q0 = hist[0]
        if t - t0 < self.window_s * WINDOW_SLACK:
            return None
        return (charge_c - q0) / (t - t0)

    def update(self, t: float, envelopes: Mapping[str, Mapping], pack_names: Sequence[str],
               pack_temperature_c: Sequence[float], ambient_c: float, charge_c: Sequence[float]) -> dict | None:
        """The ``/status`` ``fit_envelope`` record at message time ``t``; None when no pack of the
        active set has a training envelope (nothing to compare with)."""
        judged = {n: i for i, n in enumerate(pack_names) if n in envelopes}
        if not judged:
            return None
        air = float(ambient_c) if ambient_c is not None and math.isfinite(ambient_c) else None
        packs: dict[str, dict] = {}
        for name, i in judged.items():
            temp = float(pack_temperature_c[i])
            temp = temp if math.isfinite(temp) else None
            current = self.sustained_current(name, t, float(charge_c[i]))
            training = envelopes[name]
            was_outside = self._outside.get(name, False)
            reasons = outside_training(training, (temp, temp) if temp is not None else None,
                                       (air, air) if air is not None else None, current,
                                       margin_scale=0.0 if was_outside else 1.0)
            unknown = [what for what, v in (("pack temperature", temp), ("air temperature", air),
                                            (f"{self.window_s:.0f}-s current", current)) if v is None]
            self._outside[name] = bool(reasons)
            state = "outside" if reasons else ("unknown" if len(unknown) == 3 else "inside")
            packs[name] = {"state": state, "outside": reasons, "not_judged": unknown, "training": dict(training),
                           "now": {"pack_temperature_c": temp, "ambient_c": air, "sustained_current_a": current}}
        out = sorted(n for n, p in packs.items() if p["state"] == "outside")
        reason = ("; ".join(f"pack {n}: {', '.join(packs[n]['outside'])}" for n in out)
                  + ". Its model was learned on flights that did not go there: predictions extrapolate the "
                  "learned circuit (refit with flights that do)") if out else None
        return {"packs": packs, "outside": out, "reason": reason}


def fit_envelope_warnings(record: Mapping | None) -> list[dict]:
    """The operator's banner for ``/status`` ``warnings`` from the ``fit_envelope`` record."""
    if not record or not record.get("outside"):
        return []
    packs = ", ".join(record["outside"])
    return [{"kind": "outside_fit_envelope", "level": "warning",
             "title": f"Outside the conditions the model was fitted on: {packs}", "text": record["reason"]}]
