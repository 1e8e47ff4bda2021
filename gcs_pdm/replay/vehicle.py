"""The vehicle a replay diagnoses, and the estimate sampled through it.

``replay_vehicle`` picks the description: the one given (``--vehicle``), else the provisional one
derived from the whole log, a tlog or an autopilot's ``.bin``/``.ulg`` alike (what
``gcs-pdm vehicle init --from LOG`` would write). ``TracedPipeline``
is the replay's frame consumer: the diagnosis pipeline on that description plus, every
``period_s`` of message time, each pack's SoC, temperature, current and Monte Carlo time to
cut-off at the present draw, each motor's current and rpm, and what a prediction needs from the
flight (``estimation.flight_conditions``: phase, air density, load; the live service's own), so a
replay's summary shows the flight, not only its last second.
"""
from __future__ import annotations

import math
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from gcs_pdm.vehicle.description import VehicleDescription, VehicleError
from gcs_pdm.vehicle.presets import resolve

#: a pack is "drawing" (its time to cut-off is worth predicting) from this current, A
DRAWING_CURRENT_A = 1.0
#: Monte Carlo samples of each trace entry's time to cut-off
TRACE_SAMPLES = 64


def replay_vehicle(log: Path, spec: str | None) -> tuple[VehicleDescription | None, dict]:
    """(description or None, what to say about it). None: no description could be derived."""
    if spec:
        desc = resolve(spec)
        return desc, {"name": desc.name, "source": "given", "provisional": desc.provisional, "notes": []}
    from gcs_pdm.logs.provisional_vehicle import observe_file  # one derivation: tlog, DataFlash .bin, ULog .ulg

    try:
        desc, notes = observe_file(log)
    except VehicleError as exc:
        return None, {"source": "none", "why": f"no --vehicle, and none could be derived from the log: {exc}"}
    return desc, {"name": desc.name, "source": "provisional", "provisional": True, "notes": notes,
                  "save": f"gcs-pdm vehicle init --from {log} --out vehicle.toml"}


def pipeline_for(desc: VehicleDescription, params=None, **kwargs):
    """The diagnosis pipeline for a description, ``params`` (a parameter set) flown over its values."""
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline

    return DiagnosisPipeline(params, vehicle=desc, **kwargs)


class TracedPipeline:
    """A replay's frame consumer: the pipeline, with the estimate sampled every ``period_s``.

    A sample's Monte Carlo time to cut-off only fills the trace, so with ``background`` its flight
    runs on one worker thread while the frames go on: the sample copies what the prediction reads
    (``prediction.held_current_inputs``), draws the samples on this thread (the rng's order stays
    the frames' order) and submits their flight (``HeldCurrentSamples.fly``: one compiled call
    with the GIL released, so it overlaps the frames' Python on the second core and takes the GIL
    twice, not at every chunk); ``report`` reduces the flights to quantiles in order. The same
    numbers as ``background=False`` (all on the calling thread)."""

    def __init__(self, desc: VehicleDescription, about: dict, *, period_s: float = 30.0, seed: int = 0,
                 background: bool = True):
        from gcs_pdm.estimation.flight_conditions import FlightConditions
        from gcs_pdm.vehicle.model_inputs import model_inputs

        self.pipeline = pipeline_for(desc)
        self.about = about
        self.period_s = period_s
        #: the vehicle flown (``gcs-pdm replay`` resolves none given and none derived to ``edge540``)
        self.vehicle = desc
        self.cutoff_v = model_inputs(self.vehicle).pack_cutoff_v
        #: the prediction's inputs from the flight, worked out as the live service does
        self.conditions = FlightConditions()
        self._pipeline_types = self.pipeline.consumed_frame_types
        #: the samples; a drawing pack's ``time_to_cutoff_s`` is filled in by ``report()``
        self.trace: list[dict] = []
        #: message time of the next sample: taken after the first frame, of any type, reaching it
        #: (a replay that passes frames over hands such a frame over all the same)
        self.next_due_s = -math.inf
        self._rng = np.random.default_rng(seed)
        #: (trace entry, which packs draw, the Monte Carlo's draws, their flight or its future) of
        #: each sample that predicts
        self._pending: list[tuple] = []
        # its thread starts at the first submission; close() (or report()) ends it
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="replay-trace") if background else None

    def __call__(self, frame) -> None:
        self.conditions.consume(frame)
        due = frame.time_s >= self.next_due_s
        if due or type(frame) in self._pipeline_types:
            self.pipeline.consume(frame)
        else:  # handed over for the flight conditions only: the pipeline counts it as passed over
            self.pipeline.passed_over(1)
        if due:
            self.next_due_s = frame.time_s + self.period_s
            self._sample(frame.time_s)

    consume = __call__

    @property
    def consumed_frame_types(self) -> frozenset:
        """The pipeline's and the flight conditions': a frame of another type changes nothing a
        sample reads (the state after it is the state after the last consumed frame), so only due
        ones need handing over."""
        return self._pipeline_types | self.conditions.FRAME_TYPES

    def passed_over(self, count: int) -> None:
        self.pipeline.passed_over(count)

    def _sample(self, t: float) -> bool:
        """Sample the estimate at ``t``; False (nothing sampled) while the estimator is not ready."""
        from gcs_pdm.estimation import prediction

        est = self.pipeline.estimator
        if not est.ready():
            return False
        e = est.estimate()
        current = np.nan_to_num(np.asarray(est.pack_current, dtype=float))

        entry = {
            "time_s": round(t, 3),
            "packs": {n: {"soc": _num(e.soc[i]), "soc_sd": _num(e.soc_sd[i]), "temperature_c": _num(e.pack_temp_c[i]),
                          "temperature_sd": _num(e.pack_temp_sd[i]), "current_a": _num(current[i]),
                          "time_to_cutoff_s": None}  # filled by _fill_trace while the pack draws
                      for i, n in enumerate(est.pack_names)},
            "motors": {n: {"current_a": _num(est.motor_current[i]), "rpm": _num(est.motor_rpm[i])}
                       for i, n in enumerate(est.motor_names)},
            "flight": flight_entry(self.prediction_inputs(t)),
        }
        self.trace.append(entry)
        drawing = current >= DRAWING_CURRENT_A
        if np.any(drawing) and np.all(np.isfinite(e.soc)):
            samples = prediction.draw_held_current(prediction.held_current_inputs(est, self.cutoff_v), rng=self._rng,
                                                   n_samples=TRACE_SAMPLES)
            flown = samples.fly() if self._worker is None else self._worker.submit(samples.fly)
            self._pending.append((entry, drawing, samples, flown))
        return True

    def prediction_inputs(self, t: float):
        """What a prediction at ``t`` starts from (``FlightConditions.inputs``), as live."""
        return self.conditions.inputs(t, self.vehicle, self.pipeline.estimator)

    def _fill_trace(self) -> None:
        """Each predicting sample's time to cut-off into its entry, in order: waits for the
        worker; a prediction's exception is raised here, and the worker is stopped either way."""
        try:
            for entry, drawing, samples, flown in self._pending:
                ttc = samples.prediction(flown.result() if isinstance(flown, Future) else flown).time_to_cutoff_s
                for i, pack in enumerate(entry["packs"].values()):
                    if drawing[i]:
                        pack["time_to_cutoff_s"] = [_num(v) for v in ttc[i]]
            self._pending = []
        finally:
            self.close()

    def close(self) -> None:
        """Stop the worker (predictions not started are dropped, a running one is waited for);
        samples after this predict on the calling thread. The replay command calls it on its
        way out, whatever happened, so no worker outlives the replay."""
        if self._worker is not None:
            self._worker.shutdown(wait=True, cancel_futures=True)
            self._worker = None
        self._pending = [p for p in self._pending if not isinstance(p[3], Future)]

    def report(self) -> dict:
        est_time = getattr(self.pipeline.estimator, "time_s", None)
        if not self.trace and est_time is not None and math.isfinite(est_time):
            # a log shorter than its first due sample (the estimator not ready at the first frame,
            # the next due after the log's end): its last state, at the estimator's own time (the
            # same whether or not frames it ignores were handed over), so the trace is not empty
            self._sample(est_time)
        self._fill_trace()
        return {**self.pipeline.report(), "vehicle": self.about, "trace": self.trace}


def print_estimate(consumer_report: dict | None) -> None:
    """The replay's vehicle and a few of its trace samples, for the replay CLIs (tlog and autopilot log)."""
    about = (consumer_report or {}).get("vehicle")
    if about:
        if about["source"] == "none":
            print(f"  vehicle: none ({about['why']}); diagnosed as the paper's aircraft")
        else:
            print(f"  vehicle description: {about['name']} ({about['source']})")
            for note in about["notes"]:
                print(f"    provisional: {note}")
            if about.get("save"):
                print(f"    save and correct it: {about['save']}")
    trace = (consumer_report or {}).get("trace") or []
    for sample in trace[::max(1, len(trace) // 8)]:
        packs = "; ".join(f"{n} SoC {_f(p['soc'])}, {_f(p['temperature_c'])} °C, {_f(p['current_a'])} A"
                          + (f", cut-off in {_f(p['time_to_cutoff_s'][1])} s" if p["time_to_cutoff_s"] else "")
                          for n, p in sample["packs"].items())
        print(f"  t={sample['time_s']:.0f} s: {packs}")


def flight_entry(inputs) -> dict:
    """A trace's ``flight``: the prediction's inputs, numbers as every trace value (``_num``)."""
    return {k: _num(v) if isinstance(v, float) else v for k, v in inputs.to_dict().items()}


def _f(x) -> str:
    return "?" if x is None else f"{x:.3g}"


def _num(x) -> float | None:
    """A trace value: rounded to 4 decimals, None where not finite."""
    return round(float(x), 4) if math.isfinite(x) else None
