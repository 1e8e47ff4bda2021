"""Service configuration: documented defaults < a TOML/JSON file < ``GCS_PDM_*`` environment variables
< explicit overrides (the command line's options), layered by pydantic-settings.

Pydantic validates every value, so a bad setting is rejected at start-up with the field named
(``ConfigError: policy: Input should be 'auto' or 'advise'``). The file may be TOML (stdlib
``tomllib``) or JSON; keys are the field names below. An environment variable is the field name
upper-cased with the ``GCS_PDM_`` prefix (``GCS_PDM_POLICY=advise``, ``GCS_PDM_HTTP_PORT=8080``).
See docs/service.md for the table of settings.
"""
from __future__ import annotations

import json
import os
import re
import secrets
import tomllib
from contextvars import ContextVar
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping

from pydantic import Field, ValidationError, field_validator
from pydantic.fields import FieldInfo
from pydantic_settings import BaseSettings, EnvSettingsSource, PydanticBaseSettingsSource, SettingsConfigDict
from pydantic_settings.sources.utils import parse_env_vars

from gcs_pdm.mavlink.stream_requests import DEFAULT_RATES_HZ as DEFAULT_STREAM_RATES_HZ, StreamPolicy
from gcs_pdm.planning.planners import SERVICE_PLANNERS

ENV_PREFIX = "GCS_PDM_"


#: shortest accepted api_token: a generated one is 32 characters; a few letters can be guessed
MIN_TOKEN_CHARS = 16
#: tokens that come from examples and templates (compared case-insensitively, ignoring - and _)
PLACEHOLDER_TOKENS = frozenset({
    "changeme", "changemeplease", "changethis", "replaceme", "token", "secret", "password", "passw0rd",
    "test", "testing", "example", "default", "admin", "apitoken", "yourtoken", "yourapitoken",
    "mytoken", "secrettoken", "xxxxxxxxxxxxxxxx", "0123456789abcdef", "1234567890123456",
})


#: fewest distinct characters in an accepted api_token (16 spaces or "aaaaaaaaaaaaaaaa" are one)
MIN_TOKEN_DISTINCT = 8
#: the most common passwords (lists of leaked passwords), refused with digits or symbols around them
COMMON_PASSWORDS = frozenset({
    "password", "qwerty", "qwertyuiop", "letmein", "welcome", "admin", "administrator", "iloveyou", "monkey",
    "dragon", "football", "baseball", "sunshine", "princess", "trustno", "master", "shadow", "superman", "batman",
    "abc", "login", "starwars", "whatever", "freedom", "passwd", "secret", "hello", "charlie", "michael", "jordan",
    "access", "mustang", "flower", "hunter", "ninja", "azerty", "solo", "loveme", "zaq", "qazwsx", "changeme",
})
_LEET = str.maketrans("0134@$5!7", "oleaassit")


def _common_password(token: str) -> bool:
    """A common password, repeated, or dressed up: leading with one (p@ssw0rd read as password) and
    followed by at most two more letters among digits and symbols."""
    low = token.lower().strip()
    letters = re.sub(r"[^a-z]", "", low)
    unleet = low.translate(_LEET)  # one character for one, so positions agree with ``low``
    for word in COMMON_PASSWORDS:
        if letters and len(letters) % len(word) == 0 and letters == word * (len(letters) // len(word)):
            return True
        if unleet.startswith(word) and len(re.sub(r"[^a-z]", "", low[len(word):])) <= 2:
            return True
    return False


def token_problem(token: str) -> str | None:
    """Why ``token`` cannot be the API's bearer token, or None."""
    advice = "set a random one (e.g. python -c 'import secrets; print(secrets.token_urlsafe(24))')"
    if token.lower().replace("-", "").replace("_", "").replace(" ", "") in PLACEHOLDER_TOKENS:
        return f"is a known placeholder; {advice}"
    if len(token) < MIN_TOKEN_CHARS:
        return f"is shorter than {MIN_TOKEN_CHARS} characters; set a random one, or leave it unset to have one generated"
    if len(set(token)) < MIN_TOKEN_DISTINCT:
        return f"has fewer than {MIN_TOKEN_DISTINCT} distinct characters; {advice}"
    if _common_password(token):
        return f"is a common password; {advice}"
    return None


class ConfigError(ValueError):
    """A configuration value that cannot be used; the message names the field."""


#: what one ``load_config`` call reads: the settings file (or None) and the environment
_SOURCES: ContextVar[tuple[Path | None, Mapping[str, str]]] = ContextVar("config_sources", default=(None, os.environ))


class _FileSource(PydanticBaseSettingsSource):
    """The TOML/JSON settings file of this ``load_config`` call."""

    def get_field_value(self, field: FieldInfo, field_name: str) -> tuple[Any, str, bool]:
        return None, field_name, False  # the whole file is read at once (__call__)

    def __call__(self) -> dict[str, Any]:
        path = _SOURCES.get()[0]
        return _read_file(path) if path else {}


class _EnvSource(EnvSettingsSource):
    """``GCS_PDM_*`` variables from this call's environment (``os.environ`` unless a test passes one)."""

    def _load_env_vars(self) -> Mapping[str, str | None]:
        return parse_env_vars(_SOURCES.get()[1], self.case_sensitive, self.env_ignore_empty, self.env_parse_none_str)


class ServiceConfig(BaseSettings):
    model_config = SettingsConfigDict(extra="forbid", validate_assignment=True, env_prefix=ENV_PREFIX)

    # --- links -------------------------------------------------------------------------------
    mavlink_url: str = Field("udpin:127.0.0.1:14551", description="MAVLink connection (udpin:, udpout:, tcp:, serial)")
    source_system: int = Field(245, ge=1, le=254, description="our MAVLink system id (not 255, the GCS's: docs/operations.md)")
    target_system: Annotated[int, Field(ge=1, le=255)] | Literal["auto"] = Field(1, description="the vehicle's system id; auto: the first autopilot heard")
    source_component: int = Field(195, ge=1, le=255, description="our MAVLink component id (MAV_COMP_ID_PATHPLANNER)")
    signing_key_file: str | None = Field(None, description="MAVLink 2 signing key file")
    request_streams: bool = Field(True, description="ask the vehicle for the telemetry streams it does not send "
                                  "(SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM for older firmware; /status.streams)")
    stream_rates_hz: dict[str, float] = Field(default_factory=lambda: dict(DEFAULT_STREAM_RATES_HZ), description=(
        "rate asked for each stream the vehicle does not send by itself, Hz (0: never ask): battery, position, "
        "airspeed, esc, wind, ambient, landed, mission"))
    http_host: str = Field("127.0.0.1", description="HTTP bind address; localhost unless told")
    http_port: int = Field(8000, ge=0, le=65535)

    # --- operator console ----------------------------------------------------------------------
    map_tile_url: str | None = Field(None, description="map tile URL template ({z}/{x}/{y}) the console draws over; "
                                     "None: the local east/north frame (the field has no internet)")
    map_tile_attribution: str = Field("", description="attribution text the tile server's licence asks for")
    track_window_s: float = Field(7200.0, gt=0, description="message-time seconds of the vehicle's track kept for the console (GET /status/track)")

    # --- storage -----------------------------------------------------------------------------
    data_dir: str = Field("./gcs-pdm-data", description="directory for the database, tlogs, uploads and plots")
    db_path: str | None = Field(None, description="SQLite file (default: <data_dir>/gcs_pdm.sqlite3)")
    record_tlog: bool = Field(True, description="record every live session to <data_dir>/tlogs/")

    # --- uploads (POST /files) -------------------------------------------------------------------
    max_upload_bytes: int = Field(256 * 1024 * 1024, ge=1, description="largest accepted upload (bytes); larger is 413")
    max_upload_rows: int = Field(5_000_000, ge=1, description="most rows of an uploaded CSV/Parquet table; more is 413")
    max_upload_cells: int = Field(10_000_000, ge=1, description="most cells (rows x columns) of an uploaded table; more is 413")
    max_upload_decoded_bytes: int = Field(128 << 20, ge=1, description="most bytes an uploaded table may take decoded "
                                          "(a Parquet file's uncompressed size, from its footer); more is 413")
    max_json_bytes: int = Field(1 << 20, ge=1024, description="largest request body other than an upload (bytes); "
                                "larger is 413, before it is parsed or the token is checked")
    tlog_min_mavlink_fraction: float = Field(0.9, gt=0, le=1, description="share of an uploaded tlog's bytes that must be CRC-valid MAVLink records")

    # --- auth --------------------------------------------------------------------------------
    api_token: str | None = Field(None, description="bearer token for mutating endpoints; generated and logged if unset")

    # --- decision loop -----------------------------------------------------------------------
    policy: Literal["auto", "advise"] = Field("advise", description="advise: propose, the operator approves (the safe start); auto: upload and tell the operator")
    vehicle: str | None = Field(None, description="vehicle description: a preset (edge540, plane-3s, quad-4s, ...) or "
                                "a TOML/JSON file (docs/vehicles.md); unset: a provisional one from the first telemetry")
    parameter_set: str = Field("paper_si", description="parameter set active at start-up (name in the store)")
    planner: Literal[SERVICE_PLANNERS] = Field(  # type: ignore[valid-type] - the registry's names
        "auto", description="auto (= pfls, alias stronger): PF + local search; pf: Algorithm 1 alone; exact: branch and bound")
    particles: int = Field(30, ge=1, le=10_000)
    planner_deadline_s: float = Field(20.0, gt=0, description="wall-clock budget of one planning run")
    planner_seed: int = 0
    max_failure_probability: float | None = Field(0.02, ge=0, lt=1, description=(
        "risk-bounded planning: the most expected reward with P(failure) <= this and the landing reserve at the "
        "5 % quantile, over risk_samples draws of state, parameters, fault and wind (docs/planning.md); "
        "null: the deterministic planner on the nominal model"))
    risk_samples: int = Field(200, ge=10, le=2000, description="draws of the risk-bounded planner")
    reevaluate_every_s: float = Field(30.0, gt=0, description=(
        "message-time seconds between two re-evaluations of the current mission's outlook (/status.outlook) and of a "
        "pending proposal (re-planned from the current state); an older proposal is re-planned before an approval uploads"))
    replan_cooldown_s: float = Field(30.0, ge=0, description="message-time seconds between two replans for deviations")
    deviation_soc: float = Field(0.08, gt=0, description="SoC deviation (observed vs predicted at plan time) that triggers a replan")
    confirm_download: bool = Field(True, description="confirm each upload by downloading the mission back")
    link_lost_after_s: float = Field(5.0, gt=0, description="seconds without a heartbeat from the vehicle before the link is declared lost (replans and uploads refused until it returns)")
    flight_end_after_link_lost_s: float = Field(300.0, gt=0, description="a flight ends when the vehicle has been silent this long (docs/packs.md)")
    pack_retire_capacity_fraction: float = Field(0.8, gt=0, lt=1, description="a pack is due for retirement at this fraction of its first capacity (docs/packs.md)")
    pack_retire_resistance_factor: float = Field(1.5, gt=1, description="... or at this multiple of its first resistance at 25 °C (docs/packs.md)")
    fit_workers: int = Field(1, ge=1, le=8, description="worker threads for fitting jobs")

    @field_validator("map_tile_url")
    @classmethod
    def _tile_template(cls, url: str | None) -> str | None:
        if url is None or not url.strip():
            return None
        if not url.startswith(("http://", "https://", "/")):
            raise ValueError("must be an http(s) URL or a path on this service, e.g. http://tiles.local/{z}/{x}/{y}.png")
        if not all(k in url for k in ("{z}", "{x}", "{y}")):
            raise ValueError("must hold {z}, {x} and {y} (a tile URL template)")
        return url

    @field_validator("stream_rates_hz")
    @classmethod
    def _stream_rates(cls, rates: dict[str, float]) -> dict[str, float]:
        merged = {**DEFAULT_STREAM_RATES_HZ, **rates}  # a setting names the streams it changes
        StreamPolicy(rates_hz=merged)  # ValueError names the unknown stream or the bad rate
        return merged

    @field_validator("api_token")
    @classmethod
    def _usable_token(cls, token: str | None) -> str | None:
        problem = None if token is None else token_problem(token)
        if problem:
            raise ValueError(problem)
        return token

    @classmethod
    def settings_customise_sources(cls, settings_cls, init_settings, env_settings, dotenv_settings,
                                   file_secret_settings):
        # first wins: overrides, then the environment, then the file; the defaults last
        return init_settings, _EnvSource(settings_cls), _FileSource(settings_cls)

    @property
    def data_path(self) -> Path:
        # absolute, so stored file paths stay valid whatever directory the next start runs in
        return Path(self.data_dir).expanduser().resolve()

    @property
    def database(self) -> Path:
        return Path(self.db_path) if self.db_path else self.data_path / "gcs_pdm.sqlite3"


def _read_file(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"config file {p}: {exc.strerror or exc}") from None
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"config file {p}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"config file {p}: expected a table of settings")
    # A [service] table is accepted so the file can be shared with other tools.
    return dict(data.get("service", data))


def load_config(path: str | Path | None = None, env: Mapping[str, str] | None = None,
                **overrides: Any) -> ServiceConfig:
    """Defaults, then the file (``path`` or ``$GCS_PDM_CONFIG``), then the environment, then overrides."""
    env = os.environ if env is None else env
    path = path or env.get(ENV_PREFIX + "CONFIG")
    token = _SOURCES.set((Path(path) if path else None, env))
    try:
        return ServiceConfig(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(x) for x in err["loc"]) or "config"
        # pydantic prefixes a validator's own message with "Value error, "; the field name says enough
        raise ConfigError(f"{where}: {err['msg'].removeprefix('Value error, ')}") from None
    finally:
        _SOURCES.reset(token)


def new_token() -> str:
    return secrets.token_urlsafe(24)
