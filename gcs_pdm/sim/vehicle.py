"""The simulated vehicle on a UDP link: a background thread around :class:`~gcs_pdm.sim.core.VehicleCore`.

    vehicle = SimulatedVehicle(SimConfig(mission=items, faults=(parse_fault("motor:aft:0.8@leg:2-3"),)),
                               "udpout:127.0.0.1:14550", speedup=20).start()
    ...
    vehicle.wait_for(lambda s: s.landed or s.failed, timeout=120)
    vehicle.stop()

Time: ``speedup=1`` is real time, ``speedup=N`` runs the simulated clock N times faster, and
``speedup=None`` is lock-step — as fast as the CPU allows while the vehicle is armed, real time
while it waits disarmed on the ground (so a GCS has time to connect and upload). ``hold`` (a
callable) stops the simulated clock while it returns True: the vehicle still answers the mission
protocol but neither flies nor sends telemetry, so a test can make "when does the GCS's answer
arrive in flight time" independent of how loaded the machine is. Telemetry and
every ``time_boot_ms`` carry simulated time; the mission protocol's timeouts run on wall time,
as the GCS's do.

The model's physics and telemetry noise depend only on the config and the seed, so two runs with
the same inputs fly the same flight; what a GCS sends, and when, is the only outside influence.
"""
from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Callable

from gcs_pdm.mavlink.dialect import DIALECT, mavutil
from gcs_pdm.mavlink.tlog import TlogWriter
from gcs_pdm.sim.core import VehicleCore, warm_up_kernel
from gcs_pdm.sim.mission_server import ServerTimeouts
from gcs_pdm.sim.model import Event, SimConfig, TruthState
from gcs_pdm.sim.telemetry import COMPONENT_ID, SYSTEM_ID, TelemetryConfig

log = logging.getLogger(__name__)

#: most physics ticks run between two looks at the socket (keeps the mission protocol responsive)
MAX_TICKS_PER_LOOP = 50
#: if the paced clock falls this far behind (s of simulated time), it gives up catching up
MAX_LAG_S = 5.0


class SimulatedVehicle:
    """A MAVLink 2 fixed-wing vehicle (system 1, component 1) flying the simulated truth."""

    def __init__(self, config: SimConfig, url: str = "udpout:127.0.0.1:14550", *, speedup: float | None = 1.0,
                 telemetry: TelemetryConfig | None = None, tlog_path: str | Path | None = None,
                 timeouts: ServerTimeouts | None = None, idle_speedup: float = 1.0,
                 hold: Callable[[], bool] | None = None):
        if speedup is not None and not speedup > 0:
            raise ValueError(f"speedup: must be > 0 (or None for lock-step), got {speedup!r}")
        self.config = config
        self.url = url
        self.speedup = speedup
        self.idle_speedup = idle_speedup
        self.hold = hold
        self.core = VehicleCore(config, telemetry, timeouts)
        warm_up_kernel(config)
        self.tlog_path = tlog_path
        self._tlog: TlogWriter | None = None
        self._conn = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._state: TruthState = self.core.last_state
        self._events: list[Event] = []
        self._calls: list[Callable[[], None]] = []
        self.error: BaseException | None = None
        self.sent = 0
        self.received = 0

    # ---- lifecycle ----------------------------------------------------------------------------

    def start(self) -> "SimulatedVehicle":
        if self._thread is not None:
            return self
        self._conn = mavutil.mavlink_connection(self.url, source_system=SYSTEM_ID, source_component=COMPONENT_ID,
                                                dialect=DIALECT)
        if getattr(self._conn, "WIRE_PROTOCOL_VERSION", "2.0") != "2.0":
            raise RuntimeError("pymavlink did not select MAVLink 2")
        self._conn.mav.srcSystem = SYSTEM_ID
        self._conn.mav.srcComponent = COMPONENT_ID
        if self.tlog_path is not None:
            self._tlog = TlogWriter(self.tlog_path)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sim-vehicle", daemon=True)
        self._thread.start()
        log.info("simulated vehicle on %s (speedup %s)", self.url, "lock-step" if self.speedup is None else self.speedup)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass
            self._conn = None
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None

    def __enter__(self) -> "SimulatedVehicle":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def model(self):
        """The vehicle's :class:`~gcs_pdm.sim.model.VehicleModel` (owned by the vehicle thread: read
        ``state`` instead while it runs, or change it through :meth:`call`)."""
        return self.core.model

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def local_port(self) -> int | None:
        """The UDP port the vehicle's socket is bound to (for ``udpin:`` with port 0)."""
        port = getattr(self._conn, "port", None)
        try:
            return port.getsockname()[1] if port is not None else None
        except OSError:
            return None

    # ---- observation and control (thread-safe) --------------------------------------------

    @property
    def state(self) -> TruthState:
        """The latest truth snapshot."""
        with self._lock:
            return self._state

    @property
    def events(self) -> list[Event]:
        with self._lock:
            return list(self._events)

    @property
    def fault_log(self) -> list[dict]:
        with self._lock:
            return [dict(f) for f in self.core.model.fault_log]

    def call(self, fn: Callable[[VehicleCore], None]) -> None:
        """Run ``fn(core)`` on the vehicle's thread before its next tick (e.g. to change the mission)."""
        with self._lock:
            self._calls.append(lambda: fn(self.core))

    def inject_fault(self, motor: str, magnitude: float) -> None:
        self.call(lambda core: core.model.inject_fault(motor, magnitude, reason="injected by call"))

    def wait_for(self, predicate: Callable[[TruthState], bool], timeout: float) -> TruthState:
        """Block until ``predicate(state)`` holds; raises TimeoutError (or the vehicle thread's error)."""
        deadline = time.monotonic() + timeout
        while True:
            if self.error is not None:
                raise RuntimeError("simulated vehicle thread failed") from self.error
            s = self.state
            if predicate(s):
                return s
            if time.monotonic() > deadline:
                raise TimeoutError(f"vehicle state not reached within {timeout:.1f} s (sim time {s.time_s:.1f} s, "
                                   f"mode {s.mode}, item {s.current_seq})")
            time.sleep(0.01)

    def wait_finished(self, timeout: float) -> TruthState:
        """Until the flight is over: landed, or failed and on the ground."""
        return self.wait_for(lambda s: (s.landed or s.failed) and s.on_ground and not s.armed, timeout)

    # ---- the loop -----------------------------------------------------------------------------

    def _send(self, msgs: list) -> None:
        conn = self._conn
        for msg in msgs:
            try:
                conn.mav.send(msg)
            except OSError as exc:  # udpin before any GCS spoke, or the GCS went away
                log.debug("send failed: %s", exc)
                continue
            self.sent += 1
            if self._tlog is not None:
                self._tlog.write(msg.get_msgbuf(), self._stamp())

    def _stamp(self) -> float:
        return self.core.telemetry.config.boot_unix_us / 1e6 + self.core.time_s

    def _receive(self) -> None:
        conn = self._conn
        while True:
            try:
                msg = conn.recv_msg()
            except (OSError, ConnectionError) as exc:
                log.debug("receive failed: %s", exc)
                return
            if msg is None:
                return
            if msg.get_type() == "BAD_DATA":
                continue
            self.received += 1
            if self._tlog is not None:
                self._tlog.write(msg.get_msgbuf(), self._stamp())
            self._send(self.core.receive(msg, time.monotonic()))

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # noqa: BLE001 - surfaced to the test/demo through wait_for
            log.exception("simulated vehicle stopped by an error")
            self.error = exc

    def _loop(self) -> None:
        core = self.core
        dt = core.config.physics_dt_s
        wall_ref = time.monotonic()
        sim_ref = core.time_s
        paced_speed = self.speedup if self.speedup is not None else self.idle_speedup
        while not self._stop.is_set():
            with self._lock:
                calls, self._calls = self._calls, []
            for fn in calls:
                fn()
            self._receive()
            self._send(core.poll(time.monotonic()))
            lockstep_now = self.speedup is None and core.model.armed
            now = time.monotonic()
            ticks = 0
            if self.hold is not None and self.hold():
                wall_ref, sim_ref = now, core.time_s  # the clock resumes from here, no catching up
                lockstep_now = False
            elif lockstep_now:
                while ticks < MAX_TICKS_PER_LOOP and core.model.armed:
                    self._send(core.tick())
                    ticks += 1
                wall_ref, sim_ref = time.monotonic(), core.time_s
            else:
                target = sim_ref + (now - wall_ref) * paced_speed
                if target - core.time_s > MAX_LAG_S:
                    log.warning("simulation %.1f s behind its clock: resynchronising", target - core.time_s)
                    wall_ref, sim_ref = now, core.time_s
                    target = sim_ref
                while core.time_s + 0.5 * dt <= target and ticks < MAX_TICKS_PER_LOOP:
                    self._send(core.tick())
                    ticks += 1
            if ticks:
                with self._lock:
                    self._state = core.last_state
                    self._events.extend(core.event_log)
                    core.event_log.clear()
            elif core.event_log:
                with self._lock:
                    self._events.extend(core.event_log)
                    core.event_log.clear()
                    self._state = core.last_state
            if lockstep_now:
                continue
            # sleep until the next tick is due or a packet arrives
            next_due = wall_ref + (core.time_s + dt - sim_ref) / paced_speed
            wait = min(0.02, max(0.0, next_due - time.monotonic()))
            if wait > 0:
                try:
                    self._conn.select(wait)
                except (OSError, ValueError):
                    time.sleep(wait)
