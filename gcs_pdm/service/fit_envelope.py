"""Is the vehicle inside the conditions its packs' models were fitted on? (docs/service.md, "Fit envelope")

A learned circuit interpolates its training flights. A fit says which of its validation and test
flights leave their pack and air temperatures or sustained current (``models.training_envelope``), and the
learned set carries that training envelope per pack (provenance ``packs.<name>.training_envelope``).
This watch applies the same rule to the vehicle in flight, once a second of message time: a pack
hotter or colder than any training flight, or drawing more current for a minute, is flown on an
extrapolated model (the fixtures' hot cut-off flight, 6.7 K past its training flights, is where fits
equally good on the training flights part by 50-260 mV: docs/fitting.md). It is said in ``/status``
(``fit_envelope``, and a warning banner), never acted on: the predictions are the same, the
operator knows what they rest on and that a refit with such flights would help.

The envelopes are those of the values the estimator flies (:func:`flown_envelopes`), not of the
set activated since: activation applies to planning at once, to the filters at the next start.
No I/O: the telemetry intake feeds it the estimator.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Mapping

import numpy as np

from gcs_pdm.models.training_envelope import SUSTAINED_S, outside_training, training_envelopes

#: a window this much shorter than SUSTAINED_S is accepted (status ticks are not exactly 1 s apart)
WINDOW_ACCEPT = 0.95
#: message seconds without a sample of a pack's charge, or without its current being read, after
#: which its history starts again (a link silence, a current gone): a mean across that is not a
#: sustained current. Shorter drop-outs (telemetry loses seconds of BATTERY_STATUS) are counted with
#: the estimator's held current
MAX_GAP_S = 15.0
#: an air temperature this old still stands for the air (it changes slowly; some links send it every
#: 10 s); older, or never heard, it is not judged (the estimator's default is not a reading)
AMBIENT_STALE_S = 30.0

#: each criterion of models.training_envelope.CRITERIA and the reading it judges
_READING = {"pack_temperature_high": "pack temperature", "pack_temperature_low": "pack temperature",
            "ambient_high": "air temperature", "ambient_low": "air temperature", "current": "current"}


def flown_envelopes(estimator) -> dict[str, dict]:
    """Per pack of ``estimator``: the training envelope of the fit that made the values it flies; {}
    when none did. A parameter set the estimator flies (``params``: the active set, for the paper's
    aircraft) gives the values of its packs by name; any other pack flies its description's
    ``parameters`` reference (its current scaled with the values: vehicle.model_inputs)."""
    from gcs_pdm.vehicle.model_inputs import pack_training_envelope

    params = getattr(estimator, "params", None)
    set_packs = params.packs if params is not None else {}
    from_set = training_envelopes(getattr(params, "provenance", None))
    found = {name: from_set.get(name) if name in set_packs
             else pack_training_envelope(estimator.vehicle.packs[i], f"packs[{i}]")
             for i, name in enumerate(estimator.pack_names)}
    return {name: env for name, env in found.items() if env is not None}


class FitEnvelopeWatch:
    """Per pack: the charge drawn over the last minute (its sustained current) and the criteria it
    was outside at the last look (each cleared only back inside the training span itself, and held
    while its reading is missing)."""

    def __init__(self, envelopes: Mapping[str, Mapping], window_s: float = SUSTAINED_S) -> None:
        self.envelopes = {name: dict(env) for name, env in envelopes.items()}
        self.window_s = float(window_s)
        self._charge: dict[str, deque[tuple[float, float]]] = {}
        self._outside: dict[str, dict[str, str]] = {}

    def sustained_current(self, pack: str, t: float, charge_c: float | None) -> float | None:
        """Mean current of ``pack`` over the last ``window_s`` of message time, A; None until that
        much has been seen since the history last started (a gap, message time going backwards, a
        current not being read: ``charge_c`` None)."""
        hist = self._charge.setdefault(pack, deque())
        if charge_c is None or not math.isfinite(charge_c) or (hist and not 0.0 <= t - hist[-1][0] <= MAX_GAP_S):
            hist.clear()
            if charge_c is None or not math.isfinite(charge_c):
                return None
        hist.append((t, charge_c))
        # the oldest sample kept is the newest one at least window_s old
        while len(hist) >= 2 and t - hist[1][0] >= self.window_s:
            hist.popleft()
        t0, q0 = hist[0]
        if t - t0 < self.window_s * WINDOW_ACCEPT:
            return None
        return (charge_c - q0) / (t - t0)

    def update(self, t: float, pack_names, pack_temperature_c, ambient_c: float | None,
               charge_c, temperature_modelled=()) -> dict | None:
        """The ``/status`` ``fit_envelope`` record at message time ``t``; None when no pack has a
        training envelope (nothing to compare with). ``ambient_c`` None: no air temperature is being
        read; ``charge_c[i]`` None: pack i's current is not being read."""
        if not self.envelopes:
            return None
        air = float(ambient_c) if ambient_c is not None and math.isfinite(ambient_c) else None
        packs: dict[str, dict] = {}
        for i, name in enumerate(pack_names):
            if name not in self.envelopes:
                continue
            temp = float(pack_temperature_c[i])
            temp = temp if math.isfinite(temp) else None
            current = self.sustained_current(name, t, charge_c[i])
            now = {"pack temperature": temp, "air temperature": air, "current": current}
            before = self._outside.get(name, {})
            reasons = outside_training(self.envelopes[name], None if temp is None else (temp, temp),
                                       None if air is None else (air, air), current, held=before)
            # a criterion whose reading is missing now keeps its last verdict
            reasons |= {c: why for c, why in before.items() if now[_READING[c]] is None}
            self._outside[name] = reasons
            not_judged = [what if what != "current" else f"{self.window_s:.0f}-s current"
                          for what, v in now.items() if v is None]
            state = "outside" if reasons else ("unknown" if len(not_judged) == len(now) else "inside")
            packs[name] = {"state": state, "outside": list(reasons.values()), "not_judged": not_judged,
                           "training": dict(self.envelopes[name]),
                           "now": {"pack_temperature_c": temp, "ambient_c": air, "sustained_current_a": current,
                                   **({"pack_temperature_source": "model"} if name in temperature_modelled else {})}}
        if not packs:
            return None
        out = sorted(n for n, p in packs.items() if p["state"] == "outside")
        reason = ("; ".join(f"pack {n}: {', '.join(packs[n]['outside'])}" for n in out)
                  + ". Its model was learned on flights that did not go there: predictions extrapolate the "
                  "learned circuit (refit with flights that do)") if out else None
        return {"packs": packs, "outside": out, "reason": reason}


def estimator_readings(estimator, estimate) -> dict[str, Any]:
    """What :meth:`FitEnvelopeWatch.update` judges, from the estimator and its estimate: the air
    temperature only while an ambient sensor is heard (the estimator's default stands in for it
    otherwise), each pack's charge only while its current is read (``AMBIENT_STALE_S``, ``MAX_GAP_S``)."""
    t = estimate.time_s
    heard = t - estimator.seen.get("ambient", -math.inf) <= AMBIENT_STALE_S
    read = t - estimator.current_read_time <= MAX_GAP_S
    charge = estimator.charge_c
    return {"t": t, "pack_names": estimator.pack_names, "pack_temperature_c": np.asarray(estimate.pack_temp_c),
            "ambient_c": estimate.ambient_c if heard else None,
            "charge_c": [float(q) if ok else None for q, ok in zip(charge, read)],
            "temperature_modelled": estimate.modelled_temperature}


def fit_envelope_warnings(record: Mapping | None) -> list[dict]:
    """The operator's banner for ``/status`` ``warnings`` from the ``fit_envelope`` record."""
    if not record or not record.get("outside"):
        return []
    packs = ", ".join(record["outside"])
    return [{"kind": "outside_fit_envelope", "level": "warning",
             "title": f"Outside the conditions the model was fitted on: {packs}", "text": record["reason"]}]
