"""Fault and degradation specifications for the simulated vehicle, and their command-line grammar.

Grammar (docs/sim.md):

``motor:<fwd|aft>:<magnitude>@<trigger>`` with trigger one of
    ``t:<seconds>``           flight time since arming,
    ``wp:<seq>``              when mission item ``seq`` is reached,
    ``leg:<a>-<b>[:<frac>]``  on the leg from item ``a`` to item ``b``, once ``frac`` (default 0.5)
                              of the leg's length is flown.
``<PACK>:capacity=<factor>,resistance=<factor>``  pack degradation (either key may be left out).

Pure: strings in, dataclasses out; ``apply_degradation`` returns a new ParameterSet.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES, ParameterSet, degraded


class FaultSpecError(ValueError):
    """A fault or degradation string that does not follow the grammar; the message says where."""


@dataclass(frozen=True)
class FaultTrigger:
    kind: str            # "time", "wp" or "leg"
    time_s: float = 0.0  # kind "time": flight time since arming
    seq: int = 0         # kind "wp": the item reached; kind "leg": the item flown towards (b)
    from_seq: int = 0    # kind "leg": the item the leg starts at (a)
    fraction: float = 0.5  # kind "leg": share of the leg flown before the fault

    def describe(self) -> str:
        if self.kind == "time":
            return f"t:{self.time_s:g}"
        if self.kind == "wp":
            return f"wp:{self.seq}"
        return f"leg:{self.from_seq}-{self.seq}:{self.fraction:g}"


@dataclass(frozen=True)
class FaultSpec:
    """A motor power loss of ``magnitude`` (the motor delivers 1 - m of its share) and when it starts."""

    motor: str
    magnitude: float
    trigger: FaultTrigger

    def describe(self) -> str:
        return f"motor:{self.motor}:{self.magnitude:g}@{self.trigger.describe()}"


@dataclass(frozen=True)
class Degradation:
    """A pack worse than new: capacity scaled by ``capacity`` (C_b, q_max, C_max), R_s and R_cp0 by
    ``resistance`` (the same reading as ``gcs_pdm.estimation.synthetic.PackDegradation``)."""

    pack: str
    capacity: float = 1.0
    resistance: float = 1.0

    def describe(self) -> str:
        return f"{self.pack}:capacity={self.capacity:g},resistance={self.resistance:g}"


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_FAULT_RE = re.compile(rf"^motor:(?P<motor>\w+):(?P<mag>{_NUMBER})@(?P<trigger>.+)$")


def _float(text: str, what: str, spec: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise FaultSpecError(f"{spec!r}: {what} must be a number, got {text!r}") from None


def _int(text: str, what: str, spec: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise FaultSpecError(f"{spec!r}: {what} must be an integer, got {text!r}") from None


def parse_trigger(text: str, spec: str = "") -> FaultTrigger:
    kind, _, rest = text.partition(":")
    spec = spec or text
    if kind == "t":
        t = _float(rest, "the fault time (s)", spec)
        if t < 0:
            raise FaultSpecError(f"{spec!r}: the fault time must be >= 0 s, got {t}")
        return FaultTrigger("time", time_s=t)
    if kind == "wp":
        return FaultTrigger("wp", seq=_int(rest, "the waypoint number", spec))
    if kind == "leg":
        leg, _, frac = rest.partition(":")
        a, sep, b = leg.partition("-")
        if not sep:
            raise FaultSpecError(f"{spec!r}: a leg is written leg:<from>-<to>, e.g. leg:2-3")
        fraction = _float(frac, "the leg fraction", spec) if frac else 0.5
        if not 0.0 <= fraction <= 1.0:
            raise FaultSpecError(f"{spec!r}: the leg fraction must be within [0, 1], got {fraction}")
        return FaultTrigger("leg", seq=_int(b, "the leg's end item", spec), from_seq=_int(a, "the leg's start item", spec),
                            fraction=fraction)
    raise FaultSpecError(f"{spec!r}: unknown trigger {kind!r}; use t:<s>, wp:<n> or leg:<a>-<b>")


def parse_fault(text: str, motors: tuple[str, ...] = MOTOR_NAMES) -> FaultSpec:
    """``motor:aft:0.8@leg:2-3`` → FaultSpec; ``motors``: the vehicle's motor names."""
    m = _FAULT_RE.match(text.strip())
    if not m:
        raise FaultSpecError(f"{text!r}: expected motor:<{'|'.join(motors)}>:<magnitude>@<t:s|wp:n|leg:a-b>")
    motor = m["motor"]
    if motor not in motors:
        raise FaultSpecError(f"{text!r}: motor must be one of {', '.join(motors)}, got {motor!r}")
    magnitude = float(m["mag"])
    if not 0.0 <= magnitude <= 1.0:
        raise FaultSpecError(f"{text!r}: magnitude must be within [0, 1], got {magnitude}")
    return FaultSpec(motor, magnitude, parse_trigger(m["trigger"], text))


def parse_degradation(text: str) -> Degradation:
    """``LRF40:capacity=0.8,resistance=1.5`` → Degradation."""
    pack, sep, rest = text.strip().partition(":")
    if pack not in PACK_NAMES:
        raise FaultSpecError(f"{text!r}: pack must be one of {', '.join(PACK_NAMES)}, got {pack!r}")
    if not sep or not rest:
        raise FaultSpecError(f"{text!r}: expected <PACK>:capacity=<f>,resistance=<f>")
    values = {"capacity": 1.0, "resistance": 1.0}
    for part in rest.split(","):
        key, eq, val = part.partition("=")
        key = key.strip()
        if not eq or key not in values:
            raise FaultSpecError(f"{text!r}: unknown degradation {part!r}; keys are capacity and resistance")
        values[key] = _float(val, key, text)
        if values[key] <= 0:
            raise FaultSpecError(f"{text!r}: {key} must be > 0, got {values[key]}")
    if values["capacity"] > 1.0:
        raise FaultSpecError(f"{text!r}: capacity is a loss factor and must be <= 1, got {values['capacity']}")
    return Degradation(pack, **values)


def apply_degradation(params: ParameterSet, degradations: "tuple[Degradation, ...] | list[Degradation]") -> ParameterSet:
    """The parameter set with each degradation applied (several on one pack compound)."""
    out = params
    for d in degradations:
        out = degraded(out, d.pack, d.capacity, d.resistance)
    if degradations:
        out = out.replace(name=f"{params.name}+degraded",
                          provenance={**dict(params.provenance), "degradation": [d.describe() for d in degradations]})
    return out
