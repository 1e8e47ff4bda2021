"""Telemetry intake: the link's frames into the estimator and the diagnoser, on one thread, in
message time.

* the link's reader thread hands every frame to :meth:`TelemetryIntake.on_frame`, which only
  enqueues it (the reader must never wait for us);
* the telemetry thread (:meth:`TelemetryIntake._run`) feeds the estimator and the diagnoser and
  updates the live state. It never plans, uploads or fits, so telemetry is never held up. The
  filters are not thread-safe: other threads hand work over with :meth:`call_soon`;
* it watches the link: after ``link_lost_after_s`` without a heartbeat from the tracked vehicle the
  link is lost (live state, event, predictions marked stale) until the vehicle is heard again;
* once a second of message time it publishes the estimate and calls ``on_tick`` (the live loop's
  fault and deviation checks); every ``PREDICT_PERIOD_S`` it starts a time-to-cut-off prediction
  on its own worker (a long plan must not freeze the status page's numbers) while the vehicle
  flies (``flight_phase``: by airspeed for a fixed wing, by armed state, EXTENDED_SYS_STATE and
  hover-level power for a multirotor); on the ground it says why there is none.
"""
from __future__ import annotations

import logging
import math
import queue
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

from gcs_pdm.estimation.flight_conditions import FlightConditions, PredictionInputs
from gcs_pdm.estimation.flight_phase import FlightPhase
from gcs_pdm.frames import MissionProgressFrame, PackFrame, PositionFrame, StatusFrame, StatusTextFrame
from gcs_pdm.models.powertrain import MotorFault
from gcs_pdm.service import adapters
from gcs_pdm.service.live_state import LINK_LOST, LINK_UP
from gcs_pdm.service.fit_envelope import FitEnvelopeWatch, estimator_readings, flown_envelopes
from gcs_pdm.service.status_report import model_mismatch_summary

log = logging.getLogger(__name__)

STATUS_PERIOD_S = 1.0
#: the messages that tell when the vehicle's mission must be read again (mavlink.mission_watch)
MISSION_WATCH_TYPES = frozenset({"HEARTBEAT", "HOME_POSITION", "MISSION_CURRENT", "MISSION_ACK", "MISSION_CHANGED",
                                 "MISSION_COUNT"})
#: the autopilot's own landed/in-air verdict (ArduCopter, PX4), read for the flight phase
LANDED_STATE_TYPE = "EXTENDED_SYS_STATE"
#: wall seconds between two checks of the vehicle's silence
LINK_CHECK_PERIOD_S = 0.2
PREDICT_PERIOD_S = 10.0


class TelemetryIntake:
    def __init__(self, service, link, estimator, diagnoser, *, feed_estimator: bool):
        self.service = service
        self.link = link
        self.estimator = estimator
        self.diagnoser = diagnoser
        # The pipeline feeds its own estimator; feeding it twice would double-count every frame.
        self._feed_estimator = feed_estimator
        #: the packs against the conditions their values were fitted on (fit_envelope), per estimator
        self.fit_envelope = FitEnvelopeWatch({})
        self._envelope_of = None
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
        #: what a prediction needs from the flight (phase, air density, load): the core's, as a replay's
        self.conditions = FlightConditions()
        #: the vehicle has been silent too long (see check_link); why, for the refusals and /health
        self.link_lost = False
        self.link_lost_reason: str | None = None
        self._last_link_check = -math.inf
        self._recording_stopped = False  # the live tlog's state last told (an event on each change)
        # wired by the live loop
        self.on_reached: Callable[[int, float], None] = lambda seq, t: None
        self.on_tick: Callable[[float], None] = lambda t: None
        self.on_link_restored: Callable[[], None] = lambda: None
        self.on_message: Callable[[object, float], None] = lambda msg, t: None
        #: each frame's message time and the armed flag, before anything else (flights begin and end
        #: there: service/flights.py); the vehicle's silence in wall seconds, at each link check
        self.on_clock: Callable[[float, bool | None], None] = lambda t, armed: None
        self.on_silent: Callable[[float], None] = lambda silent_s: None
        self.on_pack: Callable[[PackFrame], None] = lambda frame: None
        self._messages = None  # the link's subscription to MISSION_WATCH_TYPES
        self.motor_faults: Callable[[], list[MotorFault]] = lambda: []

    # --- lifecycle -------------------------------------------------------------------------------

    def start(self) -> None:
        self.link.add_frame_listener(self.on_frame)
        subscribe = getattr(self.link, "subscribe", None)
        if subscribe is not None:
            self._messages = subscribe(MISSION_WATCH_TYPES | {LANDED_STATE_TYPE}, maxsize=1000)
        self._thread = threading.Thread(target=self._run, name="telemetry", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._messages is not None:
            self._messages.close()
        self._predictor.shutdown(wait=True, cancel_futures=True)

    # --- threads ---------------------------------------------------------------------------------

    def on_frame(self, frame) -> None:
        try:
            self._frames.put_nowait(frame)
        except queue.Full:
            self.frames_dropped += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            if time.monotonic() - self._last_link_check >= LINK_CHECK_PERIOD_S:
                self._last_link_check = time.monotonic()
                try:
                    self.check_link()
                except Exception:  # noqa: BLE001 - the check must not stop the loop
                    log.exception("link check failed")
            self._pass_messages()
            try:
                frame = self._frames.get(timeout=LINK_CHECK_PERIOD_S)
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
        self.on_clock(t, bool(frame.armed) if isinstance(frame, StatusFrame) else self.conditions.armed)
        self.time_s = t if self.time_s is None else max(self.time_s, t)
        self.conditions.consume(frame)
        if isinstance(frame, PositionFrame) and frame.lat_deg is not None:
            self.position = (frame.lat_deg, frame.lon_deg, frame.relative_alt_m or 0.0)
        elif isinstance(frame, PackFrame):
            self.on_pack(frame)
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
            if t - self._last_predict_s >= PREDICT_PERIOD_S and not self.link_lost:
                self._last_predict_s = t
                self._predict(t)

    def _publish_estimate(self) -> None:
        st = self.service.state
        if self.estimator.ready():
            est = self.estimator.estimate()
            for i, n in enumerate(self.estimator.pack_names):
                st.update_nested("packs", n, soc=float(est.soc[i]), soc_sd=float(est.soc_sd[i]),
                                 temperature_c=float(est.pack_temp_c[i]), temperature_sd=float(est.pack_temp_sd[i]),
                                 model_mismatch=est.model_mismatch.get(n),
                                 # what the SoC rests on (a self-calibrated pack; None: the paper filter)
                                 evidence=est.evidence.get(n))
            # same keys every time, so LiveState's one-level merge replaces it whole
            st.update(model_mismatch=model_mismatch_summary(est.model_mismatch))
            st.update(fit_envelope=self._envelope_watch().update(**estimator_readings(self.estimator, est)))
            for i, n in enumerate(self.estimator.motor_names):
                st.update_nested("motors", n, temperature_c=float(est.motor_temp_c[i]),
                                 temperature_sd=float(est.motor_temp_sd[i]))
        st.update(link={"connected": not self.link_lost, "state": LINK_LOST if self.link_lost else LINK_UP,
                        "received": self.link.received, "frames": self.frames_seen,
                        "frames_dropped": self.frames_dropped,
                        "vehicle": [self.link.target_system, self.link.target_component]})

    def _envelope_watch(self) -> FitEnvelopeWatch:
        """The fit-envelope watch of the estimator now running (a new one when it is replaced: the
        envelopes are those of the values it flies)."""
        if self._envelope_of is not self.estimator:
            try:
                envelopes = flown_envelopes(self.estimator)
            except Exception:  # noqa: BLE001 - a set that cannot be read again must not stop the estimate
                log.exception("the fitted packs' training envelopes could not be read; not checked")
                envelopes = {}
            self.fit_envelope, self._envelope_of = FitEnvelopeWatch(envelopes), self.estimator
        return self.fit_envelope

    def _pass_messages(self) -> None:
        """The tracked vehicle's mission-related messages to ``on_message``, at the latest message
        time (these messages carry no timestamp of their own). Other systems' are not our vehicle's."""
        if self._messages is None:
            return
        while True:
            msg = self._messages.get(timeout=0)
            if msg is None:
                return
            if (msg.get_srcSystem(), msg.get_srcComponent()) != (self.link.target_system, self.link.target_component):
                continue
            if msg.get_type() == LANDED_STATE_TYPE:
                self.on_landed_state(getattr(msg, "landed_state", 0), self.time_s)
                continue
            try:
                self.on_message(msg, self.time_s if self.time_s is not None else 0.0)
            except Exception:  # noqa: BLE001 - one odd message must not stop the loop
                log.exception("message %s could not be watched", msg.get_type())

    def on_landed_state(self, landed_state: int, time_s: float | None) -> None:
        """EXTENDED_SYS_STATE's MAV_LANDED_STATE (0 = undefined: not evidence) at message time."""
        self.conditions.on_landed_state(landed_state, time_s)

    @property
    def ground_alt_amsl(self) -> float | None:
        return self.conditions.ground_alt_amsl

    # --- the link's state ------------------------------------------------------------------------

    def check_link(self) -> None:
        """Declare the link lost after ``link_lost_after_s`` without a heartbeat from the tracked
        vehicle, and restored when one arrives again.

        This one check runs on receive (monotonic wall) time, not message time: message time comes
        from the vehicle's own timestamps and simply stops while the vehicle is silent, so silence
        cannot be measured in it. Before the vehicle was ever heard the link is waiting, not lost."""
        self._check_recording()
        silent_fn = getattr(self.link, "vehicle_silent_s", None)
        silent = silent_fn() if silent_fn is not None else None
        if silent is None:
            return
        self.on_silent(silent)
        limit = self.service.config.link_lost_after_s
        lost = silent > limit
        st = self.service.state
        if lost and self.link_lost:
            st.update(link={"silent_s": silent})
            return
        if lost == self.link_lost:
            return
        self.link_lost = lost
        vehicle = [self.link.target_system, self.link.target_component]
        if lost:
            cause_fn = getattr(self.link, "silence_cause", None)  # heartbeats alone are not the vehicle's life
            cause = cause_fn() if cause_fn is not None else ""
            self.link_lost_reason = (f"vehicle {vehicle[0]}: {cause}" if cause.startswith("heartbeats without")
                                     else f"no heartbeat from vehicle {vehicle[0]} for {silent:.1f} s")
            self.link_lost_reason += f" (link_lost_after_s = {limit:g})"
            log.warning("link lost: %s", self.link_lost_reason)
            st.update(link={"connected": False, "state": LINK_LOST, "reason": self.link_lost_reason,
                            "silent_s": silent, "lost_at_time_s": self.time_s})
            # No count-down for a vehicle we cannot hear: its load and state since are unknown.
            for n in self.estimator.pack_names:
                st.update_nested("packs", n, time_to_cutoff_s=None, time_to_cutoff_sd=None)
            st.update(prediction={"stale": True, "reason": "link lost: " + self.link_lost_reason,
                                  "time_s": self.time_s})
            self.service.events.publish("link", status="lost", reason=self.link_lost_reason, vehicle=vehicle,
                                        time_s=self.time_s, silent_s=silent)
        else:
            log.warning("link restored: vehicle %s heard again", vehicle[0])
            reason, self.link_lost_reason = self.link_lost_reason, None
            st.update(link={"connected": True, "state": LINK_UP, "reason": None, "silent_s": silent})
            self._last_predict_s = -math.inf  # a fresh prediction at the next status tick
            self.service.events.publish("link", status="restored", vehicle=vehicle, time_s=self.time_s,
                                        was=reason)
            self.on_link_restored()

    def restart_clock(self) -> None:
        """The vehicle rebooted (its message time went back): count from its new clock."""
        self.time_s = None
        self._last_status_s = self._last_predict_s = -math.inf
        self.conditions.restart_clock()

    def _check_recording(self) -> None:
        """One ``recording`` event when the live tlog stops (a full or failing disk) and one when it
        resumes; /health and the console's banner read the link's report itself."""
        report_fn = getattr(self.link, "recording_report", None)
        if report_fn is None:
            return
        rec = report_fn()
        stopped = bool(rec.get("stopped"))
        if stopped == self._recording_stopped:
            return
        self._recording_stopped = stopped
        self.service.events.publish("recording", status="stopped" if stopped else "resumed", reason=rec.get("reason"),
                                    file=rec.get("file"), dropped=rec.get("dropped"), time_s=self.time_s)

    def flight_phase(self, t: float) -> FlightPhase:
        """Flying or not, and why, from the latest telemetry and the vehicle's airframe."""
        return self.conditions.phase(t, self._vehicle(), self.estimator)

    def _vehicle(self):
        """The description the vehicle is flown as (the service resolves "none given": ``Service.flown_vehicle``)."""
        return self.service.flown_vehicle()

    def prediction_inputs(self, t: float) -> PredictionInputs:
        """What a prediction at ``t`` starts from: the core's (``FlightConditions.inputs``), as a replay's."""
        return self.conditions.inputs(t, self._vehicle(), self.estimator)

    def _not_flying(self, t: float, phase: FlightPhase) -> None:
        """No flight load on the ground: no count-down, and the reason in its place."""
        st = self.service.state
        for n in self.estimator.pack_names:
            st.update_nested("packs", n, time_to_cutoff_s=None, time_to_cutoff_sd=None)
        # the section merges: the last flight's numbers are cleared, not left beside the reason
        cleared = dict.fromkeys(st.get("prediction") or {})
        st.update(prediction={**cleared, "stale": True, "flying": False, "reason": "not flying: " + phase.reason,
                              "time_s": t})

    def _predict(self, t: float) -> None:
        """Time to each pack's cut-off at the present load (Monte Carlo), off the telemetry thread;
        the load is the core's (``FlightConditions.inputs``: the airframe's shaft power, or each
        pack's present draw), the faults the vehicle's motors'."""
        if self._predicting or not self.estimator.ready():
            return
        vehicle = self._vehicle()
        inputs = self.prediction_inputs(t)
        phase = inputs.phase
        if not phase.flying:
            self._not_flying(t, phase)
            return
        power = inputs.shaft_power_w
        if power is None:
            job = adapters.cutoff_at_present_draw_job(self.estimator, vehicle, seed=int(t))
        else:
            job = adapters.prediction_job(self.estimator, power, inputs.ambient_c, self.motor_faults(),
                                          self.service.limits_override(vehicle),
                                          seed=int(t))
        self._predicting = True

        def run() -> None:
            try:
                pred = job()
                if self.link_lost:  # the vehicle went silent meanwhile: these numbers are stale already
                    return
                st = self.service.state
                per_pack = getattr(pred, "pack_time_to_cutoff_s", None)
                if per_pack is None:
                    per_pack = pred.time_to_cutoff_s
                for i, n in enumerate(self.estimator.pack_names):
                    q05, q50, q95 = (float(v) for v in per_pack[i])
                    sd = (q95 - q05) / 3.29 if math.isfinite(q95) and math.isfinite(q05) else None
                    st.update_nested("packs", n, time_to_cutoff_s=q50 if math.isfinite(q50) else None,
                                     time_to_cutoff_sd=sd)
                st.update(prediction={"time_s": t, "shaft_power_w": power, "stale": False, "flying": True,
                                      "reason": None, "flight": phase.reason, **pred.to_dict()})
            except Exception:  # noqa: BLE001 - a failed prediction only leaves the old numbers
                log.exception("prediction failed")
            finally:
                self._predicting = False

        self._predictor.submit(run)
