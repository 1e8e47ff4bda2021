"""The vehicle the service diagnoses: the description given (``vehicle`` in the config,
``--vehicle``), or a provisional one derived from the first telemetry.

Without a description the service cannot name a pack or a motor, so until one is derived:

* the link maps no pack or motor frames (``vehicle.telemetry.waiting_mapping``): a BATTERY_STATUS
  id means nothing yet;
* the estimator and diagnoser are an :class:`AwaitingVehicle`: nothing is estimated, diagnosed or
  predicted, and a replan is refused (409) with the reason, e.g. "waiting for the vehicle
  description: the first voltage readings of battery0 (2 of 5 readings)";
* :class:`VehicleDiscovery` folds the tracked vehicle's HEARTBEAT, BATTERY_STATUS,
  ESC_TELEMETRY_* and PARAM_VALUE messages (a link subscription, on its own thread) into a
  ``ProvisionalObserver`` until it has settled, then hands the description to the live loop,
  which builds the mapper rules, the estimator and the diagnoser from it (on the telemetry thread).
  A pack's capacity is evidence, never a guess: the discovery asks the autopilot for its capacity
  parameters (PARAM_REQUEST_READ of ArduPilot's BATT_CAPACITY/BATTn_CAPACITY and PX4's
  BATn_CAPACITY); without an answer it waits until the charge drawn against the fall of
  battery_remaining measures it, and says so (``waiting``).
"""
from __future__ import annotations

import logging
import threading
from typing import Callable

from gcs_pdm.vehicle.description import VehicleDescription, VehicleError
from gcs_pdm.vehicle.provisional import ProvisionalObserver

log = logging.getLogger(__name__)

WANTED = ("HEARTBEAT", "BATTERY_STATUS", "ESC_TELEMETRY_1_TO_4", "ESC_TELEMETRY_5_TO_8",
          "ESC_TELEMETRY_9_TO_12", "ESC_TELEMETRY_13_TO_16", "PARAM_VALUE")
#: a capacity parameter not answered is asked again every this many BATTERY_STATUS, at most CAPACITY_ASKS times
ASK_EVERY_READINGS = 10
CAPACITY_ASKS = 3


def about_vehicle(desc: VehicleDescription | None, source: str, notes: list[str] | tuple = (),
                  waiting: str | None = None) -> dict:
    """What /status, the log and the event say about the vehicle description in use."""
    out = {"name": desc.name if desc is not None else None, "source": source,
           "provisional": bool(desc is not None and desc.provisional), "notes": list(notes)}
    if desc is not None:
        out["packs"] = [p.name for p in desc.packs]
        out["motors"] = [m.name for m in desc.motors]
    if source in ("provisional", "deriving"):
        out["save"] = ("record this flight's tlog (data_dir/tlogs), then `gcs-pdm vehicle init --from LOG --out "
                       "vehicle.toml`, correct it, and start with --vehicle vehicle.toml (docs/vehicles.md)")
    if waiting:
        out["waiting_for"] = waiting
    return out


class AwaitingVehicle:
    """Estimator and diagnoser stand-in until a description exists: it estimates nothing and says why."""

    pack_names: tuple[str, ...] = ()
    motor_names: tuple[str, ...] = ()

    def __init__(self, why: Callable[[], str]):
        self._why = why
        self.estimator = self

    def consume(self, frame) -> None:
        pass

    def ready(self) -> bool:
        return False

    def active_faults(self) -> list:
        return []

    def readiness(self) -> dict[str, str]:
        why = self._why()
        return {"state": why, "prediction": why, "motor_telemetry": why, "motor_diagnosis": why}


class VehicleDiscovery:
    """Derives the provisional description from the tracked vehicle's first messages."""

    def __init__(self, link, on_derived: Callable[[VehicleDescription, list[str]], None]):
        self.link = link
        self.on_derived = on_derived
        self.observer = ProvisionalObserver()
        self.failed: str | None = None
        self._stop = threading.Event()
        self._asked: dict[str, int] = {}
        self._battery_readings = 0
        self._sub = link.subscribe(WANTED)
        self._thread = threading.Thread(target=self._run, name="vehicle-discovery", daemon=True)

    def start(self) -> "VehicleDiscovery":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sub.close()

    def waiting(self) -> str:
        if self.failed:
            return f"no vehicle description: {self.failed}; start with --vehicle FILE|PRESET (docs/vehicles.md)"
        why = self.observer.waiting_for() or "its derivation"
        asked = [n for n in self._asked if n not in self.observer.parameters]
        if why.startswith("the capacity of") and asked:
            why += f"; asked the autopilot for {', '.join(asked)}"
        return "waiting for the vehicle description: " + why

    def _ask_capacities(self) -> None:
        """PARAM_REQUEST_READ of the capacity parameters of the packs seen, not yet answered."""
        for name in self.observer.capacity_parameter_names():
            if name in self.observer.parameters or self._asked.get(name, 0) >= CAPACITY_ASKS:
                continue
            self._asked[name] = self._asked.get(name, 0) + 1
            try:
                self.link.send(self.link.mav.param_request_read_encode(
                    self.link.target_system, self.link.target_component or 0, name.encode(), -1))
            except (AttributeError, OSError, TypeError) as exc:  # a link that cannot send: the discharge will tell
                log.debug("cannot ask for %s: %s", name, exc)

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self._sub.get(timeout=0.2)
            if msg is None:
                continue
            target = self.link.target_system
            if target is None or msg.get_srcSystem() != target:  # only the tracked vehicle describes itself
                continue
            self.observer.observe(msg.get_type(), msg.to_dict())
            if msg.get_type() == "BATTERY_STATUS":
                self._battery_readings += 1
                if self._battery_readings % ASK_EVERY_READINGS == 1:
                    self._ask_capacities()
            if self.observer.waiting_for() is not None:
                continue
            try:
                desc, notes = self.observer.derive()
            except VehicleError as exc:  # e.g. a HEARTBEAT type that is neither plane nor multirotor
                self.failed = str(exc)
                log.error("no provisional vehicle description: %s", exc)
                break
            self.on_derived(desc, notes)
            break
        self._sub.close()
