"""Pydantic models of the HTTP API (requests and responses); OpenAPI at /docs is built from these."""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES

#: SQLite's INTEGER is a signed 64-bit number: a larger id names no row (and overflows the driver: a 500)
SQLITE_INT_MAX = 2**63 - 1
#: longest operator note kept with a fault, plan decision or upload
MAX_NOTE_CHARS = 2000

MotorName = Literal["fwd", "aft"]
PackName = Literal["LLF20", "ULA20", "LRF40", "URA40"]
assert set(MotorName.__args__) == set(MOTOR_NAMES) and set(PackName.__args__) == set(PACK_NAMES)


class ErrorOut(BaseModel):
    """Every error answer: ``detail`` says what went wrong. A 422 carries a list of
    ``{loc, msg, type}`` naming the field (FastAPI's validation shape); other codes carry text."""

    detail: str | list[dict[str, Any]]


#: what each error status means on this API (the OpenAPI descriptions)
ERROR_MEANINGS = {
    401: "missing or wrong bearer token",
    404: "no such resource",
    409: "the resource is not in a state that allows this",
    413: "the upload is larger than the configured limit (bytes or rows)",
    422: "a parameter or body field is invalid (named in detail[].loc)",
    507: "the data directory's disk is full or failing, or the database cannot be written (detail says which); "
         "nothing was stored",
}


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` of a route: each error status it can answer, with the common error model."""
    return {code: {"model": ErrorOut, "description": ERROR_MEANINGS[code]} for code in codes}


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    reasons: list[str] = Field(default_factory=list, description="why the status is degraded")
    version: str
    schema_version: int
    link_connected: bool
    policy: Literal["auto", "advise"]
    active_parameter_set: str | None
    interrupted_jobs_at_start: int
    readiness: dict[str, str] | None = Field(None, description="per capability: 'ready' or why not (e.g. 'waiting for pack battery voltage')")
    vehicle: dict[str, Any] | None = Field(None, description="the vehicle description in use: name, source (given, default, deriving, provisional), notes")
    foreign_systems: list[int] = Field(default_factory=list, description="other systems sending vehicle heartbeats "
                                       "on our link (ignored, never tracked; details in /status link_trust)")


class PackStatus(BaseModel):
    voltage_v: float | None = None
    current_a: float | None = None
    temperature_c: float | None = None
    temperature_sd: float | None = None
    soc: float | None = None
    soc_sd: float | None = None
    time_to_cutoff_s: float | None = Field(None, description="predicted time to the voltage cut-off at the present load")
    time_to_cutoff_sd: float | None = None
    evidence: list[str] | None = Field(None, description=(
        "what the SoC rests on (a self-calibrated pack, docs/estimation.md): rest_voltage, loaded_voltage, history, "
        "coulomb, voltage_model, prior, curve_open (the chemistry's curve hypotheses still disagree)"))
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
    outlook: dict[str, Any] | None = Field(None, description=(
        "the current mission re-evaluated from the current state every reevaluate_every_s over the risk draws: "
        "line ('gets home with X % (p05–p95), P(failure) …'), p_failure, landing_soc_p05/p50/p95 (lowest pack), "
        "route, samples, alarm (null, or {kind, level, title, text} when the forecast crosses the reserve or "
        "P(failure) > max_failure_probability); or unknown with the reason"))
    wind: dict[str, Any] | None = Field(None, description=(
        "the wind flown in: speed_mps, from_deg (where it blows from, clockwise from north), east_mps/north_mps "
        "(the air's velocity), source autopilot (WIND / WIND_COV) | triangle (ground velocity minus the airspeed "
        "vector), time_s; or unknown with the reason"))
    policy: str | None
    parameter_set: str | None
    failed: str | None = None
    model_variants: dict[str, Any] | None = Field(None, description=(
        "the active parameter set's model variant per pack and notes where an extended pack's paper values "
        "are used instead (the planner)"))
    model_mismatch: dict[str, Any] | None = Field(None, description=(
        "packs that no longer behave like their model (the estimator's normalised-innovation test; "
        "each pack's evidence is in packs.<name>.model_mismatch): packs, reason with the refit suggestion, "
        "since_s; null while every pack matches"))
    fit_envelope: dict[str, Any] | None = Field(None, description=(
        "each pack the estimator flies on fitted values, against the conditions of its training flights "
        "(pack and air temperature, 60-s mean current; docs/service.md, 'Fit envelope'): packs.<name>.state "
        "inside | outside | unknown with the reasons, outside, reason; null when no such pack carries a "
        "training envelope (the paper's values, a set fitted before envelopes were stored)"))
    streams: dict[str, Any] | None = Field(None, description=(
        "the telemetry streams the service reads (battery, position, airspeed, esc, wind, ambient, landed, mission): per "
        "stream "
        "its message, state (receiving | waiting | asked N time(s), not come | stopped), rate asked for and measured, "
        "asks sent; missing; the vehicle's answers to SET_MESSAGE_INTERVAL (docs/mavlink.md, 'Asking for streams'); "
        "null without a link or with request_streams off"))
    link_trust: dict[str, Any] = Field(default_factory=dict, description=(
        "what the link refused to believe (Link.trust_report): foreign_systems [{system, component, heartbeats, "
        "first_seen_s, last_seen_s}], time_rejected, gated values by field, bad_data, sequence (whether one sender is "
        "behind the vehicle's id: packets, lost, out_of_sequence, window, shared_now, shared, verdict; null before the vehicle is "
        "identified); available: false without a link"))
    model_config = ConfigDict(extra="allow")


class FaultIn(BaseModel):
    """An operator-declared fault (e.g. seen on the ground station, not yet by the diagnoser)."""

    kind: Literal["motor_power_loss"] = "motor_power_loss"
    motor: str = Field(..., min_length=1, max_length=64,
                       description="a motor of the vehicle description in use (/status motors; the paper's: fwd, aft)")
    magnitude: float = Field(..., ge=0.0, le=1.0, description="fraction of the motor's power lost")
    note: str = Field("", max_length=MAX_NOTE_CHARS)
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
    #: the flight it belongs to (None: before flights were recorded, or on the ground)
    flight_id: int | None = None


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
    waypoints: dict[int, int] | None = Field(
        None, description="mission item seq -> waypoint number (the numbers routes and plans use): the "
                          "objectives' numbers, else the first mission's waypoints in order")


class PlanOut(BaseModel):
    id: int
    time_s: float | None
    trigger: str
    status: str
    created_at: float
    updated_at: float
    model_config = ConfigDict(extra="allow")


class Decision(BaseModel):
    note: str = Field("", max_length=MAX_NOTE_CHARS)


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
    model_variants: dict[str, Any] | None = Field(None, description=(
        "on activation: each pack's model variant (paper, extended) and notes naming every user that still "
        "flies an extended pack's paper values (the planner's vehicle simulator)"))


class ParameterSetImport(BaseModel):
    """A parameter set as exported (``GET /parameter-sets/{name}``), under a new name."""

    parameter_set: dict[str, Any] = Field(..., description="the set's JSON (gcs_pdm.models.params.ParameterSet.to_dict)")
    name: str | None = Field(None, min_length=1, max_length=80, pattern=r"^[A-Za-z0-9_.\-]+$")
    overwrite: bool = False
    activate: bool = False


class FlightRef(BaseModel):
    """One flight: an uploaded file (``POST /files``) or a recorded tlog from the index."""

    file_id: str | None = Field(None, min_length=1, max_length=64)
    tlog_id: int | None = Field(None, ge=1, le=SQLITE_INT_MAX)
    path: str | None = Field(None, min_length=1, max_length=4096, pattern=r"^[^\x00]*$",
                             description="a server-side path (only under the data directory or fixtures)")

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
    base_set: str = Field("paper_si", max_length=128, description="parameter set the fitted values are merged into")
    save_as: str | None = Field(None, min_length=1, max_length=80, pattern=r"^[A-Za-z0-9_.\-]+$",
                                description="store the result under this name (a new one, unless overwrite)")
    overwrite: bool = Field(False, description="save_as may replace an existing user set (never a built-in or the active set)")
    settings: dict[str, Any] = Field(default_factory=dict, description="fitter settings: model (\"extended\", the default, or \"paper\"), search {starts, seed, "
                                       "sa_generations, ...}, cleaning {...}, reference, init_samples, soc_offset_range, workers; "
                                       "unknown keys are 422")


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
    path: str = Field(..., description="relative to the data directory (tlogs/live_….tlog); a tlog kept elsewhere: its file name")
    started_at: float
    ended_at: float | None
    size_bytes: int | None
    note: str | None
