"""A paced UDP shell over the simulated vehicle's socket-free core (``gcs_pdm.sim.core.VehicleCore``).

Used by the demo and the end-to-end test when ``gcs_pdm.sim`` offers no network vehicle of its own.
Simulated time runs ``speedup`` times faster than the wall clock; the mission protocol is answered
in wall time (it is a property of the radio link, not of the aircraft), so the GCS side's
timeouts behave as they would against a real vehicle.
"""
from __future__ import annotations

import logging
import threading
import time

from gcs_pdm.mavlink.dialect import DIALECT, mavutil

log = logging.getLogger(__name__)


class LoopbackVehicle:
    def __init__(self, sim_config, url: str, speedup: float = 50.0, telemetry=None):
        from gcs_pdm.sim.core import VehicleCore

        if speedup <= 0:
            raise ValueError(f"speedup: must be > 0, got {speedup}")
        self.core = VehicleCore(sim_config, telemetry)
        self.url = url
        self.speedup = float(speedup)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-vehicle", daemon=True)
        self.conn = None
        self.error: BaseException | None = None

    @property
    def model(self):
        return self.core.model

    def start(self) -> "LoopbackVehicle":
        from gcs_pdm.sim.telemetry import COMPONENT_ID, SYSTEM_ID

        self.conn = mavutil.mavlink_connection(self.url, source_system=SYSTEM_ID, source_component=COMPONENT_ID,
                                               dialect=DIALECT)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        if self.conn is not None:
            self.conn.close()

    def _send(self, msgs) -> None:
        for m in msgs:
            try:
                self.conn.mav.send(m)
            except OSError as exc:
                log.debug("vehicle send failed: %s", exc)

    def _run(self) -> None:
        try:
            wall0 = time.monotonic()
            sim0 = self.core.time_s
            while not self._stop.is_set():
                self._send(self.core.tick())
                while True:
                    msg = self.conn.recv_msg()
                    if msg is None:
                        break
                    if msg.get_type() != "BAD_DATA":
                        self._send(self.core.receive(msg, time.monotonic()))
                self._send(self.core.poll(time.monotonic()))
                ahead = (self.core.time_s - sim0) / self.speedup - (time.monotonic() - wall0)
                if ahead > 0:
                    self._stop.wait(ahead)
        except BaseException as exc:  # noqa: BLE001 - reported to whoever waits on the vehicle
            self.error = exc
            log.exception("simulated vehicle stopped")
