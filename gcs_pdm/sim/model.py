"""The simulated vehicle as a pure, steppable model: mission, modes, kinematics and the true powertrain.

``VehicleModel.step(dt)`` advances the aircraft by one physics tick and returns what happened
(items reached, faults switched on, failures) as :class:`Event` objects. No sockets, threads or
clocks: the MAVLink shell (``gcs_pdm.sim.vehicle``) and the offline recorder (``gcs_pdm.sim.record``)
drive it, and tests fly whole missions with it directly.

Truth: the vehicle description's packs and motors (the paper's aircraft is the ``edge540`` preset,
the default) run through ``topology.simulate_vehicle`` one tick at a time, carrying
``final_pack_state``/``final_motor_temp`` forward, with the motor faults that have triggered so far.
Their values are a hidden truth parameter set (``gcs_pdm.sim.truth``, optionally degraded) matched to
the packs by name, or the description's own values (``vehicle_config``). The limits decide a failure;
the aircraft then loses its propulsion and glides to the ground.
While disarmed the packs and motors only rest (``simulate_packs``/``simulate_motor_thermal`` at
zero current).

Mission conventions (ArduPlane-like, docs/sim.md): item 0 is home and is never flown; AUTO starts
at item 1; TAKEOFF, WAYPOINT, LAND, RETURN_TO_LAUNCH are flown, DO_CHANGE_SPEED sets the airspeed;
after the last item the vehicle returns to launch and lands.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from gcs_pdm.geo import enu_from_geodetic, geodetic_from_enu
from gcs_pdm.missions import (MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_TAKEOFF,
                              MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT, MissionItem)
from gcs_pdm.models import kernel
from gcs_pdm.models.params import ParameterSet
from gcs_pdm.models.powertrain import (EDGE_540, Airframe, Limits, air_density, ambient_temperature, shaft_power,
                                       shaft_rpm)
from gcs_pdm.models.topology import simulate_vehicle, simulate_vehicle_extended
from gcs_pdm.sim import flight
from gcs_pdm.sim.faults import Degradation, FaultSpec, apply_degradation
from gcs_pdm.sim.flight import FlightLimits, Kinematics
from gcs_pdm.sim.truth import DEFAULT_TRUTH_SEED, true_parameters

log = logging.getLogger(__name__)

MAV_CMD_DO_CHANGE_SPEED = 178
NAV_COMMANDS = frozenset({MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_LAND, MAV_CMD_NAV_TAKEOFF})
SUPPORTED_COMMANDS = NAV_COMMANDS | {MAV_CMD_DO_CHANGE_SPEED}

# ArduPlane custom modes (the ones this vehicle flies).
MODE_MANUAL = "MANUAL"
MODE_AUTO = "AUTO"
MODE_RTL = "RTL"
PLANE_MODES = {"MANUAL": 0, "AUTO": 10, "RTL": 11}
# ArduCopter's numbers for the same behaviours (STABILIZE stands for MANUAL)
COPTER_MODES = {"MANUAL": 0, "AUTO": 3, "RTL": 6}

# severities (MAV_SEVERITY)
SEVERITY_EMERGENCY = 0
SEVERITY_CRITICAL = 2
SEVERITY_ERROR = 3
SEVERITY_WARNING = 4
SEVERITY_INFO = 6


def _paper_aircraft():
    from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

    return PRESETS[DEFAULT_PRESET]


@dataclass(frozen=True)
class SimConfig:
    """Everything that makes one simulated flight; the same config (and seed) flies the same flight."""

    seed: int = 0  # sensor noise and drop-outs
    #: the hidden truth: ``params`` if given, else ``true_parameters(truth_seed)``, else (both None,
    #: as ``vehicle_config`` sets them) the description's own values; matched to its packs by name
    truth_seed: int | None = DEFAULT_TRUTH_SEED
    params: ParameterSet | None = None
    home_lat_deg: float = 37.0870
    home_lon_deg: float = -76.3800
    home_alt_m: float = 0.0  # above sea level
    ground_temp_c: float = 20.0
    initial_soc: float | tuple[float, float, float, float] = 1.0
    faults: tuple[FaultSpec, ...] = ()
    degradations: tuple[Degradation, ...] = ()  # of the hidden truth's packs
    #: one limit for every pack and motor (a scenario's); None: the description's, per pack and motor
    limits: Limits | None = None
    airframe: Airframe = EDGE_540  # a fixed wing's drag polar (vehicle_config: the description's)
    flight_limits: FlightLimits = FlightLimits()
    wind_en_mps: tuple[float, float] = (0.0, 0.0)  # mean wind, the air's velocity east, north
    #: gusts: a first-order Gauss-Markov process on each wind component, 1-sigma m/s and time
    #: constant s (seeded with ``seed``); 0 = a steady wind
    wind_gust_mps: float = 0.0
    wind_gust_tau_s: float = 5.0
    cruise_airspeed_mps: float = 25.0
    physics_dt_s: float = 0.1
    mission: tuple[MissionItem, ...] = ()
    #: arm and fly AUTO as soon as a mission is loaded (after ``start_delay_s`` on the ground)
    autostart: bool = True
    start_delay_s: float = 5.0
    fault_drag: float = 0.1  # kernel: drag of a faulted rotor that still spins
    #: the ``VehicleDescription`` flown: its packs, motors, buses and telemetry layout (default: the
    #: paper's aircraft, ``edge540``; ``vehicle_config`` builds a config for any other)
    vehicle: object = field(default_factory=_paper_aircraft)
    #: a described vehicle's packs rest on their chemistry's curve (``sim.pack_curves``), not on
    #: their parameter set's linear one: a LiPo at 70 % shows what a LiPo at 70 % shows
    chemistry_curves: bool = False

    def truth(self) -> ParameterSet | None:
        """The hidden truth parameter set, degraded; None: the description's own values are the truth."""
        if self.params is None and self.truth_seed is None:
            if self.degradations:
                raise ValueError("degradations: they degrade a truth parameter set's packs; this config flies "
                                 "its description's own values (give params or truth_seed)")
            return None
        base = self.params if self.params is not None else true_parameters(self.truth_seed)
        return apply_degradation(base, self.degradations)

    def true_inputs(self):
        """The description's model inputs with the truth's values: each pack's by its name, every
        motor the set's one motor type; the limits ``limits`` if given."""
        from gcs_pdm.vehicle.model_inputs import model_inputs

        inputs = model_inputs(self.vehicle, self.truth())
        if self.limits is not None:
            lim = self.limits
            inputs = replace(inputs, pack_cutoff_v=np.full(inputs.n_packs, float(lim.pack_cutoff_v)),
                             pack_max_temp_c=np.full(inputs.n_packs, float(lim.pack_max_temp_c)),
                             motor_max_temp_c=np.full(inputs.n_motors, float(lim.motor_max_temp_c)))
        return inputs


def vehicle_config(desc, **kw) -> SimConfig:
    """A ``SimConfig`` flying ``desc`` (a ``VehicleDescription``): its airframe, cruise speed and
    climb rate; a multirotor lifts off and lands vertically (no ground roll, a steep approach)."""
    from gcs_pdm.vehicle.model_inputs import powertrain_airframe

    airframe = powertrain_airframe(desc)
    if desc.airframe.type == "multirotor":
        limits = FlightLimits(max_climb_mps=desc.climb_rate_mps, max_sink_mps=desc.climb_rate_mps,
                              rotate_airspeed_mps=0.0, takeoff_climb_mps=desc.climb_rate_mps,
                              acceptance_radius_m=5.0, glide_slope_deg=60.0, max_bank_deg=25.0)
    else:
        limits = FlightLimits(max_climb_mps=desc.climb_rate_mps,
                              rotate_airspeed_mps=desc.airframe.stall_airspeed + 2.0)
    kw.setdefault("truth_seed", None)  # the description's own values are the truth
    return SimConfig(vehicle=desc, airframe=airframe, flight_limits=limits,
                     cruise_airspeed_mps=desc.cruise_speed_mps, **kw)


@dataclass(frozen=True)
class Event:
    """Something the vehicle reports (or the truth records) at a simulated time."""

    time_s: float
    kind: str  # "reached", "current", "statustext", "fault", "failure", "landed", "armed", "disarmed", "mode"
    seq: int = -1
    text: str = ""
    severity: int = SEVERITY_INFO


@dataclass(frozen=True)
class TruthState:
    """A snapshot of everything true about the vehicle (SI units, °C)."""

    time_s: float
    armed: bool
    mode: str
    on_ground: bool
    landed: bool
    failed: bool
    failure: str
    current_seq: int
    mission_count: int
    mission_state: int  # MISSION_STATE: 1 none, 2 not started, 3 active, 5 complete
    east_m: float
    north_m: float
    alt_m: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    heading_deg: float
    airspeed_mps: float
    groundspeed_mps: float
    climb_mps: float
    vel_north_mps: float
    vel_east_mps: float
    shaft_power_w: float
    rpm: float
    ambient_c: float
    air_density: float
    pack_voltage_v: np.ndarray  # (4,) PACK_NAMES order
    pack_current_a: np.ndarray
    pack_temp_c: np.ndarray
    pack_soc: np.ndarray
    pack_charge_c: np.ndarray  # drawn since boot
    pack_energy_j: np.ndarray
    motor_current_a: np.ndarray  # (2,) fwd, aft
    motor_temp_c: np.ndarray
    motor_voltage_v: np.ndarray  # bus voltage of each motor's string
    fault: np.ndarray  # (2,) magnitudes in force
    energy_j: float  # electrical energy drawn by the motors
    distance_m: float  # flown over ground
    #: the telemetry layout (a vehicle description's; these defaults are the paper's aircraft)
    pack_ids: tuple[int, ...] = (0, 1, 2, 3)
    pack_reports_temperature: tuple[bool, ...] = (True, True, True, True)
    esc_index: tuple[int, ...] = (0, 1)
    motor_readings: tuple[tuple[bool, bool, bool], ...] = ((True, True, True), (True, True, True))
    motor_charge_c: np.ndarray | None = None  # per motor, drawn since boot (None: its string's first pack)
    mav_type: int = 1
    multirotor: bool = False
    #: the wind in force (mean plus gust), the air's velocity east and north, m/s
    wind_east_mps: float = 0.0
    wind_north_mps: float = 0.0


class VehicleModel:
    """The steppable simulated vehicle (pure core of the MAVLink vehicle)."""

    def __init__(self, config: SimConfig):
        self.config = config
        from gcs_pdm.vehicle.model_inputs import shaft_power_model

        #: the truth parameter set (None: the description's own values)
        self.params = config.truth()
        if config.chemistry_curves and self.params is not None:
            raise ValueError("chemistry_curves: only a described vehicle's own packs (vehicle_config) name a chemistry")
        self._inputs = config.true_inputs()
        self._pack_matrix = self._inputs.pack_matrix
        self._motor_rows = self._inputs.motor_matrix
        self._topology = self._inputs.topology
        self._multirotor = config.vehicle.airframe.type == "multirotor"
        self._telemetry_layout = _telemetry_layout(config.vehicle)
        # per bus its packs (in order) and whether they are in parallel, per motor its bus: each
        # snapshot's bus voltages in plain Python (a state() per telemetry message)
        inputs = self._inputs
        self._bus_packs = [[int(b) for b in np.flatnonzero(inputs.bus_of_pack == k)]
                           for k in range(len(inputs.bus_parallel))]
        self._bus_parallel = [bool(x) for x in inputs.bus_parallel]
        self._bus_of_motor = [int(k) for k in inputs.bus_of_motor]
        # a fixed wing's power from the configured drag polar (vehicle_config sets the description's)
        self._vehicle_power = (shaft_power_model(config.vehicle) if self._multirotor
                               else lambda v, climb, rho: shaft_power(v, climb, rho, config.airframe))
        self.pack_names, self.motor_names = self._inputs.pack_names, self._inputs.motor_names
        n_packs, n_motors = len(self.pack_names), len(self.motor_names)
        self.time_s = 0.0
        self.kin = Kinematics()
        self.mode = MODE_MANUAL
        self.armed = False
        self.landed = False
        self.failed = False
        self.failure = ""
        self.mission: list[MissionItem] = []
        self.current_seq = 0
        self.mission_complete = False
        self.target_airspeed = config.cruise_airspeed_mps
        self.fault = np.zeros(n_motors)
        self.fault_log: list[dict] = []  # one entry per fault that triggered
        self.reached_log: list[tuple[int, float]] = []
        #: the items reached, as they were then (a new upload renumbers the seqs; the demo's summary
        #: tells the waypoints flown by position)
        self.reached_items: list[MissionItem] = []
        self._pending_faults = list(config.faults)
        self._armed_time = 0.0
        self._last_reached = -1
        self._leg_start: tuple[float, float] | None = None
        self._airborne_once = False
        self._ready_at: float | None = None
        self._rtl_landing = False
        self._takeoff_heading: float | None = None
        self._gust_en = (0.0, 0.0)
        self._gust_rng: np.random.Generator | None = None
        soc = np.broadcast_to(np.asarray(config.initial_soc, dtype=float), (n_packs,)).copy()
        if np.any((soc <= 0) | (soc > 1)):
            raise ValueError(f"initial_soc: must be within (0, 1], got {config.initial_soc!r}")
        self.initial_soc = soc
        self._ext_matrix = None
        if config.chemistry_curves:
            from gcs_pdm.sim.pack_curves import chemistry_curve_pack, rest_voltage

            self._ext_matrix = np.stack([chemistry_curve_pack(row, spec.chemistry, spec.cells_series)
                                         for row, spec in zip(self._pack_matrix, config.vehicle.packs)])
            self.pack_state = kernel.initial_extended_state(self._ext_matrix, soc, config.ground_temp_c)
            self._pack_voltage = rest_voltage(self._ext_matrix, self.pack_state, config.ground_temp_c)
        else:
            self.pack_state = kernel.initial_pack_state(self._pack_matrix, soc, config.ground_temp_c)
        self.motor_temp = np.full(n_motors, float(config.ground_temp_c))
        self.pack_current = np.zeros(n_packs)
        self.motor_current = np.zeros(n_motors)
        self.pack_charge = np.zeros(n_packs)
        self.motor_charge = np.zeros(n_motors)
        self.pack_energy = np.zeros(n_packs)
        self.energy_j = 0.0
        self.distance_m = 0.0
        self.shaft_power_w = 0.0
        self.events: list[Event] = []
        if config.mission:
            self.set_mission(list(config.mission))

    # ---- mission store (the mission protocol server calls these) --------------------------------

    def set_mission(self, items: list[MissionItem], current: int | None = None) -> None:
        """Replace the mission. On the ground the vehicle starts again at item 1; in flight it keeps
        its current index (as ArduPilot does) unless ``current`` names another item, and re-targets
        whatever item now has that index."""
        items = [it if it.seq == i else replace(it, seq=i) for i, it in enumerate(items)]
        self.mission = items
        flying = self.armed and not self.kin.on_ground
        if current is not None and 1 <= current < len(items):
            seq = current
        elif not flying or self.mission_complete:
            seq = 1 if len(items) > 1 else 0
        else:
            seq = self.current_seq if 1 <= self.current_seq < len(items) else (1 if len(items) > 1 else 0)
        self.mission_complete = False  # the mode stays: a vehicle in RTL keeps returning until set to AUTO
        self._set_current(seq, reset_leg=True)
        log.info("mission of %d items loaded; current item %d", len(items), seq)

    def clear_mission(self) -> None:
        self.mission = []
        self.current_seq = 0
        self.mission_complete = False
        if self.armed and not self.kin.on_ground and self.mode == MODE_AUTO:
            self.set_mode(MODE_RTL)
        self._emit("current", seq=0)

    def set_current(self, seq: int) -> bool:
        if not 0 <= seq < len(self.mission):
            return False
        if seq == 0:
            seq = 1 if len(self.mission) > 1 else 0  # ArduPilot: item 0 (home) restarts the mission
        self.mission_complete = False
        self._set_current(seq, reset_leg=True)
        return True

    def _set_current(self, seq: int, reset_leg: bool) -> None:
        self.current_seq = seq
        if reset_leg:
            self._leg_start = (self.kin.east_m, self.kin.north_m)
        self._emit("current", seq=seq)

    # ---- modes and arming ------------------------------------------------------------------

    def set_mode(self, mode: str) -> bool:
        if mode not in PLANE_MODES:
            return False
        if mode != self.mode:
            self.mode = mode
            self._rtl_landing = False
            if mode == MODE_RTL:
                self._leg_start = (self.kin.east_m, self.kin.north_m)
            self._emit("mode", text=mode)
            self._emit("statustext", text=f"Mode {mode}", severity=SEVERITY_INFO)
        return True

    def arm(self) -> tuple[bool, str]:
        if self.failed:
            return False, "Arm: vehicle has failed"
        if self.armed:
            return True, ""
        self.armed = True
        self.landed = False
        self._armed_time = 0.0
        self._emit("armed")
        self._emit("statustext", text="Throttle armed", severity=SEVERITY_INFO)
        return True, ""

    def disarm(self, force: bool = False) -> tuple[bool, str]:
        if not self.kin.on_ground and not force:
            return False, "Disarm: vehicle is flying"
        if self.armed:
            self.armed = False
            self._emit("disarmed")
            self._emit("statustext", text="Throttle disarmed", severity=SEVERITY_INFO)
        return True, ""

    def start_mission(self) -> tuple[bool, str]:
        if len(self.mission) < 2:
            return False, "Mission start: no mission"
        if self.failed:
            return False, "Mission start: vehicle has failed"
        ok, why = self.arm()
        if not ok:
            return ok, why
        self.mission_complete = False
        self.landed = False
        if self.kin.on_ground:
            self._set_current(1, reset_leg=True)
        self.set_mode(MODE_AUTO)
        return True, ""

    def inject_fault(self, motor: str, magnitude: float, reason: str = "injected") -> None:
        """Switch a motor power loss on now (it compounds with any earlier fault on that motor)."""
        i = self.motor_names.index(motor)
        self.fault[i] = 1.0 - (1.0 - self.fault[i]) * (1.0 - float(magnitude))
        entry = {"motor": motor, "magnitude": float(magnitude), "time_s": self.time_s, "reason": reason,
                 "current_seq": self.current_seq, "last_reached_seq": self._last_reached,
                 "east_m": self.kin.east_m, "north_m": self.kin.north_m, "alt_m": self.kin.alt_m}
        self.fault_log.append(entry)
        self._emit("fault", text=f"motor:{motor}:{magnitude:g} ({reason})")
        log.info("fault at %.1f s: %s motor loses %.0f%% (%s)", self.time_s, motor, 100 * magnitude, reason)

    # ---- the step -----------------------------------------------------------------------------

    def _emit(self, kind: str, seq: int = -1, text: str = "", severity: int = SEVERITY_INFO) -> None:
        self.events.append(Event(self.time_s, kind, seq, text, severity))

    def take_events(self) -> list[Event]:
        out, self.events = self.events, []
        return out

    @property
    def finished(self) -> bool:
        """On the ground after a flight (landed or failed), nothing left to fly."""
        if not self.kin.on_ground or self.armed:
            return False
        return self._airborne_once or self.failed

    def step(self, dt: float | None = None) -> list[Event]:
        """Advance the vehicle by ``dt`` seconds (default: the configured physics tick)."""
        dt = self.config.physics_dt_s if dt is None else float(dt)
        if not dt > 0.0:
            raise ValueError(f"dt: must be > 0 s, got {dt!r}")
        self._autostart()
        self._gust(dt)
        power, motors_on = self._fly(dt)
        self.time_s += dt
        if self.armed:
            self._armed_time += dt
        self._check_time_faults()
        self._powertrain(dt, power, motors_on)
        self.distance_m += self.kin.groundspeed_mps * dt
        return self.take_events()

    @property
    def wind_en(self) -> tuple[float, float]:
        """The wind in force now: the mean plus the gust."""
        we, wn = self.config.wind_en_mps
        return we + self._gust_en[0], wn + self._gust_en[1]

    def _gust(self, dt: float) -> None:
        c = self.config
        if c.wind_gust_mps <= 0.0:
            return
        if self._gust_rng is None:
            # its own stream, so a steady wind's flight draws exactly what it did before gusts existed
            self._gust_rng = np.random.default_rng([int(c.seed), 0x6057])
        a = math.exp(-dt / c.wind_gust_tau_s)
        drive = c.wind_gust_mps * math.sqrt(1.0 - a * a)
        self._gust_en = (a * self._gust_en[0] + drive * float(self._gust_rng.normal()),
                         a * self._gust_en[1] + drive * float(self._gust_rng.normal()))

    def _autostart(self) -> None:
        cfg = self.config
        if not cfg.autostart or self.armed or self.failed or self._airborne_once or len(self.mission) < 2:
            return
        if self._ready_at is None:
            self._ready_at = self.time_s + cfg.start_delay_s
        if self.time_s >= self._ready_at:
            self.start_mission()

    # -- guidance ---------------------------------------------------------------------------

    def _item_target(self, item: MissionItem) -> tuple[float, float, float]:
        """(east, north, alt above home) of a positional item; a zero position means 'here'."""
        c = self.config
        if item.x == 0 and item.y == 0:
            east, north = self.kin.east_m, self.kin.north_m
        else:
            east, north = enu_from_geodetic(item.x / 1e7, item.y / 1e7, c.home_lat_deg, c.home_lon_deg)
        alt = float(item.z)
        if item.frame in (MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT):
            alt -= c.home_alt_m
        return east, north, alt

    def _fly(self, dt: float) -> tuple[float, bool]:
        """Kinematics for one tick; returns (shaft power demand W, motors running)."""
        k, lim, c = self.kin, self.config.flight_limits, self.config
        if self.failed or not self.armed:
            return self._unpowered(dt), False
        if self.mode == MODE_MANUAL:
            if k.on_ground:
                flight.advance(k, dt, heading_cmd=None, airspeed_cmd=0.0, climb_cmd=0.0, limits=lim, airborne=False,
                               accel=lim.rollout_decel_mps2)
                return 0.0, True
            # no pilot in this simulation: MANUAL in the air holds heading and altitude; a multirotor
            # (ArduCopter's STABILIZE number) holds its position: it hovers
            hover = self._multirotor
            flight.advance(k, dt, heading_cmd=None, airspeed_cmd=0.0 if hover else self.target_airspeed, climb_cmd=0.0,
                           limits=lim, wind_en=self.wind_en)
            return self._flight_power(), True
        if self.mode == MODE_RTL or not self.mission or self.current_seq >= len(self.mission):
            return self._fly_home(dt)
        item = self.mission[self.current_seq]
        if item.command == MAV_CMD_DO_CHANGE_SPEED:
            if item.param2 > 0:
                self.target_airspeed = float(item.param2)
            self._reached(self.current_seq)
            return self._hold(dt)
        if item.command == MAV_CMD_NAV_TAKEOFF:
            return self._fly_takeoff(dt, item)
        if item.command == MAV_CMD_NAV_WAYPOINT:
            return self._fly_waypoint(dt, item)
        if item.command == MAV_CMD_NAV_LAND:
            e, n, _ = self._item_target(item)
            return self._fly_land(dt, e, n, item.seq)
        if item.command == MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._fly_home(dt, seq=item.seq)
        # anything else was refused at upload; skip it if it got here (e.g. a mission from config)
        self._reached(self.current_seq)
        return self._hold(dt)

    def _hold(self, dt: float) -> tuple[float, bool]:
        k, lim = self.kin, self.config.flight_limits
        if k.on_ground:
            return 0.0, True
        flight.advance(k, dt, heading_cmd=None, airspeed_cmd=self.target_airspeed, climb_cmd=0.0, limits=lim,
                       wind_en=self.wind_en)
        return self._flight_power(), True

    def _unpowered(self, dt: float) -> float:
        k, lim = self.kin, self.config.flight_limits
        if k.on_ground:
            flight.advance(k, dt, heading_cmd=None, airspeed_cmd=0.0, climb_cmd=0.0, limits=lim, airborne=False,
                           accel=lim.rollout_decel_mps2)
            return 0.0
        glide = max(self.config.airframe.stall_airspeed + 4.0, 18.0)
        flight.advance(k, dt, heading_cmd=None, airspeed_cmd=glide, climb_cmd=-lim.failure_sink_mps, limits=lim,
                       wind_en=self.wind_en)
        if k.alt_m <= 0.0:
            self._touchdown()
        return 0.0

    def _flight_power(self) -> float:
        k, c = self.kin, self.config
        rho = float(air_density(c.home_alt_m + k.alt_m, c.ground_temp_c))
        return float(self._vehicle_power(k.airspeed_mps, k.climb_mps, rho))

    def _fly_takeoff(self, dt: float, item: MissionItem) -> tuple[float, bool]:
        k, lim = self.kin, self.config.flight_limits
        _, _, alt = self._item_target(item)
        if self._takeoff_heading is None:
            self._takeoff_heading = self._runway_heading()
            k.heading_rad = self._takeoff_heading
        if k.on_ground:
            flight.advance(k, dt, heading_cmd=None, airspeed_cmd=self.target_airspeed, climb_cmd=0.0, limits=lim,
                           airborne=False, accel=lim.takeoff_accel_mps2)
            if k.airspeed_mps >= lim.rotate_airspeed_mps:
                k.on_ground = False
                self._airborne_once = True
            return flight.ground_roll_power(k.airspeed_mps, lim.takeoff_accel_mps2, lim, self.config.airframe), True
        flight.advance(k, dt, heading_cmd=self._takeoff_heading, airspeed_cmd=self.target_airspeed,
                       climb_cmd=min(lim.takeoff_climb_mps, flight.altitude_command(alt - k.alt_m, lim) + 1.0),
                       limits=lim, wind_en=self.wind_en)
        if k.alt_m >= alt - 2.0:
            self._reached(item.seq)
        return self._flight_power(), True

    def _runway_heading(self) -> float:
        """Take off towards the first positional item after the take-off (or north)."""
        for it in self.mission[self.current_seq + 1:]:
            if it.command in (MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LAND) and (it.x or it.y):
                e, n, _ = self._item_target(it)
                if math.hypot(e - self.kin.east_m, n - self.kin.north_m) > 1.0:
                    return math.atan2(e - self.kin.east_m, n - self.kin.north_m)
        return 0.0

    def _steer(self, dt: float, east: float, north: float, alt: float) -> float:
        """Fly towards (east, north) and alt; returns the horizontal distance left."""
        k, lim, c = self.kin, self.config.flight_limits, self.config
        de, dn = east - k.east_m, north - k.north_m
        course = math.atan2(de, dn)
        heading = flight.course_heading(course, max(k.airspeed_mps, 1.0), self.wind_en)
        flight.advance(k, dt, heading_cmd=heading, airspeed_cmd=self.target_airspeed,
                       climb_cmd=flight.altitude_command(alt - k.alt_m, lim), limits=lim, wind_en=self.wind_en)
        if k.on_ground and k.airspeed_mps >= lim.rotate_airspeed_mps:
            k.on_ground = False
        return math.hypot(east - k.east_m, north - k.north_m)

    def _passed(self, east: float, north: float) -> bool:
        """Past the line through the target perpendicular to the leg (ArduPlane's 'passed waypoint')."""
        if self._leg_start is None:
            return False
        le, ln = east - self._leg_start[0], north - self._leg_start[1]
        if math.hypot(le, ln) < 1.0:
            return False
        return (self.kin.east_m - east) * le + (self.kin.north_m - north) * ln > 0.0

    def _fly_waypoint(self, dt: float, item: MissionItem) -> tuple[float, bool]:
        k, lim = self.kin, self.config.flight_limits
        if k.on_ground:  # AUTO from the ground without a take-off item: take off towards it
            flight.advance(k, dt, heading_cmd=None, airspeed_cmd=self.target_airspeed, climb_cmd=0.0, limits=lim,
                           airborne=False, accel=lim.takeoff_accel_mps2)
            if k.airspeed_mps >= lim.rotate_airspeed_mps:
                k.on_ground = False
                self._airborne_once = True
            e, n, _ = self._item_target(item)
            k.heading_rad = math.atan2(e - k.east_m, n - k.north_m)
            return flight.ground_roll_power(k.airspeed_mps, lim.takeoff_accel_mps2, lim, self.config.airframe), True
        e, n, alt = self._item_target(item)
        dist = self._steer(dt, e, n, alt)
        self._check_leg_faults(dist)
        radius = item.param2 if item.param2 > 0 else lim.acceptance_radius_m
        if dist <= radius or self._passed(e, n):
            self._reached(item.seq)
        return self._flight_power(), True

    def _fly_home(self, dt: float, seq: int = -1) -> tuple[float, bool]:
        k, lim = self.kin, self.config.flight_limits
        if k.on_ground:
            return 0.0, True  # RTL on the ground: nowhere to return to
        if not self._rtl_landing:
            dist = self._steer(dt, 0.0, 0.0, max(lim.rtl_alt_m, 0.0))
            # start the approach far enough out to descend on the glide slope
            if dist <= max(lim.acceptance_radius_m, k.alt_m / math.tan(math.radians(lim.glide_slope_deg))):
                self._rtl_landing = True
                self._leg_start = (k.east_m, k.north_m)
            return self._flight_power(), True
        return self._fly_land(dt, 0.0, 0.0, seq)

    def _fly_land(self, dt: float, east: float, north: float, seq: int) -> tuple[float, bool]:
        k, lim, c = self.kin, self.config.flight_limits, self.config
        dist = math.hypot(east - k.east_m, north - k.north_m)
        passed = self._passed(east, north) or dist < 5.0
        if k.alt_m > lim.flare_alt_m:
            glide_alt = dist * math.tan(math.radians(lim.glide_slope_deg))
            if passed:
                climb = -lim.max_sink_mps
                heading = None
            else:
                climb = flight.altitude_command(min(glide_alt, k.alt_m) - k.alt_m, lim)
                heading = flight.course_heading(math.atan2(east - k.east_m, north - k.north_m),
                                                max(k.airspeed_mps, 1.0), self.wind_en)
            airspeed = max(c.airframe.stall_airspeed + 4.0, min(self.target_airspeed, 20.0))
            flight.advance(k, dt, heading_cmd=heading, airspeed_cmd=airspeed, climb_cmd=climb, limits=lim,
                           wind_en=self.wind_en)
            return self._flight_power(), True
        if not k.on_ground:  # flare
            flight.advance(k, dt, heading_cmd=None, airspeed_cmd=c.airframe.stall_airspeed + 1.0,
                           climb_cmd=-lim.flare_sink_mps, limits=lim, wind_en=self.wind_en)
            if k.alt_m <= 0.0:
                self._touchdown(seq)
                return 0.0, True
            return self._flight_power(), True
        return 0.0, True

    def _touchdown(self, seq: int = -1) -> None:
        k = self.kin
        k.alt_m = 0.0
        k.climb_mps = 0.0
        k.on_ground = True
        if self.failed:
            k.airspeed_mps = 0.0  # an unpowered arrival: the aircraft stops where it comes down
            k.vel_east_mps = k.vel_north_mps = 0.0
            self._emit("statustext", text="Crashed: vehicle on the ground", severity=SEVERITY_CRITICAL)
            self.disarm(force=True)
            return
        self.landed = True
        self._emit("landed")
        self._emit("statustext", text="Landed", severity=SEVERITY_INFO)
        if seq >= 0:
            self._reached(seq, advance=False)
        self.mission_complete = True
        self.disarm(force=True)

    def _reached(self, seq: int, advance: bool = True) -> None:
        self._emit("reached", seq=seq)
        self.reached_log.append((seq, self.time_s))
        if 0 <= seq < len(self.mission):
            self.reached_items.append(self.mission[seq])
        self._last_reached = seq
        for spec in list(self._pending_faults):
            if spec.trigger.kind == "wp" and spec.trigger.seq == seq:
                self._pending_faults.remove(spec)
                self.inject_fault(spec.motor, spec.magnitude, reason=spec.describe())
        if not advance:
            return
        nxt = seq + 1
        if nxt < len(self.mission):
            self._set_current(nxt, reset_leg=True)
        else:
            self.mission_complete = True
            self._emit("statustext", text="Mission complete, returning home", severity=SEVERITY_INFO)
            self.set_mode(MODE_RTL)

    # -- faults -----------------------------------------------------------------------------

    def _check_time_faults(self) -> None:
        for spec in list(self._pending_faults):
            if spec.trigger.kind == "time" and self.armed and self._armed_time >= spec.trigger.time_s:
                self._pending_faults.remove(spec)
                self.inject_fault(spec.motor, spec.magnitude, reason=spec.describe())

    def _check_leg_faults(self, dist_left: float) -> None:
        for spec in list(self._pending_faults):
            tr = spec.trigger
            # the leg a-b: flying towards b with a (or a non-positional item after it) reached last
            if tr.kind != "leg" or self.current_seq != tr.seq or not tr.from_seq <= self._last_reached < tr.seq:
                continue
            if self._leg_start is None:
                continue
            item = self.mission[self.current_seq]
            e, n, _ = self._item_target(item)
            length = math.hypot(e - self._leg_start[0], n - self._leg_start[1])
            if length <= 0.0 or 1.0 - dist_left / length >= tr.fraction:
                self._pending_faults.remove(spec)
                self.inject_fault(spec.motor, spec.magnitude, reason=spec.describe())

    # -- powertrain (the kernel) -----------------------------------------------------------

    def _powertrain(self, dt: float, power: float, motors_on: bool) -> None:
        c = self.config
        amb = self.ambient_c
        self.shaft_power_w = power if motors_on else 0.0
        if not motors_on:
            # resting: no current through packs or motors
            n_packs, n_motors = len(self.pack_names), len(self.motor_names)
            zero = np.zeros((n_packs, 1))
            if self._ext_matrix is None:
                run = kernel.simulate_packs(self._pack_matrix, self.pack_state, np.full((n_packs, 1), dt), zero, amb)
            else:
                run = kernel.simulate_packs(self._ext_matrix, self.pack_state, np.full((n_packs, 1), dt), zero, amb,
                                            variant="extended")
            self.pack_state = run.final_state
            if self._ext_matrix is not None:  # its voltage depends on the current: kept from the run
                self._pack_voltage = run.voltage[:, -1].copy()
            # one parameter row per motor: the kernel sizes its loop by the parameter rows
            self.motor_temp = kernel.simulate_motor_thermal(self._motor_rows, self.motor_temp,
                                                            np.full((n_motors, 1), dt), np.zeros((n_motors, 1)),
                                                            amb)[:, -1]
            self.pack_current = np.zeros(n_packs)
            self.motor_current = np.zeros(n_motors)
            return
        if self._ext_matrix is None:
            run = simulate_vehicle(self._topology, self._pack_matrix[None], self._motor_rows[None],
                                   self.pack_state[None], self.motor_temp[None], np.array([dt]), np.array([power]),
                                   amb, self.fault[None], fault_drag=c.fault_drag, record=True, stop_on_failure=False)
        else:
            run = simulate_vehicle_extended(
                self._topology, self._pack_matrix[None], self._ext_matrix[None], np.ones(len(self.pack_names), bool),
                self._motor_rows[None], self.pack_state[None], self.motor_temp[None], np.array([dt]),
                np.array([power]), amb, self.fault[None], fault_drag=c.fault_drag, record=True, stop_on_failure=False)
        self.pack_state = run.final_pack_state[0]
        self.motor_temp = run.final_motor_temp[0]
        self.pack_current = run.pack_current[0, -1].copy()
        self.motor_current = run.motor_current[0, -1].copy()
        self.motor_charge += self.motor_current * dt
        self.pack_charge += run.charge_c[0]
        v = run.pack_voltage[0, -1]
        if self._ext_matrix is not None:
            self._pack_voltage = v.copy()
        self.pack_energy += v * self.pack_current * dt
        self.energy_j += float(run.energy_j[0])
        if run.failed[0] and not self.failed:
            self._fail(int(run.fail_cause[0]))

    def _fail(self, cause: int) -> None:
        self.failed = True
        what = kernel.FAILURE_NAMES.get(cause, f"cause {cause}")
        detail = self._failure_detail(cause)
        self.failure = f"{what}{detail}"
        log.warning("vehicle failure at %.1f s: %s", self.time_s, self.failure)
        self._emit("failure", text=self.failure, severity=SEVERITY_CRITICAL)
        self._emit("statustext", text=f"FAILURE: {self.failure}"[:50], severity=SEVERITY_CRITICAL)
        if self.kin.on_ground:
            # failed before or after flying: nothing to glide, the vehicle stops where it is
            self._emit("statustext", text="Propulsion lost on the ground", severity=SEVERITY_EMERGENCY)
            self.disarm(force=True)
        else:
            self._emit("statustext", text="Propulsion lost, gliding down", severity=SEVERITY_EMERGENCY)

    def _failure_detail(self, cause: int) -> str:
        if cause in (kernel.FAIL_UNDERVOLTAGE, kernel.FAIL_DEPLETED):
            return f" ({self.pack_names[int(np.argmin(self._terminal_voltage()))]})"
        if cause == kernel.FAIL_PACK_OVERTEMP:
            t = self.pack_state[:, kernel.S_T]
            b = int(np.argmax(t))
            return f" ({self.pack_names[b]} {t.max():.0f}C>{self._topology.pack_max_temp_c[b]:g})"
        if cause == kernel.FAIL_MOTOR_OVERTEMP:
            return f" ({self.motor_names[int(np.argmax(self.motor_temp))]} {self.motor_temp.max():.0f}C)"
        return ""

    # ---- observation -------------------------------------------------------------------------

    @property
    def ambient_c(self) -> float:
        c = self.config
        return float(ambient_temperature(c.home_alt_m + self.kin.alt_m, c.ground_temp_c, c.home_alt_m))

    @property
    def mission_state(self) -> int:
        if len(self.mission) < 2:
            return 1
        if self.mission_complete:
            return 5
        if self.armed and self.mode == MODE_AUTO:
            return 3
        return 2

    def state(self) -> TruthState:
        k, c = self.kin, self.config
        lat, lon = geodetic_from_enu(k.east_m, k.north_m, c.home_lat_deg, c.home_lon_deg)
        rho = float(air_density(c.home_alt_m + k.alt_m, c.ground_temp_c))
        v = self._terminal_voltage()
        motor_v = self._motor_voltages(v)
        rpm = float(shaft_rpm(self.shaft_power_w, rho, c.airframe)) if self.shaft_power_w > 0 else 0.0
        if self._multirotor:
            # each rotor turns its own share of the power
            rpm = float(shaft_rpm(self.shaft_power_w / len(self.motor_names), rho, c.airframe)) if rpm else 0.0
        return TruthState(
            time_s=self.time_s, armed=self.armed, mode=self.mode, on_ground=k.on_ground, landed=self.landed,
            failed=self.failed, failure=self.failure, current_seq=self.current_seq, mission_count=len(self.mission),
            mission_state=self.mission_state, east_m=k.east_m, north_m=k.north_m, alt_m=k.alt_m, lat_deg=lat,
            lon_deg=lon, alt_amsl_m=c.home_alt_m + k.alt_m, heading_deg=math.degrees(k.heading_rad) % 360.0,
            airspeed_mps=k.airspeed_mps, groundspeed_mps=k.groundspeed_mps, climb_mps=k.climb_mps,
            vel_north_mps=k.vel_north_mps, vel_east_mps=k.vel_east_mps, shaft_power_w=self.shaft_power_w,
            rpm=rpm,
            ambient_c=self.ambient_c, air_density=rho, pack_voltage_v=v.copy(),
            pack_current_a=self.pack_current.copy(), pack_temp_c=self.pack_state[:, kernel.S_T].copy(),
            pack_soc=self._pack_soc(),
            pack_charge_c=self.pack_charge.copy(), pack_energy_j=self.pack_energy.copy(),
            motor_current_a=self.motor_current.copy(), motor_temp_c=self.motor_temp.copy(),
            motor_voltage_v=motor_v, fault=self.fault.copy(), energy_j=self.energy_j, distance_m=self.distance_m,
            wind_east_mps=self.wind_en[0], wind_north_mps=self.wind_en[1], motor_charge_c=self.motor_charge.copy(),
            **self._telemetry_layout)

    def _terminal_voltage(self) -> np.ndarray:
        if self._ext_matrix is not None:
            return self._pack_voltage
        return kernel.terminal_voltage(self._pack_matrix, self.pack_state)

    def _pack_soc(self) -> np.ndarray:
        if self._ext_matrix is not None:
            return self.pack_state[:, kernel.X_SOC].copy()
        return kernel.state_of_charge(self._pack_matrix, self.pack_state).copy()

    def battery_capacities_mah(self) -> dict[int, float]:
        """The capacity the autopilot is configured with, per BATTERY_STATUS id (its BATTn_CAPACITY):
        the description's rated capacity (an autopilot is not told a hidden truth's)."""
        return {p.mavlink_battery_id: float(p.capacity_mah) for p in self.config.vehicle.packs}

    def _motor_voltages(self, v: np.ndarray) -> np.ndarray:
        """Each motor's bus voltage: its packs' sum in series, their mean in parallel."""
        pack_v = v.tolist()
        bus = []
        for packs, parallel in zip(self._bus_packs, self._bus_parallel):
            total = sum(pack_v[b] for b in packs)
            bus.append(total / len(packs) if parallel else total)
        return np.array([bus[k] for k in self._bus_of_motor])


def _telemetry_layout(desc) -> dict:
    """The description's telemetry layout, as ``TruthState`` carries it (fixed for a flight)."""
    from gcs_pdm.vehicle.model_inputs import mav_type

    return dict(pack_ids=tuple(p.mavlink_battery_id for p in desc.packs),
                pack_reports_temperature=tuple(p.reports_temperature for p in desc.packs),
                esc_index=tuple(m.esc_index for m in desc.motors),
                motor_readings=tuple((m.readings.current, m.readings.rpm, m.readings.temperature)
                                     for m in desc.motors),
                mav_type=mav_type(desc), multirotor=desc.airframe.type == "multirotor")
