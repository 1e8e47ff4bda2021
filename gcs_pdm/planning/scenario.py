"""A planning scenario: where the vehicle is, what it still may visit, and what it must not exceed.

This is the one format the planner reads — from a JSON file (``gcs-pdm plan``) or built by the
service from live state (:meth:`Scenario.from_live`). Positions are local ENU metres about the home
point (east, north); altitudes are metres above home, as in a ``*_RELATIVE_ALT`` mission. A waypoint
given in degrees is converted with an equirectangular projection about home, which is accurate to
well under a metre over the few kilometres a small UAV flies. The format is documented in
docs/planning.md.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from gcs_pdm.geo import enu_from_geodetic
from gcs_pdm.models import kernel
from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES, ParameterSet, builtin
from gcs_pdm.models.powertrain import DescribedMotorFault, Limits, MotorFault, PowertrainState, fault_vector
from gcs_pdm.models.wind import wind_from_speed_direction
from gcs_pdm.vehicle.description import VehicleDescription
from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

FORMAT_VERSION = 1


class ScenarioError(ValueError):
    """A scenario that cannot be planned; the message names the offending field."""


@dataclass(frozen=True)
class Waypoint:
    """A place worth visiting: position, flight parameters Γ (altitude, airspeed) and its reward."""

    number: int
    east_m: float
    north_m: float
    alt_m: float
    reward: float
    airspeed_mps: float = 25.0

    def __post_init__(self) -> None:
        for name in ("east_m", "north_m", "alt_m", "reward", "airspeed_mps"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ScenarioError(f"waypoint {self.number}.{name}: expected a finite number, got {v!r}")
        if self.reward < 0:
            raise ScenarioError(f"waypoint {self.number}.reward: must be >= 0, got {self.reward}")
        if self.airspeed_mps <= 0:
            raise ScenarioError(f"waypoint {self.number}.airspeed_mps: must be > 0, got {self.airspeed_mps}")


@dataclass(frozen=True)
class Home:
    """Take-off and landing site; the origin of the local frame."""

    lat_deg: float = 37.0870
    lon_deg: float = -76.3800
    ground_alt_m: float = 0.0     # above sea level, for air density
    ground_temp_c: float = 20.0   # ambient at the ground; aloft follows the standard lapse rate
    landing_east_m: float = 0.0
    landing_north_m: float = 0.0


@dataclass(frozen=True)
class StartState:
    """The vehicle now: position, the time on the vehicle's clock and the powertrain state.

    The powertrain is given either as full kernel pack states (only meaningful with the parameter
    set that produced them) or as per-pack SoC and temperatures, from which a settled state is
    built for whichever parameter set plans (the R–C pairs settled at ``pack_current_a``). A
    scenario file's start is the paper aircraft's (four packs, two motors); the service records a
    described vehicle's live state here too, one row per pack and motor of its description.
    """

    east_m: float
    north_m: float
    alt_m: float
    pack_temp_c: tuple[float, ...]
    motor_temp_c: tuple[float, ...]
    pack_soc: tuple[float, ...] | None = None
    pack_state: tuple[tuple[float, ...], ...] | None = None
    #: the packs' present currents (empty: 0 A each)
    pack_current_a: tuple[float, ...] = ()
    time_s: float = 0.0

    def __post_init__(self) -> None:
        n = len(self.pack_temp_c)
        if n < 1:
            raise ScenarioError("start.pack_temp_c: expected one value per pack, got none")
        if len(self.motor_temp_c) < 1:
            raise ScenarioError("start.motor_temp_c: expected one value per motor, got none")
        if self.pack_current_a and len(self.pack_current_a) != n:
            raise ScenarioError(f"start.pack_current_a: expected {n} values (one per pack), "
                                f"got {len(self.pack_current_a)}")
        if self.pack_soc is None and self.pack_state is None:
            raise ScenarioError("start: give pack_soc or pack_state")
        if self.pack_soc is not None:
            if len(self.pack_soc) != n:
                raise ScenarioError(f"start.pack_soc: expected {n} values (one per pack), got {len(self.pack_soc)}")
            if any(not 0.0 <= s <= 1.0 for s in self.pack_soc):
                raise ScenarioError(f"start.pack_soc: values must be within [0, 1], got {self.pack_soc}")
        if self.pack_state is not None and np.shape(self.pack_state) != (n, kernel.N_PACK_STATE):
            raise ScenarioError(f"start.pack_state: expected shape ({n}, {kernel.N_PACK_STATE}), "
                                f"got {np.shape(self.pack_state)}")

    @property
    def n_packs(self) -> int:
        return len(self.pack_temp_c)

    def powertrain(self, params: ParameterSet) -> PowertrainState:
        """The start as the kernel's state of the paper's four-pack layout under ``params``."""
        if self.n_packs != len(PACK_NAMES) or len(self.motor_temp_c) != len(MOTOR_NAMES):
            raise ScenarioError(f"start: {self.n_packs} pack(s) and {len(self.motor_temp_c)} motor(s); the "
                                f"scenario's own vehicle (the paper's aircraft) has {len(PACK_NAMES)} and "
                                f"{len(MOTOR_NAMES)}: plan it for its vehicle description (--vehicle)")
        if self.pack_state is not None:
            x = np.array(self.pack_state, dtype=np.float64)
        else:
            current = self.pack_current_a or (0.0,) * self.n_packs
            x = kernel.initial_pack_state(params.pack_matrix(), np.array(self.pack_soc), np.array(self.pack_temp_c),
                                          np.array(current))
        x[:, kernel.S_T] = self.pack_temp_c
        return PowertrainState(pack_state=x, motor_temp_c=np.array(self.motor_temp_c, dtype=np.float64))


@dataclass(frozen=True)
class PlanLimits:
    """The kernel's failure limits plus the charge every pack must still hold on landing."""

    pack_cutoff_v: float = Limits.pack_cutoff_v
    pack_max_temp_c: float = Limits.pack_max_temp_c
    motor_max_temp_c: float = Limits.motor_max_temp_c
    landing_reserve_soc: float = 0.0

    def kernel_limits(self) -> Limits:
        return Limits(self.pack_cutoff_v, self.pack_max_temp_c, self.motor_max_temp_c)


def named_motor_faults(faults: Sequence[MotorFault], motor_names: Sequence[str]) -> dict[str, float]:
    """Each motor's power-loss magnitude, by name (several faults on one motor compound, as
    ``powertrain.fault_vector`` has them); a fault on a motor the vehicle lacks is an error."""
    return dict(zip(motor_names, (float(m) for m in fault_vector(list(faults), tuple(motor_names)))))


@dataclass(frozen=True)
class FlownVehicle:
    """What a planner's simulator flies: a vehicle description, a parameter set flown over its
    values (None: the description's own), its powertrain state now (None: full packs at the
    ground temperature), its motors' power losses by name, and limits for every pack and motor
    with the landing reserve (None: the description's per pack and motor, and its reserve).
    ``VehicleSimulator(scenario, **flown.simulator_args())`` flies it."""

    vehicle: VehicleDescription
    params: ParameterSet | None = None
    state: PowertrainState | None = None
    motor_faults: Mapping[str, float] = field(default_factory=dict)
    limits: "PlanLimits | None" = None

    def simulator_args(self) -> dict[str, Any]:
        return {"vehicle": self.vehicle, "params": self.params, "state": self.state,
                "motor_faults": dict(self.motor_faults), "limits": self.limits}


@dataclass(frozen=True)
class Scenario:
    name: str
    home: Home
    start: StartState
    waypoints: tuple[Waypoint, ...]
    faults: tuple[MotorFault, ...] = ()
    limits: PlanLimits = field(default_factory=PlanLimits)
    #: a built-in set name, or an inline parameter set (``ParameterSet.to_dict`` form)
    params: str | Mapping[str, Any] = "paper_si"
    reward_collected: float = 0.0
    #: waypoints of the original mission already flown (for reports only)
    visited: tuple[int, ...] = ()
    description: str = ""
    return_airspeed_mps: float = 25.0
    max_climb_rate_mps: float = 5.0
    #: the wind the legs are flown in, m/s, the velocity of the air (the direction it blows towards)
    wind_east_mps: float = 0.0
    wind_north_mps: float = 0.0

    def __post_init__(self) -> None:
        numbers = [w.number for w in self.waypoints]
        if len(set(numbers)) != len(numbers):
            raise ScenarioError(f"waypoints: numbers must be unique, got {numbers}")
        if self.return_airspeed_mps <= 0 or self.max_climb_rate_mps <= 0:
            raise ScenarioError("return_airspeed_mps and max_climb_rate_mps must be > 0")
        if not (math.isfinite(self.wind_east_mps) and math.isfinite(self.wind_north_mps)):
            raise ScenarioError("wind: east_mps and north_mps must be finite")

    @property
    def wind_en_mps(self) -> tuple[float, float]:
        return (float(self.wind_east_mps), float(self.wind_north_mps))

    def with_wind(self, east_mps: float, north_mps: float) -> "Scenario":
        return _replace(self, wind_east_mps=float(east_mps), wind_north_mps=float(north_mps))

    # ---- parameters ----------------------------------------------------------------------------
    def parameter_set(self) -> ParameterSet:
        if isinstance(self.params, str):
            try:
                return builtin(self.params)
            except KeyError as exc:
                raise ScenarioError(f"params: {exc.args[0]}") from None
        return ParameterSet.from_dict(self.params)

    def flown_vehicle(self, params: ParameterSet | None = None) -> FlownVehicle:
        """The vehicle a scenario file describes: the paper's aircraft, the ``edge540`` preset, on
        ``params`` (default the scenario's own set), from its start, with its faults (named by the
        paper's motors) and its limits and landing reserve for every pack and motor."""
        ps = params if params is not None else self.parameter_set()
        vehicle = PRESETS[DEFAULT_PRESET]
        state = self.start.powertrain(ps)
        try:
            faults = named_motor_faults(self.faults, vehicle.motor_names)
        except ValueError as exc:
            raise ScenarioError(f"faults: {exc}") from None
        return FlownVehicle(vehicle=vehicle, params=ps, state=state, motor_faults=faults, limits=self.limits)

    def subset(self, numbers: Sequence[int], name: str | None = None) -> "Scenario":
        keep = set(numbers)
        return _replace(self, name=name or self.name, waypoints=tuple(w for w in self.waypoints if w.number in keep))

    def with_params(self, params: str | ParameterSet) -> "Scenario":
        return _replace(self, params=params if isinstance(params, str) else params.to_dict())

    # ---- construction from live state --------------------------------------------------------
    @classmethod
    def from_live(cls, state: PowertrainState, faults: Sequence[MotorFault], waypoints: Sequence[Waypoint],
                  position_enu: tuple[float, float, float], home: Home, limits: PlanLimits | None = None, *,
                  params: ParameterSet | None = None, name: str = "live", time_s: float = 0.0,
                  reward_collected: float = 0.0, visited: Sequence[int] = (),
                  wind_en_mps: tuple[float, float] = (0.0, 0.0)) -> "Scenario":
        """The scenario the service builds: the estimated state (full pack states, one row per pack
        of the vehicle flown) and ``params``, the set they were estimated under (None: the
        vehicle's description values; the record keeps the default set's name)."""
        x = np.asarray(state.pack_state, dtype=np.float64)
        start = StartState(east_m=position_enu[0], north_m=position_enu[1], alt_m=position_enu[2],
                           pack_temp_c=tuple(float(t) for t in x[:, kernel.S_T]),
                           motor_temp_c=tuple(float(t) for t in state.motor_temp_c),
                           pack_state=tuple(tuple(float(v) for v in row) for row in x), time_s=time_s)
        return cls(name=name, home=home, start=start, waypoints=tuple(waypoints), faults=tuple(faults),
                   limits=limits or PlanLimits(), params=params.to_dict() if params is not None else "paper_si",
                   reward_collected=reward_collected, visited=tuple(visited), wind_east_mps=float(wind_en_mps[0]),
                   wind_north_mps=float(wind_en_mps[1]))

    # ---- JSON ----------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        s = self.start
        start: dict[str, Any] = {"east_m": s.east_m, "north_m": s.north_m, "alt_m": s.alt_m, "time_s": s.time_s,
                                 "pack_temp_c": list(s.pack_temp_c), "motor_temp_c": list(s.motor_temp_c),
                                 "pack_current_a": list(s.pack_current_a or (0.0,) * s.n_packs)}
        if s.pack_soc is not None:
            start["pack_soc"] = list(s.pack_soc)
        if s.pack_state is not None:
            start["pack_state"] = [list(r) for r in s.pack_state]
        h = self.home
        return {
            "format": "gcs-pdm-scenario", "version": FORMAT_VERSION,
            "name": self.name, "description": self.description,
            "home": {"lat_deg": h.lat_deg, "lon_deg": h.lon_deg, "ground_alt_m": h.ground_alt_m,
                     "ground_temp_c": h.ground_temp_c, "landing_east_m": h.landing_east_m,
                     "landing_north_m": h.landing_north_m},
            "start": start,
            "waypoints": [{"number": w.number, "east_m": w.east_m, "north_m": w.north_m, "alt_m": w.alt_m,
                           "airspeed_mps": w.airspeed_mps, "reward": w.reward} for w in self.waypoints],
            "faults": [{"motor": f.motor, "magnitude": f.magnitude, "kind": f.kind} for f in self.faults],
            "limits": {"pack_cutoff_v": self.limits.pack_cutoff_v, "pack_max_temp_c": self.limits.pack_max_temp_c,
                       "motor_max_temp_c": self.limits.motor_max_temp_c,
                       "landing_reserve_soc": self.limits.landing_reserve_soc},
            "params": self.params if isinstance(self.params, str) else dict(self.params),
            "reward_collected": self.reward_collected, "visited": list(self.visited),
            "return_airspeed_mps": self.return_airspeed_mps, "max_climb_rate_mps": self.max_climb_rate_mps,
            # calm air is the default and is left out (scenario files written before wind stay as they were)
            **({"wind": {"east_mps": self.wind_east_mps, "north_mps": self.wind_north_mps}}
               if self.wind_en_mps != (0.0, 0.0) else {}),
        }

    def to_json(self, **kw: Any) -> str:
        return json.dumps(self.to_dict(), **kw)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Scenario":
        if not isinstance(data, Mapping):
            raise ScenarioError("scenario: expected a JSON object")
        if data.get("format", "gcs-pdm-scenario") != "gcs-pdm-scenario":
            raise ScenarioError(f"format: expected 'gcs-pdm-scenario', got {data.get('format')!r}")
        if int(data.get("version", FORMAT_VERSION)) > FORMAT_VERSION:
            raise ScenarioError(f"version: this gcs-pdm reads scenario format {FORMAT_VERSION}, "
                                f"got {data.get('version')!r}")
        try:
            hd = dict(data.get("home", {}))
            home = Home(**{k: float(v) for k, v in hd.items() if k in Home.__dataclass_fields__})
            unknown = set(hd) - set(Home.__dataclass_fields__)
            if unknown:
                raise ScenarioError(f"home: unknown field(s) {sorted(unknown)}")
            sd = data["start"]
            if "lat_deg" in sd:
                east, north = enu_from_geodetic(float(sd["lat_deg"]), float(sd["lon_deg"]), home.lat_deg, home.lon_deg)
            else:
                east, north = float(sd["east_m"]), float(sd["north_m"])
            start = StartState(
                east_m=east, north_m=north, alt_m=float(sd["alt_m"]), time_s=float(sd.get("time_s", 0.0)),
                pack_temp_c=tuple(float(v) for v in sd["pack_temp_c"]),
                motor_temp_c=tuple(float(v) for v in sd["motor_temp_c"]),
                pack_soc=tuple(float(v) for v in sd["pack_soc"]) if "pack_soc" in sd else None,
                pack_state=tuple(tuple(float(v) for v in r) for r in sd["pack_state"]) if "pack_state" in sd else None,
                pack_current_a=tuple(float(v) for v in sd.get("pack_current_a", ())))
            wps = []
            for i, wd in enumerate(data["waypoints"]):
                number = int(wd.get("number", i + 1))
                if "lat_deg" in wd:
                    e, n = enu_from_geodetic(float(wd["lat_deg"]), float(wd["lon_deg"]), home.lat_deg, home.lon_deg)
                elif "east_m" in wd and "north_m" in wd:
                    e, n = float(wd["east_m"]), float(wd["north_m"])
                else:
                    raise ScenarioError(f"waypoints[{i}]: give lat_deg/lon_deg or east_m/north_m")
                wps.append(Waypoint(number=number, east_m=e, north_m=n, alt_m=float(wd["alt_m"]),
                                    reward=float(wd["reward"]), airspeed_mps=float(wd.get("airspeed_mps", 25.0))))
            # any motor's name: a plan record's faults are its vehicle's (flown_vehicle checks the paper's)
            faults = tuple((MotorFault if str(f["motor"]) in MOTOR_NAMES else DescribedMotorFault)(
                motor=str(f["motor"]), magnitude=float(f["magnitude"]), kind=str(f.get("kind", "motor_power_loss")))
                for f in data.get("faults", ()))
            ld = dict(data.get("limits", {}))
            unknown = set(ld) - set(PlanLimits.__dataclass_fields__)
            if unknown:
                raise ScenarioError(f"limits: unknown field(s) {sorted(unknown)}")
            limits = PlanLimits(**{k: float(v) for k, v in ld.items()})
            params = data.get("params", "paper_si")
            if not isinstance(params, (str, Mapping)):
                raise ScenarioError("params: expected a built-in set name or an inline parameter set")
            return cls(name=str(data.get("name", "scenario")), home=home, start=start, waypoints=tuple(wps),
                       faults=faults, limits=limits, params=params,
                       reward_collected=float(data.get("reward_collected", 0.0)),
                       visited=tuple(int(v) for v in data.get("visited", ())),
                       description=str(data.get("description", "")),
                       return_airspeed_mps=float(data.get("return_airspeed_mps", 25.0)),
                       max_climb_rate_mps=float(data.get("max_climb_rate_mps", 5.0)),
                       **_wind_fields(data.get("wind")))
        except KeyError as exc:
            raise ScenarioError(f"scenario: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ScenarioError):
                raise
            raise ScenarioError(f"scenario: {exc}") from None

    @classmethod
    def from_json(cls, text: str) -> "Scenario":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ScenarioError(f"scenario: not JSON: {exc}") from None
        return cls.from_dict(data)


def _wind_fields(wind: Any) -> dict[str, float]:
    """``"wind": {"east_mps": e, "north_mps": n}`` (the air's velocity) or
    ``{"speed_mps": s, "from_deg": d}`` (where it blows from, as a forecast or ArduPilot's WIND says it)."""
    if wind is None:
        return {}
    if not isinstance(wind, Mapping):
        raise ScenarioError("wind: expected {east_mps, north_mps} or {speed_mps, from_deg}")
    keys = set(wind)
    if keys == {"east_mps", "north_mps"}:
        return {"wind_east_mps": float(wind["east_mps"]), "wind_north_mps": float(wind["north_mps"])}
    if keys == {"speed_mps", "from_deg"}:
        east, north = wind_from_speed_direction(float(wind["speed_mps"]), float(wind["from_deg"]))
        return {"wind_east_mps": east, "wind_north_mps": north}
    raise ScenarioError(f"wind: expected {{east_mps, north_mps}} or {{speed_mps, from_deg}}, got {sorted(keys)}")


def _replace(s: Scenario, **changes: Any) -> Scenario:
    import dataclasses

    return dataclasses.replace(s, **changes)
