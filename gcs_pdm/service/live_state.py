"""The one place that holds what the service currently knows about the vehicle.

Written by the live loop (one thread), read by the HTTP API (others): every update and every
snapshot takes the lock, and a snapshot is a plain JSON-able dict copy.
"""
from __future__ import annotations

import copy
import math
import threading
from typing import Any

from gcs_pdm.estimation.wind import WindEstimator
from gcs_pdm.frames import (AirdataFrame, AmbientFrame, MissionProgressFrame, MotorFrame, PackFrame,
                            PositionFrame, StatusFrame, WindFrame)
from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES
from gcs_pdm.service.storage import Conflict
from gcs_pdm.service.track import Track

#: the link's states in /status: no vehicle heard yet, telemetry flowing, vehicle silent too long
LINK_WAITING, LINK_UP, LINK_LOST = "waiting", "up", "lost"


class LinkLost(Conflict):
    """An action that needs the vehicle (replan, upload, approval, mission read) while the link is
    lost: refused (HTTP 409 with the reason), never queued to run against a silent vehicle."""


def _clean(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _packs(names) -> dict[str, dict]:
    return {n: {"voltage_v": None, "current_a": None, "temperature_c": None, "soc": None, "soc_sd": None,
                "temperature_sd": None, "time_to_cutoff_s": None, "time_to_cutoff_sd": None} for n in names}


def _motors(names) -> dict[str, dict]:
    return {n: {"current_a": None, "rpm": None, "temperature_c": None, "temperature_sd": None,
                "health": 1.0, "fault": None} for n in names}


class LiveState:
    def __init__(self, track_window_s: float = 7200.0) -> None:
        self._lock = threading.Lock()
        #: the vehicle's recent positions (1 Hz, ``track_window_s`` of message time) for the console
        self.track = Track(window_s=track_window_s)
        #: the wind: the autopilot's estimate, else the wind triangle (gcs_pdm.estimation.wind)
        self.wind = WindEstimator()
        self._s: dict[str, Any] = {
            "time_s": None,
            "link": {"url": None, "connected": False, "state": LINK_WAITING, "reason": None, "vehicle": None,
                     "received": 0, "last_frame_time_s": None},
            "packs": _packs(PACK_NAMES),
            "motors": _motors(MOTOR_NAMES),
            "ambient_c": None,
            "position": {"lat_deg": None, "lon_deg": None, "alt_m": None, "relative_alt_m": None},
            "airdata": {"airspeed": None, "groundspeed": None, "climb_rate": None, "throttle_pct": None},
            "armed": None, "mode": None, "system_status": None,
            "mission": {"current_seq": None, "last_reached_seq": None, "count": None},
            "prediction": None,
            "outlook": {"unknown": "not evaluated yet", "line": "outlook unknown: not evaluated yet"},
            "wind": {"unknown": "no wind estimate from the autopilot and no airspeed with ground velocity yet"},
            "policy": None,
            "parameter_set": None,
            "failed": None,
            "model_mismatch": None,
            "fit_envelope": None,
            "model_variants": None,
            # what the service can and cannot do now, and why (the pipeline's readiness)
            "readiness": {"state": "no vehicle link", "prediction": "no vehicle link",
                          "motor_telemetry": "no vehicle link", "motor_diagnosis": "no vehicle link"},
            "vehicle": None,
        }

    def set_components(self, packs: tuple[str, ...] | list[str], motors: tuple[str, ...] | list[str]) -> None:
        """The vehicle's packs and motors by name (a description's), their readings not yet known."""
        with self._lock:
            self._s["packs"] = _packs(packs)
            self._s["motors"] = _motors(motors)

    def update(self, **sections: Any) -> None:
        with self._lock:
            for key, value in sections.items():
                if isinstance(value, dict) and isinstance(self._s.get(key), dict):
                    self._s[key].update(value)
                else:
                    self._s[key] = value

    def replace(self, **sections: Any) -> None:
        """Set whole sections (``update`` merges a dict into the one there)."""
        with self._lock:
            self._s.update(sections)

    def update_nested(self, section: str, name: str, **values: Any) -> None:
        with self._lock:
            self._s[section][name].update({k: _clean(v) for k, v in values.items()})

    def apply_frame(self, f: Any) -> None:
        """Raw telemetry, as received (the estimator's view is set separately)."""
        with self._lock:
            s = self._s
            s["time_s"] = max(s["time_s"] or f.time_s, f.time_s)
            s["link"]["last_frame_time_s"] = f.time_s
            if isinstance(f, PackFrame) and f.pack in s["packs"]:
                p = s["packs"][f.pack]
                for k in ("voltage_v", "current_a", "temperature_c"):
                    v = getattr(f, k)
                    if v is not None:
                        p[k if k != "temperature_c" else "temperature_raw_c"] = v
            elif isinstance(f, MotorFrame) and f.motor in s["motors"]:
                m = s["motors"][f.motor]
                for k in ("current_a", "rpm"):
                    v = getattr(f, k)
                    if v is not None:
                        m[k] = v
                if f.temperature_c is not None:
                    m["temperature_raw_c"] = f.temperature_c
            elif isinstance(f, AmbientFrame):
                if f.temperature_c is not None:
                    s["ambient_c"] = f.temperature_c
            elif isinstance(f, PositionFrame):
                s["position"].update({k: getattr(f, k) for k in ("lat_deg", "lon_deg", "alt_m", "relative_alt_m")})
                self.track.add(f.time_s, f.lat_deg, f.lon_deg, f.alt_m, f.relative_alt_m)
            elif isinstance(f, AirdataFrame):
                s["airdata"].update({k: getattr(f, k) for k in ("airspeed", "groundspeed", "climb_rate", "throttle_pct")})
            elif isinstance(f, StatusFrame):
                s["armed"], s["mode"], s["system_status"] = f.armed, f.mode, f.system_status
            if isinstance(f, (WindFrame, PositionFrame, AirdataFrame)):
                self.wind.consume(f)
                est = self.wind.estimate(f.time_s)
                s["wind"] = est.to_dict() if est is not None else {
                    "unknown": "no fresh wind estimate from the autopilot and the wind triangle not settled"}
            if isinstance(f, MissionProgressFrame):
                if f.current_seq is not None:
                    s["mission"]["current_seq"] = f.current_seq
                if f.reached_seq is not None:
                    s["mission"]["last_reached_seq"] = f.reached_seq

    def wind_en(self) -> tuple[float, float] | None:
        """The wind now (the air's velocity east, north, m/s), or None while it is unknown."""
        with self._lock:
            est = self.wind.estimate(self._s["time_s"])
            return None if est is None else est.en

    def get(self, key: str) -> Any:
        with self._lock:
            return copy.deepcopy(self._s.get(key))

    def track_dict(self, since_s: float | None = None) -> dict[str, Any]:
        with self._lock:
            return self.track.to_dict(since_s)

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            return copy.deepcopy(self._s)
