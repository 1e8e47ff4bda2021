"""The vehicle description: what the vehicle is, as data (docs/vehicles.md).

A description lists the packs, the motors, how the packs feed the motors, the airframe, and the
mission's reward and landing reserve. It is read from TOML or JSON and validated with pydantic;
every error names the field it is about (``packs[0].cells_series: must be >= 1``). Units are SI
except where the field's name says otherwise (``capacity_mah``, ``_c`` for °C).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on 3.10
    import tomli as tomllib


class VehicleError(ValueError):
    """A description that cannot be read or is not a vehicle; the message names the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


#: full-cell open-circuit voltage and the default cut-off per chemistry, V per cell
CHEMISTRY_CELL_VOLTAGE: dict[str, tuple[float, float]] = {
    "lipo": (4.2, 3.5),
    "lihv": (4.35, 3.5),
    "liion": (4.2, 3.0),
    "lifepo4": (3.45, 2.8),
}


class ParameterRef(_Strict):
    """Where a pack's model parameters come from.

    ``set`` is a built-in parameter set name (``paper_si``), a fitted set's JSON file (what
    ``gcs-pdm fit`` writes), or ``"chemistry-default"``: the paper's 5S 7.8 Ah LiPo pack scaled
    to this pack's cells and capacity (docs/vehicles.md gives the scaling). ``pack`` picks the pack
    inside a set (LLF20, ULA20, LRF40, URA40 in the paper's sets; a vehicle's fitted set holds that
    vehicle's packs by name); ``scale_to_pack`` scales that pack to this pack's cells and capacity
    (from the set's own pack format) instead of taking it as it is.
    """

    set: str = "chemistry-default"
    pack: str | None = None
    scale_to_pack: bool = False

    @model_validator(mode="after")
    def _pack_named(self) -> "ParameterRef":
        if self.set != "chemistry-default" and self.pack is None:
            raise ValueError(f"pack: name the pack inside parameter set {self.set!r}")
        return self


class PackSpec(_Strict):
    name: str = Field(min_length=1)
    #: BATTERY_STATUS.id of this pack
    mavlink_battery_id: int = Field(ge=0, le=255)
    #: DataFlash BAT instance (ArduPilot); defaults to the MAVLink id
    dataflash_instance: int | None = Field(default=None, ge=0)
    cells_series: int = Field(ge=1, le=24)
    cells_parallel: int = Field(default=1, ge=1, le=16)
    capacity_mah: float = Field(gt=0)
    chemistry: Literal["lipo", "lihv", "liion", "lifepo4"] = "lipo"
    #: resting voltage per cell of a full pack, V, when it is not the chemistry's (4.2 for LiPo)
    full_cell_voltage: float | None = Field(default=None, gt=3.0, le=4.5)
    #: terminal voltage per cell below which the pack has failed (under load), V
    cutoff_v_per_cell: float | None = Field(default=None, gt=2.0, lt=4.5)
    min_temp_c: float = Field(default=0.0, ge=-40, le=40)
    max_temp_c: float = Field(default=60.0, gt=20, le=120)
    parameters: ParameterRef = ParameterRef()
    #: whether the pack reports its temperature (False: estimated from the thermal model)
    reports_temperature: bool = True
    #: whether the estimator learns the pack's open-circuit curve and resistance in flight from its
    #: prior (False: its ``parameters`` are flown as they are, e.g. the paper's fitted packs, until a
    #: flight contradicts them: ``estimation.fitted_prior``)
    self_calibrate: bool = True

    @property
    def full_voltage(self) -> float:
        return self.full_cell_v * self.cells_series

    @property
    def full_cell_v(self) -> float:
        return self.full_cell_voltage or CHEMISTRY_CELL_VOLTAGE[self.chemistry][0]

    @property
    def cutoff_voltage(self) -> float:
        per_cell = self.cutoff_v_per_cell or CHEMISTRY_CELL_VOLTAGE[self.chemistry][1]
        return per_cell * self.cells_series

    @property
    def capacity_c(self) -> float:
        return self.capacity_mah * 3.6


class MotorReadings(_Strict):
    """Which ESC telemetry readings exist for a motor."""

    current: bool = True
    rpm: bool = True
    temperature: bool = True


class MotorParamsSpec(_Strict):
    """Motor electrical and thermal parameters (``gcs_pdm.models.params.MotorParams``)."""

    R_w: float = Field(gt=0)
    I_0: float = Field(ge=0)
    P_iron: float = Field(ge=0)
    C_t: float = Field(gt=0)
    h: float = Field(gt=0)


class MotorSpec(_Strict):
    name: str = Field(min_length=1)
    #: index in ESC_TELEMETRY_1_TO_4 / 5_TO_8 ... (0-based), and ArduPilot's ESC instance
    esc_index: int = Field(ge=0, le=31)
    readings: MotorReadings = MotorReadings()
    max_temp_c: float = Field(default=100.0, gt=20, le=250)
    max_current_a: float | None = Field(default=None, gt=0)
    #: a built-in/fitted parameter set's motor (``set``), or the values themselves (``values``)
    parameter_set: str | None = None
    values: MotorParamsSpec | None = None

    @model_validator(mode="after")
    def _one_source(self) -> "MotorSpec":
        if (self.values is None) == (self.parameter_set is None):
            raise ValueError("values: give either the motor's values or a parameter_set (one of them)")
        return self


class Bus(_Strict):
    """One electrical bus: packs joined in series or in parallel, driving some motors."""

    packs: list[str] = Field(min_length=1)
    arrangement: Literal["series", "parallel"] = "series"
    motors: list[str] = Field(min_length=1)


class FixedWing(_Strict):
    """Parabolic drag polar (``gcs_pdm.models.powertrain.Airframe``, docs/model.md)."""

    type: Literal["fixed_wing"] = "fixed_wing"
    wing_area_m2: float = Field(gt=0)
    aspect_ratio: float = Field(gt=0)
    cd0: float = Field(gt=0, lt=1)
    oswald: float = Field(gt=0, le=1)
    eta_prop: float = Field(gt=0, le=1)
    descent_recovery: float = Field(default=0.6, ge=0, le=1)
    min_shaft_power_w: float = Field(default=40.0, ge=0)
    prop_diameter_m: float = Field(gt=0)
    prop_power_coeff: float = Field(default=0.045, gt=0)
    stall_airspeed: float = Field(gt=0)
    max_airspeed: float = Field(gt=0)
    #: motors on one shaft (the paper's aircraft): a fault shows as one motor's share moving
    shared_shaft: bool = False
    #: a flight's prediction flies this drag polar at the present airspeed and climb (a polar checked
    #: against flights, as the paper's); false: each pack holds its present draw
    predict_with_drag_polar: bool = False


class Multirotor(_Strict):
    """Momentum theory with a figure of merit and profile/parasite terms (gcs_pdm/models/multirotor.py)."""

    type: Literal["multirotor"] = "multirotor"
    rotor_diameter_m: float = Field(gt=0)
    #: hover figure of merit: ideal induced power / actual rotor power
    figure_of_merit: float = Field(default=0.65, gt=0, le=1)
    #: equivalent flat-plate drag area of the body, m²
    drag_area_m2: float = Field(default=0.02, gt=0)
    #: blade tip speed in hover, m/s (profile power grows as 1 + 3 (V / V_tip)²)
    tip_speed_mps: float = Field(default=120.0, gt=0)
    max_airspeed: float = Field(gt=0)


Airframe = Annotated[Union[FixedWing, Multirotor], Field(discriminator="type")]


class VehicleDescription(_Strict):
    name: str = Field(min_length=1)
    description: str = ""
    #: set when the description was derived from telemetry rather than written by a person
    provisional: bool = False
    packs: list[PackSpec] = Field(min_length=1)
    motors: list[MotorSpec] = Field(min_length=1)
    buses: list[Bus] = Field(min_length=1)
    airframe: Airframe
    mass_kg: float = Field(gt=0)
    cruise_speed_mps: float = Field(gt=0)
    climb_rate_mps: float = Field(gt=0)
    #: reward of each mission goal reached (the planner's utility units)
    mission_reward: float = Field(default=100.0, ge=0)
    #: charge that must be left in every pack on landing, fraction of capacity
    landing_reserve: float = Field(default=0.2, ge=0, lt=1)
    #: how many other fresh current readings (its series string's other packs, the motor it alone
    #: feeds) a pack's own current is checked against (a spike replaced, a missing one filled). 2:
    #: one other sensor against the pack's own cannot say which is wrong (stock ArduPilot SITL's ESC
    #: current is a tenth of its battery current); 1 where they are known to agree (``edge540``)
    current_references: int = Field(default=2, ge=1, le=8)

    @model_validator(mode="after")
    def _consistent(self) -> "VehicleDescription":
        packs = [p.name for p in self.packs]
        motors = [m.name for m in self.motors]
        for kind, names in (("packs", packs), ("motors", motors)):
            dup = {n for n in names if names.count(n) > 1}
            if dup:
                raise ValueError(f"{kind}: duplicate name {sorted(dup)[0]!r}")
        ids = [p.mavlink_battery_id for p in self.packs]
        if len(set(ids)) != len(ids):
            raise ValueError("packs: two packs share a mavlink_battery_id")
        escs = [m.esc_index for m in self.motors]
        if len(set(escs)) != len(escs):
            raise ValueError("motors: two motors share an esc_index")
        fed_packs: list[str] = []
        fed_motors: list[str] = []
        for i, bus in enumerate(self.buses):
            for p in bus.packs:
                if p not in packs:
                    raise ValueError(f"buses[{i}].packs: no pack {p!r}; have {', '.join(packs)}")
            for m in bus.motors:
                if m not in motors:
                    raise ValueError(f"buses[{i}].motors: no motor {m!r}; have {', '.join(motors)}")
            fed_packs += bus.packs
            fed_motors += bus.motors
        for kind, have, fed in (("packs", packs, fed_packs), ("motors", motors, fed_motors)):
            for n in have:
                if fed.count(n) != 1:
                    raise ValueError(f"buses: {kind[:-1]} {n!r} must be on exactly one bus, is on {fed.count(n)}")
        return self

    # ---- derived views ----------------------------------------------------------------------
    @property
    def pack_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.packs)

    @property
    def motor_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.motors)

    def bus_of_pack(self, name: str) -> int:
        return next(i for i, b in enumerate(self.buses) if name in b.packs)

    def bus_of_motor(self, name: str) -> int:
        return next(i for i, b in enumerate(self.buses) if name in b.motors)

    def feed_kind(self) -> str:
        """One pack, packs in parallel, series strings, a pack per motor (or mixed)."""
        if len(self.packs) == 1:
            return "one pack"
        if len(self.buses) == 1 and self.buses[0].arrangement == "parallel":
            return "packs in parallel"
        if all(len(b.packs) == 1 and len(b.motors) == 1 for b in self.buses):
            return "a pack per motor"
        if all(b.arrangement == "series" for b in self.buses):
            return "series strings"
        return "mixed"

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json", exclude_none=True)


# ---- reading and writing -------------------------------------------------------------------------

def _field_path(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("fixed_wing", "multirotor"):  # the discriminator's branch, not a field
            continue
        else:
            out += ("." if out else "") + str(part)
    return out or "description"


def validation_message(exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        msg = err["msg"].removeprefix("Value error, ")
        lines.append(f"{_field_path(tuple(err['loc']))}: {msg}")
    return "; ".join(lines)


def from_dict(data: Any) -> VehicleDescription:
    try:
        return VehicleDescription.model_validate(data)
    except ValidationError as exc:
        raise VehicleError(validation_message(exc)) from None


def parse(text: str, fmt: str) -> VehicleDescription:
    """A description from TOML (``fmt="toml"``) or JSON text."""
    try:
        data = tomllib.loads(text) if fmt == "toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise VehicleError(f"not {fmt.upper()}: {exc}") from None
    return from_dict(data)


def load(path: str | Path) -> VehicleDescription:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise VehicleError(f"{path}: {exc.strerror or exc}") from None
    fmt = "json" if path.suffix.lower() == ".json" else "toml"
    try:
        return parse(text, fmt)
    except VehicleError as exc:
        raise VehicleError(f"{path}: {exc}") from None


def dumps(desc: VehicleDescription, fmt: str = "toml") -> str:
    data = desc.to_dict()
    if fmt == "json":
        return json.dumps(data, indent=2) + "\n"
    import tomli_w

    return tomli_w.dumps(data)
