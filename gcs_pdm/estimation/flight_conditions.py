"""What a prediction needs from the flight, worked out once from the telemetry frames: the flight
phase (flying or not, and why), the air density, the airspeed and climb, the ambient temperature
and the load to extrapolate (the airframe's shaft power, or each pack's present draw).

The live service (``service.telemetry_intake``) and a replay (``replay.vehicle.TracedPipeline``)
each hold one :class:`FlightConditions`, hand it the same frames and ask it the same question
(:meth:`FlightConditions.inputs`), so from the same frames they predict from the same inputs.

The load follows the airframe's model (``vehicle.model_inputs.shaft_power_model``): a fixed wing's
shaft power at its airspeed and climb; a multirotor's level-flight power at its airspeed (hover at
zero: a climb lasts seconds, not the prediction's hour). A described fixed wing other than the
paper's aircraft holds each pack's present draw instead: its prediction has no shaft-power model
of its packs yet (issue 32).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from gcs_pdm.estimation.flight_phase import FlightPhase, flight_phase
from gcs_pdm.frames import AirdataFrame, AmbientFrame, PositionFrame, StatusFrame
from gcs_pdm.models.powertrain import air_density
from gcs_pdm.vehicle.description import VehicleDescription
from gcs_pdm.vehicle.model_inputs import shaft_power_model

#: message seconds after which a landed state no longer counts (the vehicle stopped sending it)
LANDED_STATE_MAX_AGE_S = 10.0
#: the ambient temperature a prediction assumes before the vehicle reported one, °C
DEFAULT_AMBIENT_C = 20.0


@dataclass(frozen=True)
class PredictionInputs:
    """What a prediction at ``time_s`` starts from (see the module docstring)."""
    time_s: float
    phase: FlightPhase
    air_density_kg_m3: float
    airspeed_mps: float
    climb_mps: float
    ambient_c: float
    #: the load to extrapolate, W; None: each pack holds its present draw
    shaft_power_w: float | None

    def to_dict(self) -> dict:
        return {"flying": self.phase.flying, "phase": self.phase.reason, "air_density_kg_m3": self.air_density_kg_m3,
                "airspeed_mps": self.airspeed_mps, "climb_mps": self.climb_mps, "ambient_c": self.ambient_c,
                "shaft_power_w": self.shaft_power_w}


class FlightConditions:
    """The flight's evidence from the frames (position, air data, armed flag, ambient temperature)
    and EXTENDED_SYS_STATE's landed state, kept as the latest heard."""

    #: the frames it reads (a consumer that passes other types over must still hand it these)
    FRAME_TYPES = frozenset({PositionFrame, AirdataFrame, StatusFrame, AmbientFrame})

    def __init__(self) -> None:
        #: the home's altitude above mean sea level (the first position that gives both altitudes)
        self.ground_alt_amsl: float | None = None
        self.alt_above_home_m = math.nan
        self.airdata: tuple[float, float] | None = None  # airspeed, climb rate
        self.armed: bool | None = None  # HEARTBEAT's armed flag (None: not heard)
        self.landed_state: tuple[int, float] | None = None  # MAV_LANDED_STATE, message time
        self.ambient_c: float | None = None

    def consume(self, frame) -> None:
        if isinstance(frame, PositionFrame) and frame.lat_deg is not None:
            self.alt_above_home_m = frame.relative_alt_m or 0.0
            if self.ground_alt_amsl is None and frame.alt_m is not None and frame.relative_alt_m is not None:
                self.ground_alt_amsl = frame.alt_m - frame.relative_alt_m
        elif isinstance(frame, AirdataFrame) and frame.airspeed is not None:
            self.airdata = (frame.airspeed, frame.climb_rate or 0.0)
        elif isinstance(frame, StatusFrame):
            self.armed = bool(frame.armed)
        elif isinstance(frame, AmbientFrame) and frame.temperature_c is not None:
            self.ambient_c = frame.temperature_c

    def on_landed_state(self, landed_state: int, time_s: float | None) -> None:
        """EXTENDED_SYS_STATE's MAV_LANDED_STATE (0 = undefined: not evidence) at message time."""
        state = int(landed_state)
        self.landed_state = (state, time_s if time_s is not None else 0.0) if state else None

    def restart_clock(self) -> None:
        """The vehicle rebooted: its armed flag and landed state are heard afresh."""
        self.armed = None
        self.landed_state = None

    def air_density(self) -> float:
        alt = (self.ground_alt_amsl or 0.0) + (self.alt_above_home_m if math.isfinite(self.alt_above_home_m) else 0.0)
        return float(air_density(alt))

    def phase(self, t: float, vehicle: VehicleDescription, estimator) -> FlightPhase:
        """Flying or not, and why, from the latest evidence and the vehicle's airframe."""
        multirotor = vehicle.airframe.type == "multirotor"
        airspeed, climb = self.airdata if self.airdata is not None else (None, None)
        landed = self.landed_state
        if landed is not None and t - landed[1] > LANDED_STATE_MAX_AGE_S:
            landed = None
        power = hover = None
        if multirotor:
            hover = float(shaft_power_model(vehicle)(0.0, 0.0, self.air_density()))
            if estimator.ready():
                v = estimator.estimate().pack_voltage_v
                watts = [x for x in (v * estimator.pack_current) if math.isfinite(x)]
                power = float(sum(watts)) if watts else None
        return flight_phase(multirotor=multirotor, armed=self.armed, landed_state=landed[0] if landed else None,
                            airspeed_mps=airspeed, climb_mps=climb, electrical_power_w=power, hover_power_w=hover)

    def inputs(self, t: float, vehicle: VehicleDescription, estimator) -> PredictionInputs:
        """The prediction's inputs at ``t`` for ``vehicle`` (the paper's aircraft is the ``edge540``
        preset), whose state ``estimator`` tracks."""
        rho = self.air_density()
        airspeed, climb = self.airdata if self.airdata is not None else (0.0, 0.0)
        fixed_wing = vehicle.airframe.type == "fixed_wing"
        if fixed_wing and not vehicle.airframe.predict_with_drag_polar:
            power = None  # each pack holds its present draw
        else:
            power = float(shaft_power_model(vehicle)(airspeed, climb if fixed_wing else 0.0, rho))
        return PredictionInputs(time_s=t, phase=self.phase(t, vehicle, estimator), air_density_kg_m3=rho,
                                airspeed_mps=airspeed, climb_mps=climb,
                                ambient_c=float(self.ambient_c) if self.ambient_c is not None else DEFAULT_AMBIENT_C,
                                shaft_power_w=power)
