"""Ask the vehicle for the telemetry streams the service needs and it does not send (the shell of
:mod:`gcs_pdm.mavlink.stream_requests`): a link subscription to those streams' messages, the
tracked vehicle's HEARTBEAT and COMMAND_ACK, on its own thread; every ``PERIOD_S`` it sends the
asks that are due (COMMAND_LONG SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM for older firmware)
and publishes what was asked for and what came as ``/status.streams``.

Its own thread, not the telemetry thread's: before the first asked stream comes there may be no
frame at all to wake the telemetry thread, and a silence is exactly what it must act on.
"""
from __future__ import annotations

import logging
import threading
import time

from gcs_pdm.mavlink.stream_requests import STREAMS, StreamPolicy, StreamRequests

log = logging.getLogger(__name__)

PERIOD_S = 0.5
#: MAV_AUTOPILOT_INVALID: a GCS, gimbal or camera heartbeat, not the vehicle's
_AUTOPILOT_INVALID = 8


class StreamWatch:
    def __init__(self, service, link, policy: StreamPolicy | None = None, period_s: float = PERIOD_S):
        self.service = service
        self.link = link
        self.requests = StreamRequests(policy)
        self.period_s = period_s
        self.sent = 0
        self._sub = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stream-requests", daemon=True)

    def start(self) -> "StreamWatch":
        types = {s.message for s in STREAMS} | {"HEARTBEAT", "COMMAND_ACK"}
        self._sub = self.link.subscribe(types)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        if self._sub is not None:
            self._sub.close()
            self._sub = None  # stopped twice (stop_mavlink, then Service.close): closed once

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self.step(time.monotonic())
            except Exception:  # noqa: BLE001 - asking must outlive one bad message or send
                log.exception("stream requests: step failed")

    def step(self, now: float) -> None:
        """Fold the messages received since the last step, send what is due, publish the report."""
        target = (self.link.target_system, self.link.target_component)
        while self._sub is not None:
            msg = self._sub.get(timeout=0)
            if msg is None:
                break
            if target[0] is None or (msg.get_srcSystem(), msg.get_srcComponent()) != target:
                continue
            kind = msg.get_type()
            if kind == "HEARTBEAT":
                if getattr(msg, "autopilot", _AUTOPILOT_INVALID) != _AUTOPILOT_INVALID:
                    self.requests.on_vehicle(now)
            elif kind == "COMMAND_ACK":
                self.requests.on_ack(int(msg.command), int(msg.result))
            else:
                self.requests.on_message(kind, now)
        for ask in self.requests.due(now):
            self._send(ask, target)
        self.service.state.update(streams=self.requests.report(now))

    def _send(self, ask, target) -> None:
        mav = self.link.mav
        log.info("asking vehicle %s for %s (message %d) at %g Hz%s", target[0], ask.stream, ask.msgid, ask.rate_hz,
                 f", and stream groups {list(ask.data_streams)}" if ask.data_streams else "")
        self.link.send(mav.command_long_encode(target[0], target[1], 511, 0, float(ask.msgid), float(ask.interval_us),
                                               0, 0, 0, 0, 0))
        for group in ask.data_streams:
            self.link.send(mav.request_data_stream_encode(target[0], target[1], group, max(1, round(ask.rate_hz)), 1))
        self.sent += 1
