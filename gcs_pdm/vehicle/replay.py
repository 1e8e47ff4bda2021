"""The vehicle a replay diagnoses, and the estimate sampled through it.

``replay_vehicle`` picks the description: the one given (``--vehicle``), else the provisional one
derived from the whole log (what ``gcs-pdm vehicle init --from LOG`` would write). ``TracedPipeline``
is the replay's frame consumer: the diagnosis pipeline on that description plus, every
``period_s`` of message time, each pack's SoC, temperature, current and Monte Carlo time to
cut-off at the present draw, and each motor's current and rpm, so a replay's summary shows the
flight, not only its last second.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gcs_pdm.vehicle.description import VehicleDescription, VehicleError
from gcs_pdm.vehicle.presets import PRESETS, is_paper_aircraft, resolve

#: a pack is "drawing" (its time to cut-off is worth predicting) from this current, A
DRAWING_CURRENT_A = 1.0


def replay_vehicle(log: Path, spec: str | None) -> tuple[VehicleDescription | None, dict]:
    """(description or None, what to say about it). None: no description could be derived."""
    if spec:
        desc = resolve(spec)
        return desc, {"name": desc.name, "source": "given", "provisional": desc.provisional, "notes": []}
    if log.suffix.lower() != ".tlog":
        return None, {"source": "none", "why": f"no --vehicle, and a provisional description is derived from "
                                               f"tlogs only ({log.suffix} given)"}
    from gcs_pdm.vehicle.provisional import observe_tlog

    try:
        desc, notes = observe_tlog(log)
    except VehicleError as exc:
        return None, {"source": "none", "why": f"no --vehicle, and none could be derived from the log: {exc}"}
    return desc, {"name": desc.name, "source": "provisional", "provisional": True, "notes": notes,
                  "save": f"gcs-pdm vehicle init --from {log} --out vehicle.toml"}


def pipeline_for(desc: VehicleDescription | None, params=None, **kwargs):
    """The diagnosis pipeline for a description (the paper's own for ``edge540`` or None)."""
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline

    if desc is None or is_paper_aircraft(desc):
        return DiagnosisPipeline(params, **kwargs)
    return DiagnosisPipeline(vehicle=desc, **kwargs)


class TracedPipeline:
    """A replay's frame consumer: the pipeline, with the estimate sampled every ``period_s``."""

    def __init__(self, desc: VehicleDescription | None, about: dict, *, period_s: float = 30.0, seed: int = 0):
        from gcs_pdm.vehicle.model_inputs import model_inputs

        self.pipeline = pipeline_for(desc)
        self.about = about
        self.period_s = period_s
        self.cutoff_v = model_inputs(desc if desc is not None else PRESETS["edge540"]).pack_cutoff_v
        self.trace: list[dict] = []
        self._next_s = -math.inf
        self._rng = np.random.default_rng(seed)

    def __call__(self, frame) -> None:
        self.pipeline.consume(frame)
        if frame.time_s >= self._next_s:
            self._next_s = frame.time_s + self.period_s
            self._sample(frame.time_s)

    consume = __call__

    def _sample(self, t: float) -> None:
        from gcs_pdm.estimation.prediction import predict_packs_at_current

        est = self.pipeline.estimator
        if not est.ready():
            return
        e = est.estimate()
        current = np.nan_to_num(np.asarray(est.pack_current, dtype=float))
        ttc = None
        if np.any(current >= DRAWING_CURRENT_A) and np.all(np.isfinite(e.soc)):
            ttc = predict_packs_at_current(est, self.cutoff_v, rng=self._rng, n_samples=64).time_to_cutoff_s

        def num(x):
            return round(float(x), 4) if math.isfinite(x) else None

        self.trace.append({
            "time_s": round(t, 3),
            "packs": {n: {"soc": num(e.soc[i]), "soc_sd": num(e.soc_sd[i]), "temperature_c": num(e.pack_temp_c[i]),
                          "temperature_sd": num(e.pack_temp_sd[i]), "current_a": num(current[i]),
                          "time_to_cutoff_s": None if ttc is None or current[i] < DRAWING_CURRENT_A
                          else [num(v) for v in ttc[i]]}
                      for i, n in enumerate(est.pack_names)},
            "motors": {n: {"current_a": num(est.motor_current[i]), "rpm": num(est.motor_rpm[i])}
                       for i, n in enumerate(est.motor_names)},
        })

    def report(self) -> dict:
        return {**self.pipeline.report(), "vehicle": self.about, "trace": self.trace}
