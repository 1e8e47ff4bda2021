"""Pydantic models of the HTTP API (requests and responses); OpenAPI at /docs is built from these."""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES

MotorName = Literal["fwd", "aft"]
PackName = Literal["LLF20", "ULA20", "LRF40", "URA40"]
assert set(MotorName.__args__) == set(MOTOR_NAMES) and set(PackName.__args__) == set(PACK_NAMES)


class Health(BaseModel):
    status: Literal["ok"]
    version: str
    schema_version: int
    link_connected: bool
    policy: Literal["auto", "advise"]
    active_parameter_set: str | None
    interrupted_jobs_at_start: int
    readiness: dict[str, str] | None = Field(None, description="per capability: 'ready' or why not (e.g. 'waiting for pack battery voltage')")
    vehicle: dict[str, Any] | None = Field(None, description="the vehicle description in use: name, source (given, default, deriving, provisional), notes")


class PackStatus(BaseModel):
    voltage_v: float | None = None
    current_a: float | None = None
    temperature_c: float | None = None
    temperature_sd: float | None = None
    soc: float | None = None
    soc_sd: float | None = None
    time_to_cutoff_s: float | None = Field(None, description="predicted time to the voltage cut-off at the present load")
    time_to_cutoff_sd: float | None = None
    model_config = ConfigDict(extra="allow")


class MotorStatus(BaseModel):
    current_a: float | None = None
    rpm: float | None = None
    temperature_c: float | None = None
    temperature_sd: float | None = None
    health: float = Field(1.0, description="1 - diagnosed power-loss magnitude")
    fault: dict | None = None
    model_config = ConfigDict(extra="allow")


class VehicleStatus(BaseModel):
    time_s: float | None = Field(None, description="latest message time (vehicle clock), s")
    link: dict[str, Any]
    packs: dict[str, PackStatus]
    motors: dict[str, MotorStatus]
    ambient_c: float | None
    position: dict[str, float | None]
    airdata: dict[str, float | None]
    armed: bool | None
    mode: str | None
    mission: dict[str, Any]
    prediction: dict[str, Any] | None
    policy: str | None
    parameter_set: str | None
    failed: str | None = None
    model_config = ConfigDict(extra="allow")


class FaultIn(BaseModel):
    """An operator-declared fault (e.g. seen on the ground station, not yet by the diagnoser)."""

    kind: Literal["motor_power_loss"] = "motor_power_loss"
    motor: str = Field(..., min_length=1, max_length=64,
                       description="a motor of the vehicle description in use (/status motors; the paper's: fwd, aft)")
    magnitude: float = Field(..., ge=0.0, le=1.0, description="fraction of the motor's power lost")
    note: str = ""
    replan: bool = Field(True, description="re-plan the mission with this fault")


class FaultOut(BaseModel):
    id: int
    time_s: float | None
    kind: str
    target: str | None
    magnitude: float | None
    source: str
    active: bool
    detail: dict[str, Any]
    created_at: float


class MissionItemModel(BaseModel):
    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float | None
    param2: float | None
    param3: float | None
    param4: float | None
    x: int
    y: int
    z: float
    mission_type: int = 0


class MissionOut(BaseModel):
    items: list[MissionItemModel] | None
    source: str = Field(..., description="'download' (read back from the vehicle) or 'none'")
    time_s: float | None = None


class PlanOut(BaseModel):
    id: int
    time_s: float | None
    trigger: str
    status: str
    created_at: float
    updated_at: float
    model_config = ConfigDict(extra="allow")


class Decision(BaseModel):
    note: str = ""


class UploadOut(BaseModel):
    id: int
    plan_id: int | None
    status: str
    created_at: float
    model_config = ConfigDict(extra="allow")


class PolicyIn(BaseModel):
    policy: Literal["auto", "advise"]


class ParameterSetSummary(BaseModel):
    name: str
    builtin: bool
    active: bool
    physical: bool
    description: str
    provenance: dict[str, Any]
    created_at: float


class ParameterSetImport(BaseModel):
    """A parameter set as exported (``GET /parameter-sets/{name}``), under a new name."""

    parameter_set: dict[str, Any] = Field(..., description="the set's JSON (gcs_pdm.models.params.ParameterSet.to_dict)")
    name: str | None = Field(None, min_length=1, max_length=80, pattern=r"^[A-Za-z0-9_.\-]+$")
    overwrite: bool = False
    activate: bool = False


class FlightRef(BaseModel):
    """One flight: an uploaded file (``POST /files``) or a recorded tlog from the index."""

    file_id: str | None = None
    tlog_id: int | None = None
    path: str | None = Field(None, description="a server-side path (only under the data directory or fixtures)")

    @model_validator(mode="after")
    def _one(self) -> "FlightRef":
        if sum(x is not None for x in (self.file_id, self.tlog_id, self.path)) != 1:
            raise ValueError("give exactly one of file_id, tlog_id, path")
        return self


class FitFlights(BaseModel):
    train: list[FlightRef] = Field(..., min_length=1)
    validation: list[FlightRef] = Field(..., min_length=1)
    test: list[FlightRef] = Field(default_factory=list)


class FitJobIn(BaseModel):
    component: Literal["battery", "motor"] = "battery"
    packs: list[PackName] = Field(default_factory=lambda: list(PACK_NAMES), min_length=1)
    flights: FitFlights
    base_set: str = Field("paper_si", description="parameter set the fitted values are merged into")
    save_as: str | None = Field(None, pattern=r"^[A-Za-z0-9_.\-]+$",
                                description="store the result under this name (a new one, unless overwrite)")
    overwrite: bool = Field(False, description="save_as may replace an existing user set (never a built-in or the active set)")
    settings: dict[str, Any] = Field(default_factory=dict, description="fitter settings: search {starts, seed, sa_generations, ...}, cleaning {...}, "
                                       "reference, init_samples, soc_offset_range, workers; unknown keys are 422")


class JobOut(BaseModel):
    id: str
    kind: str
    status: Literal["queued", "running", "succeeded", "failed", "cancelled", "interrupted"]
    progress: float
    stage: str
    request: dict[str, Any]
    result: Any | None = None
    error: str | None = None
    created_at: float
    updated_at: float


class JobCreated(BaseModel):
    id: str
    status: str


class FileOut(BaseModel):
    id: str
    filename: str
    kind: str
    size_bytes: int
    created_at: float


class TlogOut(BaseModel):
    id: int
    path: str
    started_at: float
    ended_at: float | None
    size_bytes: int | None
    note: str | None
