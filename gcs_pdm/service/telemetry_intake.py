"""Telemetry intake: the link's frames into the estimator and the diagnoser, on one thread, in
message time.

* the link's reader thread hands every frame to :meth:`TelemetryIntake.on_frame`, which only
  enqueues it (the reader must never wait for us);
* the telemetry thread (:meth:`TelemetryIntake._run`) feeds the estimator and the diagnoser and
  updates the live state. It never plans, uploads or fits, so telemetry is never held up. The
  filters are not thread-safe: other threads hand work over with :meth:`call_soon`;
* once a second of message time it publishes the estimate and calls ``on_tick`` (the live loop's
  fault and deviation checks); every ``PREDICT_PERIOD_S`` it starts a time-to-cut-off prediction
  on its own worker (a long plan must not freeze the status page's numbers).
"""
from __future__ import annotations

import logging
import math
import queue
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

from gcs_pdm.frames import AirdataFrame, MissionProgressFrame, PositionFrame, StatusTextFrame
from gcs_pdm.models.powertrain import MotorFault, air_density, shaft_power
from gcs_pdm.service import adapters

log = logging.getLogger(__name__)

STATUS_PERIOD_S = 1.0
PREDICT_PERIOD_S = 10.0
#: below this airspeed the vehicle is on the ground: no flight load to extrapolate
FLYING_AIRSPEED_MPS = 5.0


class TelemetryIntake:
    def __init__(self, service, link, estimator, diagnoser, *, feed_estimator: bool):
        self.service = service
        self.link = link
        self.estimator = estimator
        self.diagnoser = diagnoser
        # The pipeline feeds its own estimator; feeding it twice would double-count every frame.
        self._feed_estimator = feed_estimator
        self._frames: queue.Queue = queue.Queue(maxsize=50_000)
        self.frames_dropped = 0
        self.frames_seen = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._predictor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="predict")
        self._predicting = False
        self._last_predict_s = -math.inf
        self._last_status_s = -math.inf
        #: latest message time seen (None before the first frame)
        self.time_s: float | None = None
        self.position = (math.nan, math.nan, math.nan)  # lat, lon, altitude above home
        self.ground_alt_amsl: float | None = None
        self._airdata: tuple[float, float] | None = None  # airspeed, climb rate
        # wired by the live loop
        self.on_reached: Callable[[int, float], None] = lambda seq, t: None
        self.on_tick: Callable[[float], None] = lambda t: None
        self.motor_faults: Callable[[], list[MotorFault]] = lambda: []

    # --- lifecycle -------------------------------------------------------------------------------

    def start(self) -> None:
        self.link.add_frame_listener(self.on_frame)
        self._thread = threading.Thread(target=self._run, name="telemetry", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._predictor.shutdown(wait=True, cancel_futures=True)

    # --- threads ---------------------------------------------------------------------------------

    def on_frame(self, frame) -> None:
        try:
            self._frames.put_nowait(frame)
        except queue.Full:
            self.frames_dropped += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self._frames.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                if callable(frame):  # work handed over by another thread (see call_soon)
                    frame()
                else:
                    self.process(frame)
            except Exception:  # noqa: BLE001 - one bad frame must not stop the loop
                log.exception("frame %r could not be processed", frame)

    def call_soon(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` between two frames on the telemetry thread (the filters are not thread-safe);
        driven directly, before the next :meth:`process`."""
        self._frames.put(fn)

    def elsewhere(self) -> bool:
        """Called from another thread than the running telemetry thread (e.g. an HTTP handler)?
        Driven directly (no thread started: tests and replays) the caller is the telemetry thread."""
        return self._thread is not None and threading.current_thread() is not self._thread

    # --- one frame -------------------------------------------------------------------------------

    def process(self, frame) -> None:
        """One frame, in message time (public so tests and replays can drive it directly)."""
        if self._thread is None:  # driven directly: run the work handed over since the last frame
            while True:
                try:
                    fn = self._frames.get_nowait()
                except queue.Empty:
                    break
                if callable(fn):
                    fn()
        self.frames_seen += 1
        st = self.service.state
        st.apply_frame(frame)
        t = frame.time_s
        self.time_s = t if self.time_s is None else max(self.time_s, t)
        if isinstance(frame, PositionFrame) and frame.lat_deg is not None:
            self.position = (frame.lat_deg, frame.lon_deg, frame.relative_alt_m or 0.0)
            if self.ground_alt_amsl is None and frame.alt_m is not None and frame.relative_alt_m is not None:
                self.ground_alt_amsl = frame.alt_m - frame.relative_alt_m
        elif isinstance(frame, AirdataFrame) and frame.airspeed is not None:
            self._airdata = (frame.airspeed, frame.climb_rate or 0.0)
        elif isinstance(frame, MissionProgressFrame) and frame.reached_seq is not None:
            self.on_reached(frame.reached_seq, t)
        elif isinstance(frame, StatusTextFrame):
            self.service.events.publish("statustext", time_s=t, severity=frame.severity, text=frame.text)
            if frame.severity <= 2:
                st.update(failed=frame.text)
        if self._feed_estimator:
            self.estimator.consume(frame)
        self.diagnoser.consume(frame)
        if t - self._last_status_s >= STATUS_PERIOD_S:
            self._last_status_s = t
            self._publish_estimate()
            self.on_tick(t)
            if t - self._last_predict_s >= PREDICT_PERIOD_S:
                self._last_predict_s = t
                self._predict(t)

    def _publish_estimate(self) -> None:
        st = self.service.state
        if self.estimator.ready():
            est = self.estimator.estimate()
            for i, n in enumerate(self.estimator.pack_names):
                st.update_nested("packs", n, soc=float(est.soc[i]), soc_sd=float(est.soc_sd[i]),
                                 temperature_c=float(est.pack_temp_c[i]), temperature_sd=float(est.pack_temp_sd[i]))
            for i, n in enumerate(self.estimator.motor_names):
                st.update_nested("motors", n, temperature_c=float(est.motor_temp_c[i]),
                                 temperature_sd=float(est.motor_temp_sd[i]))
        st.update(link={"connected": True, "received": self.link.received, "frames": self.frames_seen,
                        "frames_dropped": self.frames_dropped,
                        "vehicle": [self.link.target_system, self.link.target_component]})

    def _predict(self, t: float) -> None:
        """Time to each pack's cut-off at the present load (Monte Carlo), off the telemetry thread."""
        if self._predicting or self._airdata is None or not self.estimator.ready():
            return
        airspeed, climb = self._airdata
        if airspeed < FLYING_AIRSPEED_MPS:
            return
        alt = (self.ground_alt_amsl or 0.0) + (self.position[2] if math.isfinite(self.position[2]) else 0.0)
        power = float(shaft_power(airspeed, climb, air_density(alt)))
        amb = self.service.state.get("ambient_c")
        limits = self.service.limits.kernel_limits() if self.service.limits is not None else None
        if adapters.follows_description(self.service.vehicle):
            # a described vehicle: each pack at its present draw (no four-pack shaft-power model)
            job, power = adapters.cutoff_at_present_draw_job(self.estimator, self.service.vehicle, seed=int(t)), None
        else:
            job = adapters.prediction_job(self.estimator, power, float(amb) if amb is not None else 20.0,
                                          self.motor_faults(), limits, seed=int(t))
        self._predicting = True

        def run() -> None:
            try:
                pred = job()
                st = self.service.state
                per_pack = getattr(pred, "pack_time_to_cutoff_s", None)
                if per_pack is None:
                    per_pack = pred.time_to_cutoff_s
                for i, n in enumerate(self.estimator.pack_names):
                    q05, q50, q95 = (float(v) for v in per_pack[i])
                    sd = (q95 - q05) / 3.29 if math.isfinite(q95) and math.isfinite(q05) else None
                    st.update_nested("packs", n, time_to_cutoff_s=q50 if math.isfinite(q50) else None,
                                     time_to_cutoff_sd=sd)
                st.update(prediction={"time_s": t, "shaft_power_w": power, **pred.to_dict()})
            except Exception:  # noqa: BLE001 - a failed prediction only leaves the old numbers
                log.exception("prediction failed")
            finally:
                self._predicting = False

        self._predictor.submit(run)
