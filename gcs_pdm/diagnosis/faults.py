"""Faults as the diagnoser reports them: (type, magnitude, time, evidence, confidence).

One vocabulary end to end: the diagnoser raises :class:`Fault` objects, the service passes them on
unchanged (an operator-declared fault is a ``Fault`` too, see :func:`operator_fault`), and the
planner's view is :func:`motor_faults` (the worst ``powertrain.MotorFault`` per motor).
``Fault.to_dict()`` is a stable contract (the service stores it): keys are never renamed; new keys
may be added.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Iterable

from gcs_pdm.models.params import MOTOR_NAMES
from gcs_pdm.models.powertrain import DescribedMotorFault, MotorFault

MOTOR_POWER_LOSS = "motor_power_loss"
PACK_CAPACITY_LOSS = "pack_capacity_loss"
PACK_RESISTANCE_RISE = "pack_resistance_rise"
PREDICTED_LIMIT_VIOLATION = "predicted_limit_violation"
DEGRADATION_RATE_DEVIATION = "degradation_rate_deviation"
#: an advisory, not a fault of the vehicle: a pack no longer behaves like its model (refit it)
MODEL_MISMATCH = "model_mismatch"

FAULT_TYPES = (MOTOR_POWER_LOSS, PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE, PREDICTED_LIMIT_VIOLATION,
               DEGRADATION_RATE_DEVIATION, MODEL_MISMATCH)
#: types that tell the operator something but are no reason to re-plan
ADVISORY_TYPES = (MODEL_MISMATCH,)

#: what ``magnitude`` means for each type
MAGNITUDE_MEANING = {
    MOTOR_POWER_LOSS: "fraction of its half of the shaft power the motor no longer delivers (0..1)",
    PACK_CAPACITY_LOSS: "fraction of the parameter set's capacity the pack has lost (0..1)",
    PACK_RESISTANCE_RISE: "relative rise of the pack's series resistance R_s + R_cp0 (0.5 = +50 %)",
    PREDICTED_LIMIT_VIOLATION: "probability that the vehicle fails before the mission ends (0..1)",
    DEGRADATION_RATE_DEVIATION: "relative deviation of the observed rate from the predicted one",
    MODEL_MISMATCH: "the pack's model-consistency statistic when raised: mean squared normalised innovation "
                    "(1 = as variable as the filter expects; the raise bound is in the evidence)",
}


@dataclass(frozen=True)
class Fault:
    type: str
    component: str          # motor ('fwd'/'aft'), pack name, or 'vehicle'
    magnitude: float
    time_s: float           # message time the fault was raised
    confidence: float       # 0..1
    evidence: dict = field(default_factory=dict)
    active: bool = True
    updated_s: float | None = None   # message time of the latest evidence
    cleared_s: float | None = None   # message time the evidence went away

    def __post_init__(self) -> None:
        if self.type not in FAULT_TYPES:
            raise ValueError(f"type: expected one of {FAULT_TYPES}, got {self.type!r}")
        if not math.isfinite(self.magnitude):
            raise ValueError(f"magnitude: must be finite, got {self.magnitude!r}")
        if not 0.0 <= self.confidence <= 1.0:
            raise ValueError(f"confidence: must be within [0, 1], got {self.confidence!r}")

    @property
    def key(self) -> tuple[str, str]:
        return (self.type, self.component)

    def with_(self, **changes: Any) -> "Fault":
        return replace(self, **changes)

    def as_motor_fault(self) -> MotorFault:
        """The planner's view of a motor power loss."""
        if self.type != MOTOR_POWER_LOSS:
            raise ValueError(f"only {MOTOR_POWER_LOSS} faults map to a MotorFault, not {self.type}")
        magnitude = min(max(self.magnitude, 0.0), 1.0)
        if self.component in MOTOR_NAMES:
            return MotorFault(self.component, magnitude)
        return DescribedMotorFault(self.component, magnitude)  # a vehicle description's motor

    def to_dict(self) -> dict[str, Any]:
        return {
            "type": self.type,
            "component": self.component,
            "magnitude": round(float(self.magnitude), 4),
            "time_s": round(float(self.time_s), 3),
            "confidence": round(float(self.confidence), 3),
            "active": self.active,
            "updated_s": None if self.updated_s is None else round(float(self.updated_s), 3),
            "cleared_s": None if self.cleared_s is None else round(float(self.cleared_s), 3),
            "evidence": _jsonable(self.evidence),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Fault":
        try:
            return cls(type=d["type"], component=d["component"], magnitude=float(d["magnitude"]),
                       time_s=float(d["time_s"]), confidence=float(d["confidence"]),
                       evidence=dict(d.get("evidence", {})), active=bool(d.get("active", True)),
                       updated_s=d.get("updated_s"), cleared_s=d.get("cleared_s"))
        except KeyError as exc:
            raise ValueError(f"fault: missing field {exc.args[0]!r}") from None


def operator_fault(motor: str, magnitude: float, time_s: float | None) -> Fault:
    """A motor power loss the operator declared (seen on the ground station): certain, no evidence.

    ``time_s`` is the message time of the declaration (NaN before any telemetry)."""
    return Fault(MOTOR_POWER_LOSS, motor, float(magnitude), math.nan if time_s is None else float(time_s), 1.0,
                 {"source": "operator"})


def motor_faults(faults: Iterable[Fault]) -> list[MotorFault]:
    """The planner's view: one ``MotorFault`` per motor with an active power loss, the worst one
    when several are reported on a motor (diagnosed and declared, or declared twice)."""
    worst: dict[str, MotorFault] = {}
    for f in faults:
        if f.type != MOTOR_POWER_LOSS or not f.active:
            continue
        mf = f.as_motor_fault()
        if mf.motor not in worst or mf.magnitude > worst[mf.motor].magnitude:
            worst[mf.motor] = mf
    return [worst[m] for m in sorted(worst)]


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if hasattr(x, "tolist"):
        return _jsonable(x.tolist())
    if isinstance(x, float):
        return round(x, 4) if math.isfinite(x) else None
    return x
