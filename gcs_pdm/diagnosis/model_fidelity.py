"""The model-mismatch advisory: a pack that no longer behaves like its model, debounced.

The estimator's per-pack model-consistency test (``estimation.pack_filter.ConsistencyWindow``:
mean squared normalised innovation over a window against a χ² bound, with hysteresis) says whether
a pack matches its model now. This monitor turns it into a ``Fault`` of type ``model_mismatch``
(an advisory: no reason to re-plan, ``faults.ADVISORY_TYPES``) once the test has held for
``raise_after_s`` of message time, and clears it once the test has been clear for
``clear_after_s``. The evidence is the estimator's (``StateEstimator.model_check``), refreshed while
the advisory is active, with the suggestion to refit the pack.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from gcs_pdm.diagnosis.debounce import DebounceConfig, Debouncer
from gcs_pdm.diagnosis.faults import MODEL_MISMATCH, Fault


@dataclass(frozen=True)
class ModelFidelityConfig:
    #: the window already spans minutes; the debounce only stops a statistic that grazes its
    #: bound from raising and clearing the advisory on every other frame
    raise_after_s: float = 10.0
    clear_after_s: float = 60.0


class ModelMismatchMonitor:
    def __init__(self, pack_names, config: ModelFidelityConfig = ModelFidelityConfig()):
        self.pack_names = tuple(pack_names)
        self.config = config
        debounce = DebounceConfig(config.raise_after_s, config.clear_after_s)
        self._debounce = {n: Debouncer(debounce) for n in self.pack_names}
        self._index = {n: b for b, n in enumerate(self.pack_names)}
        self.faults: dict[tuple[str, str], Fault] = {}
        #: per pack: nothing raised or pending, so ``update`` of a pack whose test is clear changes
        #: nothing and returns nothing (the caller may skip it: nearly every frame)
        self.idle = [True] * len(self.pack_names)

    def update(self, time_s: float, estimator, pack: str) -> list[tuple[str, Fault]]:
        """After a frame of ``pack``: the raise/clear events of its advisory."""
        b = self._index.get(pack)
        if b is None:
            return []
        deb = self._debounce[pack]
        active = estimator.mismatch_active(b)
        if not active and not deb.active and math.isnan(deb.pending_since):
            return []  # the pack matches its model and nothing is pending (nearly every frame): no change
        key = (MODEL_MISMATCH, pack)
        kind = deb.update(time_s, active, not active)
        self.idle[b] = not deb.active and math.isnan(deb.pending_since)
        if kind == "raise":
            ev = estimator.model_check(b)
            f = Fault(MODEL_MISMATCH, pack, float(ev["statistic"] or 0.0), time_s, _confidence(ev), ev,
                      updated_s=time_s)
            self.faults[key] = f
            return [("raise", f)]
        f = self.faults.get(key)
        if f is None or not f.active:
            return []
        if kind == "clear":
            f = f.with_(active=False, cleared_s=time_s, updated_s=time_s, evidence=estimator.model_check(b))
            self.faults[key] = f
            return [("clear", f)]
        if active and time_s - (f.updated_s or f.time_s) >= 1.0:
            # the magnitude stays the raise's (a stored fault is re-stored when it moves); the
            # evidence follows the window, once a second of message time
            self.faults[key] = f.with_(evidence=estimator.model_check(b), updated_s=time_s)
        return []


def _confidence(evidence: dict) -> float:
    """0.5 at the bound, 1 at twice the bound (the window's own false-alarm rate is in the evidence)."""
    stat, bound = evidence.get("statistic"), evidence.get("bound")
    if not stat or not bound:
        return 0.5
    return float(min(1.0, max(0.5, stat / (2.0 * bound))))
