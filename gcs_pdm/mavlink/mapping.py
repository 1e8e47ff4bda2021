"""Message -> frame mapping: configuration as data, compiled once into fast per-message handlers.

The configuration is a plain dict (JSON-able): message name -> list of rules. A rule says which
frame kind it produces (``gcs_pdm.frames.FRAME_KINDS``), how the frame's key is found (a field
such as BATTERY_STATUS.id, the array index of ESC_TELEMETRY_1_TO_4, or a constant), optional
``match`` conditions (NAMED_VALUE_FLOAT.name == "MOT_TEMP") and, per frame field, where its value
comes from. Field specs:

``{"field": "current_battery", "scale": 0.01, "missing": [-1]}``
    one field (``[i]``-indexed automatically for indexed keys), times ``scale`` plus ``offset``;
    raw values in ``missing`` (and NaN) become None.
``{"sum": ["voltages", "voltages_ext"], "scale": 0.001, "missing": [0, 65535]}``
    sum of all elements of the listed array fields that are not ``missing``; None if none is.
``{"transform": "armed"}`` / ``{"transform": "flight_mode"}`` / ``{"field": "text", "text": true}``
    named computations (see ``TRANSFORMS``) and NUL-terminated strings.

Changing what a vehicle sends is a change of this dict (see ``docs/mavlink.md``).
"""
from __future__ import annotations

import copy
import logging
import math
import struct
from collections import Counter
from dataclasses import dataclass, field, fields as dc_fields
from typing import Any, Callable

from gcs_pdm.frames import FRAME_KIND_OF, FRAME_KINDS, PACK_NAMES
from gcs_pdm.mavlink.clock import VehicleClock, Verdict
from gcs_pdm.mavlink.dialect import MAV_AUTOPILOT_INVALID, MAV_MODE_FLAG_SAFETY_ARMED, MESSAGE_IDS_BY_NAME, mavlink2, mavutil
from gcs_pdm.mavlink.plausibility import FrameGate, PhysicalEnvelope, default_envelope
from gcs_pdm.mavlink.wire import TIME_BOOT_MS_OFFSET, layout

log = logging.getLogger(__name__)

INT16_MAX = 32767
UINT16_MAX = 65535

DEFAULT_MAPPING: dict[str, list[dict[str, Any]]] = {
    "BATTERY_STATUS": [{
        "frame": "pack",
        "key": {"field": "id", "target": "pack", "map": {str(i): name for i, name in enumerate(PACK_NAMES)}},
        "fields": {
            # Cell voltages summed; UINT16_MAX marks unused cells, 0 unused extension cells.
            "voltage_v": {"sum": ["voltages", "voltages_ext"], "scale": 0.001, "missing": [0, UINT16_MAX]},
            "current_a": {"field": "current_battery", "scale": 0.01, "missing": [-1]},
            "temperature_c": {"field": "temperature", "scale": 0.01, "missing": [INT16_MAX]},
        },
    }],
    "ESC_TELEMETRY_1_TO_4": [{
        "frame": "motor",
        "key": {"index": True, "target": "motor", "map": {"0": "fwd", "1": "aft"}},
        "fields": {
            "current_a": {"field": "current", "scale": 0.01},
            "rpm": {"field": "rpm"},
            "temperature_c": {"field": "temperature"},
        },
    }],
    "SCALED_PRESSURE": [{
        "frame": "ambient",
        "fields": {"temperature_c": {"field": "temperature", "scale": 0.01}},
    }],
    "GLOBAL_POSITION_INT": [{
        "frame": "position",
        "fields": {
            "lat_deg": {"field": "lat", "scale": 1e-7},
            "lon_deg": {"field": "lon", "scale": 1e-7},
            "alt_m": {"field": "alt", "scale": 0.001},
            "relative_alt_m": {"field": "relative_alt", "scale": 0.001},
            "vn": {"field": "vx", "scale": 0.01},
            "ve": {"field": "vy", "scale": 0.01},
            "vd": {"field": "vz", "scale": 0.01},
        },
    }],
    "VFR_HUD": [{
        "frame": "airdata",
        "fields": {
            "airspeed": {"field": "airspeed"},
            "groundspeed": {"field": "groundspeed"},
            "climb_rate": {"field": "climb"},
            "throttle_pct": {"field": "throttle"},
            "heading_deg": {"field": "heading"},
        },
    }],
    "HEARTBEAT": [{
        "frame": "status",
        "fields": {
            "armed": {"transform": "armed"},
            "mode": {"transform": "flight_mode"},
            "system_status": {"field": "system_status"},
        },
    }],
    "MISSION_CURRENT": [{"frame": "mission_progress", "fields": {"current_seq": {"field": "seq"}}}],
    "MISSION_ITEM_REACHED": [{"frame": "mission_progress", "fields": {"reached_seq": {"field": "seq"}}}],
    "STATUSTEXT": [{
        "frame": "statustext",
        "fields": {"severity": {"field": "severity"}, "text": {"field": "text", "text": True}},
    }],
    # the autopilot's wind estimate: ArduPilot's WIND says where it blows from; PX4's WIND_COV gives
    # the air's velocity north/east (NaN when it has none), turned into the same convention
    "WIND": [{
        "frame": "wind",
        "fields": {"speed_mps": {"field": "speed"}, "from_deg": {"transform": "wind_from_deg"}},
    }],
    "WIND_COV": [{
        "frame": "wind",
        "fields": {"speed_mps": {"transform": "wind_cov_speed"}, "from_deg": {"transform": "wind_cov_from_deg"}},
    }],
}


def default_mapping() -> dict[str, list[dict[str, Any]]]:
    """A fresh copy of the default mapping, to modify for a vehicle that names things differently."""
    return copy.deepcopy(DEFAULT_MAPPING)


class MappingError(ValueError):
    """A mapping configuration that names an unknown message, field or frame."""


# --- named transforms over a whole unpacked message ---------------------------------------

_mode_cache: dict[tuple, str] = {}


def _flight_mode(values: dict[str, Any]) -> str:
    key = (values["type"], values["autopilot"], values["base_mode"], values["custom_mode"])
    name = _mode_cache.get(key)
    if name is None:
        try:
            name = mavutil.mode_string_v10(mavlink2.MAVLink_heartbeat_message(key[0], key[1], key[2], key[3], 0, 3))
        except Exception:  # noqa: BLE001 - an odd vehicle type must not stop telemetry
            name = f"Mode({key[3]})"
        _mode_cache[key] = name
    return name


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _wind_cov_speed(v: dict[str, Any]) -> float | None:
    return _finite_or_none(math.hypot(v["wind_x"], v["wind_y"]))


def _wind_cov_from_deg(v: dict[str, Any]) -> float | None:
    # wind_x north, wind_y east: the velocity it blows towards; from = the opposite bearing
    return _finite_or_none(math.degrees(math.atan2(-v["wind_y"], -v["wind_x"])) % 360.0)


TRANSFORMS: dict[str, tuple[tuple[str, ...], Callable[[dict[str, Any]], Any]]] = {
    "armed": (("base_mode",), lambda v: bool(v["base_mode"] & MAV_MODE_FLAG_SAFETY_ARMED)),
    "flight_mode": (("type", "autopilot", "base_mode", "custom_mode"), _flight_mode),
    # ArduPilot sends -180..180
    "wind_from_deg": (("direction",), lambda v: _finite_or_none(v["direction"] % 360.0)),
    "wind_cov_speed": (("wind_x", "wind_y"), _wind_cov_speed),
    "wind_cov_from_deg": (("wind_x", "wind_y"), _wind_cov_from_deg),
}


# --- compilation ---------------------------------------------------------------------------

def conversion(scale: float, offset: float) -> tuple:
    """How a raw value becomes the frame's: ``("identity",)`` (the raw value itself, its type kept),
    ``("divide", N, offset)`` — a scale of 1/N divides by N, so 85455938 * 1e-7 gives 8.5455938
    exactly as printed rather than 8.545593799999999 — or ``("multiply", scale, offset)``."""
    if scale == 1.0 and offset == 0.0:
        return ("identity",)
    divisor = round(1.0 / scale) if scale else 0
    if divisor > 1 and abs(divisor * scale - 1.0) < 1e-12:
        return ("divide", divisor, offset)
    return ("multiply", scale, offset)


def _conversion_source(x: str, scale: float, offset: float) -> str:
    """Source of :func:`conversion` applied to ``x``."""
    how = conversion(scale, offset)
    if how[0] == "identity":
        return x
    return f"{x} {'/' if how[0] == 'divide' else '*'} {how[1]!r} + {how[2]!r}"


class _Source:
    """The pieces of one generated frame builder: the expressions, and the names they use."""

    def __init__(self):
        self.names: dict[str, Any] = {}

    def bind(self, value) -> str:
        name = f"_b{len(self.names)}"
        self.names[name] = value
        return name


@dataclass(frozen=True, slots=True)
class Constant:
    """A frame field every frame of a rule gets alike: its key (``pack``/``motor``), or None."""

    value: Any


@dataclass(frozen=True, slots=True)
class FieldRule:
    """Where one frame field comes from, resolved against the message's layout: positions in the
    unpacked payload tuple (what the generated builders index, and what the replay's column
    mapping, ``gcs_pdm.mavlink.frame_columns``, decodes)."""

    how: str  # "field", "text" (NUL-terminated string), "sum" or "transform"
    position: int = 0  # field, text
    spans: tuple[tuple[int, int], ...] = ()  # sum: the [start, end) positions of each summed field
    needed: tuple[tuple[str, int], ...] = ()  # transform: its inputs, (name, position)
    fn: Callable | None = None  # transform
    scale: float = 1.0
    offset: float = 0.0
    missing: frozenset = frozenset()  # raw values that mean "not available"


def _resolve_field(spec: dict, lay, element: int | None) -> FieldRule:
    """One frame field's spec (module docstring) against the message layout ``lay``."""
    scale = float(spec.get("scale", 1.0))
    offset = float(spec.get("offset", 0.0))
    if not (math.isfinite(scale) and math.isfinite(offset)):
        raise MappingError(f"{lay.name}: scale and offset must be finite numbers, got {scale!r}, {offset!r}")
    missing = frozenset(spec.get("missing", ()))
    if "transform" in spec:
        try:
            needed, fn = TRANSFORMS[spec["transform"]]
        except KeyError:
            raise MappingError(f"{lay.name}: unknown transform {spec['transform']!r}; known: {sorted(TRANSFORMS)}")
        for name in needed:
            if name not in lay.index:
                raise MappingError(f"{lay.name}: transform {spec['transform']!r} needs field {name!r}")
        return FieldRule("transform", needed=tuple((name, lay.index[name]) for name in needed), fn=fn)
    if "sum" in spec:
        spans = []
        for name in spec["sum"]:
            if name not in lay.index:
                raise MappingError(f"{lay.name} has no field {name!r}")
            spans.append((lay.index[name], lay.index[name] + lay.count[name]))
        return FieldRule("sum", spans=tuple(spans), scale=scale, offset=offset, missing=missing)
    name = spec.get("field")
    if name not in lay.index:
        raise MappingError(f"{lay.name} has no field {name!r}; fields: {sorted(lay.index)}")
    pos = lay.index[name]
    if element is not None:
        if element >= lay.count[name]:
            raise MappingError(f"{lay.name}.{name} has {lay.count[name]} elements, index {element} requested")
        pos += element
    elif "index" in spec:
        pos += int(spec["index"])
    return FieldRule("text" if spec.get("text") else "field", position=pos, scale=scale, offset=offset,
                     missing=missing)


def _field_source(rule: FieldRule, src: _Source) -> str:
    """The expression (over the unpacked payload tuple ``v``) of one frame field value."""
    if rule.how == "transform":
        items = ", ".join(f"{name!r}: v[{pos}]" for name, pos in rule.needed)
        return f"{src.bind(rule.fn)}({{{items}}})"
    if rule.how == "sum":
        spans, missing = rule.spans, rule.missing
        convert = eval(f"lambda x: {_conversion_source('x', rule.scale, rule.offset)}")  # noqa: S307 - our own source

        def summed(vals):
            total, seen = 0, False
            for a, b in spans:
                for v in vals[a:b]:
                    if v not in missing:
                        total += v
                        seen = True
            return convert(total) if seen else None
        return f"{src.bind(summed)}(v)"
    pos = rule.position
    if rule.how == "text":
        return f'v[{pos}].split(b"\\0", 1)[0].decode("utf-8", "replace")'
    x = f"_x{len(src.names)}"
    src.names[x] = None  # reserves the name (a local of the generated function)
    # raw values in ``missing``, and NaN (x != x), are "not available"
    assign = f"({x} := v[{pos}])"
    absent = f"{assign} in {src.bind(rule.missing)} or {x} != {x}" if rule.missing else f"{assign} != {x}"
    return f"(None if {absent} else {_conversion_source(x, rule.scale, rule.offset)})"


def _builders(lay, frame_fields: list[str], exprs: list[str], src: _Source, cls: type, gate: FrameGate | None,
              checks: tuple | None) -> tuple[Callable[[tuple], tuple], Callable[[float, tuple], Any]]:
    """Two functions compiled from source, so a message costs one call, not one closure per field:
    ``build(v)``, the frame's field values after time_s from the unpacked payload ``v`` (for frames
    held until the clock has a time), and ``make(t, v)``, the frame itself, gated: ``checks`` are
    the gate's (field, low, high) tests for this frame (None: not known here, the gate tests every
    frame); a frame that passes them is the gate's unchanged, any other goes through the gate."""
    values = ", ".join(exprs)
    code = f"def build(v):\n    return ({values},)\n"
    if gate is None or checks == ():
        code += f"def make(t, v):\n    return _cls(t, {values})\n"
    elif checks is None:
        code += f"def make(t, v):\n    return _gate(_cls(t, {values}))\n"
    else:
        tests = []
        for name, low, high in checks:
            i = frame_fields.index(name)
            tests.append(f"(r[{i}] is None or {src.bind(low)} <= r[{i}] <= {src.bind(high)})")
        code += (f"def make(t, v):\n    r = ({values},)\n    if {' and '.join(tests)}:\n"
                 f"        return _cls(t, *r)\n    return _gate(_cls(t, *r))\n")
    namespace = {k: v for k, v in src.names.items() if not k.startswith("_x")}
    namespace.update(_cls=cls, _gate=gate)
    exec(compile(code, f"<mapping {lay.name}>", "exec"), namespace)  # noqa: S102 - our own source
    return namespace["build"], namespace["make"]


@dataclass(slots=True, frozen=True)
class _Instance:
    """One frame a rule makes from a message (one per mapped key or array element)."""

    raw_key: Any  # the raw key value (None: not keyed by a field)
    name: str | None  # the frame's key
    element: int | None  # array index
    build: Callable[[tuple], tuple]
    make: Callable[[float, tuple], Any]
    sources: tuple = ()  # per frame field after time_s: a FieldRule or a Constant
    #: the gate's (field, low, high) tests of its frames (None: the gate tests every frame; (): none)
    checks: tuple | None = ()


@dataclass(slots=True)
class _CompiledRule:
    frame_cls: type
    instances: tuple[_Instance, ...]
    key_position: int | None
    match: tuple[tuple[int, Any], ...]
    kind: str = ""
    #: raw key value -> the instances it makes (a keyed rule counts the other values in ``unmapped_keys``)
    by_key: dict = field(default_factory=dict)


def _compile_rule(message: str, rule: dict, gate: FrameGate | None) -> _CompiledRule:
    if message not in MESSAGE_IDS_BY_NAME:
        raise MappingError(f"unknown message {message!r} in mapping (dialect ardupilotmega)")
    lay = layout(MESSAGE_IDS_BY_NAME[message])
    kind = rule.get("frame")
    if kind not in FRAME_KINDS:
        raise MappingError(f"{message}: unknown frame kind {kind!r}; known: {sorted(FRAME_KINDS)}")
    cls = FRAME_KINDS[kind]
    frame_fields = [f.name for f in dc_fields(cls)][1:]  # after time_s
    key = rule.get("key", {})
    key_target = key.get("target")
    if key and key_target not in frame_fields:
        raise MappingError(f"{message}: key target {key_target!r} is not a field of {cls.__name__}")
    specs = rule.get("fields", {})
    for name in specs:
        if name not in frame_fields:
            raise MappingError(f"{message}: {cls.__name__} has no field {name!r}")

    def instance(raw_key, element: int | None, key_value: str | None) -> _Instance:
        src = _Source()
        exprs, sources = [], []
        for name in frame_fields:
            if name == key_target:
                exprs.append(src.bind(key_value))
                sources.append(Constant(key_value))
            elif name in specs:
                sources.append(_resolve_field(specs[name], lay, element))
                exprs.append(_field_source(sources[-1], src))
            else:
                exprs.append("None")
                sources.append(Constant(None))
        # the gate looks a per-pack range up by the frame's field named after its kind: known
        # here unless a message field fills it
        gate_key = key_value if kind == key_target else None
        checks = None if kind in specs or gate is None else gate.ranges_for(cls, gate_key)
        return _Instance(raw_key, key_value, element, *_builders(lay, frame_fields, exprs, src, cls, gate, checks),
                         tuple(sources), () if gate is None else checks)

    instances: list[_Instance] = []
    key_position = None
    if "field" in key:
        if key["field"] not in lay.index:
            raise MappingError(f"{message} has no key field {key['field']!r}")
        key_position = lay.index[key["field"]]
        for raw, name in key.get("map", {}).items():
            instances.append(instance(int(raw), None, name))
    elif key.get("index"):
        for raw, name in key.get("map", {}).items():
            instances.append(instance(None, int(raw), name))
    else:
        const = key.get("const")
        instances.append(instance(None, None, const))
    match = []
    for fname, wanted in rule.get("match", {}).items():
        if fname not in lay.index:
            raise MappingError(f"{message}: match field {fname!r} does not exist")
        if isinstance(wanted, str):
            wanted = wanted.encode()
        match.append((lay.index[fname], wanted))
    by_key: dict = {}
    for inst in instances:
        if inst.raw_key is not None:
            by_key[inst.raw_key] = by_key.get(inst.raw_key, ()) + (inst,)
    return _CompiledRule(cls, tuple(instances), key_position, tuple(match), kind, by_key)


def _compile_mapping(mapping: dict, gate: FrameGate | None) -> dict[int, tuple[Any, list[_CompiledRule]]]:
    """msgid -> (its payload layout, its rules); ``gate``: the frames' plausibility gate, or None."""
    rules: dict[int, tuple[Any, list[_CompiledRule]]] = {}
    for message, message_rules in mapping.items():
        for rule in message_rules:
            compiled = _compile_rule(message, rule, gate)  # names an unknown message before the lookup below
            msgid = MESSAGE_IDS_BY_NAME[message]
            rules.setdefault(msgid, (layout(msgid), []))[1].append(compiled)
    return rules


def _emitter(lay, rules: list[_CompiledRule], stats: "MappingStats") -> Callable[[float, tuple], list]:
    """``emit(t, v)``: every frame the rules make from one unpacked message ``v`` at message time
    ``t``, counted; one function compiled per message type, so a message costs one call for its
    rules, not a loop over them (the rules' matches, keys and builders bound as constants)."""
    names: dict[str, Any] = {"_kinds": stats.frames_by_kind, "_unmapped": stats.unmapped_keys,
                             "_matches": _matches, "_name": lay.name}
    if all(rule.key_position is None and not rule.match for rule in rules):
        # the common case: every rule makes its frames from every message, so one list display
        makes = []
        for i, rule in enumerate(rules):
            for j, inst in enumerate(rule.instances):
                names[f"_m{i}_{j}"] = inst.make
                makes.append(f"_m{i}_{j}(t, v)")
        counts = Counter()
        for rule in rules:
            counts[rule.kind] += len(rule.instances)
        lines = ["def emit(t, v):"] + [f"    _kinds[{kind!r}] += {n}" for kind, n in counts.items()]
        lines.append(f"    return [{', '.join(makes)}]")
        exec(compile("\n".join(lines) + "\n", f"<emit {lay.name}>", "exec"), names)  # noqa: S102 - our own source
        return names["emit"]
    lines = ["def emit(t, v):", "    out = []"]
    for i, rule in enumerate(rules):
        indent = "    "
        if rule.match:
            tests = []
            for j, (pos, wanted) in enumerate(rule.match):
                names[f"_w{i}_{j}"] = wanted
                tests.append(f"_matches(v[{pos}], _w{i}_{j})")
            lines.append(f"    if {' and '.join(tests)}:")
            indent = "        "
        if rule.key_position is None:
            for j, inst in enumerate(rule.instances):
                names[f"_m{i}_{j}"] = inst.make
                lines.append(f"{indent}out.append(_m{i}_{j}(t, v))")
            lines.append(f"{indent}_kinds[{rule.kind!r}] += {len(rule.instances)}")
        else:
            names[f"_k{i}"] = {raw: tuple(inst.make for inst in insts) for raw, insts in rule.by_key.items()}
            lines += [f"{indent}makes = _k{i}.get(v[{rule.key_position}])",
                      f"{indent}if makes is None:",
                      f"{indent}    _unmapped[(_name, v[{rule.key_position}])] += 1",
                      f"{indent}else:",
                      f"{indent}    for make in makes:",
                      f"{indent}        out.append(make(t, v))",
                      f"{indent}    _kinds[{rule.kind!r}] += len(makes)"]
    lines.append("    return out")
    exec(compile("\n".join(lines) + "\n", f"<emit {lay.name}>", "exec"), names)  # noqa: S102 - our own source
    return names["emit"]


@dataclass(slots=True, frozen=True)
class _Dispatch:
    """What one message id costs in :meth:`FrameMapper.feed`, looked up once: the byte offset of its
    ``time_boot_ms`` (None: untimed) and, when the mapping makes frames from it, how to unpack it and
    its compiled rules."""

    time_offset: int | None
    size: int = 0
    unpack_from: Callable | None = None
    emit: Callable[[float, tuple], list] | None = None
    layout: Any = None
    rules: tuple = ()

    def values(self, buf, start: int, end: int) -> tuple:
        """The payload ``buf[start:end]`` unpacked, read in place when it has its full length."""
        if end - start >= self.size:  # longer (a newer dialect's extensions): the fields known here
            return self.unpack_from(buf, start)
        # zero-truncated (MAVLink 2), or without extensions (MAVLink 1): the layout pads it
        return self.layout.unpack(buf[start:end])


def _dispatch_table(rules: dict[int, tuple[Any, list[_CompiledRule]]], stats: "MappingStats") -> dict[int, _Dispatch]:
    """msgid -> :class:`_Dispatch` for every timed or mapped message (others: untimed and unmapped)."""
    table = {msgid: _Dispatch(offset) for msgid, offset in TIME_BOOT_MS_OFFSET.items()}
    for msgid, (lay, message_rules) in rules.items():
        table[msgid] = _Dispatch(TIME_BOOT_MS_OFFSET.get(msgid), lay.size, lay.struct.unpack_from,
                                 _emitter(lay, message_rules, stats), lay, tuple(message_rules))
    return table


@dataclass
class MappingStats:
    frames_by_kind: Counter = field(default_factory=Counter)
    other_source: int = 0  # messages from systems/components other than the vehicle
    before_vehicle: int = 0  # messages before the vehicle was identified
    undecodable: int = 0  # CRC-valid packets whose payload could not be unpacked
    unmapped_keys: Counter = field(default_factory=Counter)  # e.g. BATTERY_STATUS id 7
    time_rejected: int = 0  # vehicle messages dropped because their time_boot_ms was not accepted
    gated: Counter = field(default_factory=Counter)  # (kind, field, reason) -> values made missing (plausibility)

    def to_dict(self) -> dict:
        return {"frames_by_kind": dict(sorted(self.frames_by_kind.items())), "other_source": self.other_source,
                "before_vehicle": self.before_vehicle, "undecodable": self.undecodable,
                "unmapped_keys": {str(k): v for k, v in sorted(self.unmapped_keys.items())},
                "time_rejected": self.time_rejected,
                "gated": {f"{k}.{f}.{r}": n for (k, f, r), n in sorted(self.gated.items())}}


@dataclass
class ForeignSystem:
    """Another system sending vehicle (autopilot) heartbeats on our link: reported, never adopted."""

    system: int
    component: int
    heartbeats: int = 0
    first_seen_s: float | None = None  # our vehicle's message time when first heard (None before sync)
    last_seen_s: float | None = None

    def to_dict(self) -> dict:
        return {"system": self.system, "component": self.component, "heartbeats": self.heartbeats,
                "first_seen_s": self.first_seen_s, "last_seen_s": self.last_seen_s}


def _matches(value, wanted) -> bool:
    if isinstance(value, bytes):  # char[] fields: compare up to the NUL terminator
        return value.split(b"\0", 1)[0] == wanted
    return value == wanted


_HEARTBEAT = MESSAGE_IDS_BY_NAME["HEARTBEAT"]
_unpack_uint32 = struct.Struct("<I").unpack_from
_EMPTY: tuple = ()
_CLOCK_NOW = object()  # "the clock's time now"


class FrameMapper:
    """Turns packets (msgid, source, payload) into frames; one per vehicle, live or in replay.

    ``target_system``/``target_component`` None means: lock onto the first HEARTBEAT whose
    autopilot is not MAV_AUTOPILOT_INVALID (gimbals, cameras and ground stations send INVALID).
    The live service passes its configured system (default 1); ``None`` ("auto") is for replays
    and only on request live. Any other system sending autopilot heartbeats is recorded in
    ``foreign_systems`` (and logged once) and never adopted.

    ``envelope``: every frame is gated against it (``gcs_pdm.mavlink.plausibility``); the default
    is the default parameter set's, ``None`` turns gating off.
    """

    def __init__(self, mapping: dict | None = None, *, target_system: int | None = None,
                 target_component: int | None = None, sync_window_s: float = 30.0,
                 envelope: PhysicalEnvelope | None | str = "default"):
        self.mapping = default_mapping() if mapping is None else mapping
        if envelope == "default":
            envelope = default_envelope()
        self.stats = MappingStats()
        self.gate = FrameGate(envelope, self.stats.gated) if envelope is not None else None
        self.rules: dict[int, tuple[Any, list[_CompiledRule]]] = _compile_mapping(self.mapping, self.gate)
        self._dispatch = _dispatch_table(self.rules, self.stats)
        self.target_system = target_system
        self.target_component = target_component
        self.locked = target_system is not None and target_component is not None
        self.clock = VehicleClock(sync_window_s)
        self.foreign_systems: dict[int, ForeignSystem] = {}
        # frames held until the clock has a time: (receive time, own time_boot s or None, class, values)
        self._pending: list[tuple[float, float | None, type, tuple]] = []

    def remap(self, mapping: dict, envelope: PhysicalEnvelope | None = None) -> None:
        """Another vehicle layout (a description derived from the first telemetry), keeping the
        clock and the vehicle lock. The rules are swapped in one assignment: the reader thread
        maps each packet with the old rules or the new, never a mix."""
        gate = FrameGate(envelope, self.stats.gated) if envelope is not None else self.gate
        rules = _compile_mapping(mapping, gate)  # the rules carry their gate
        dispatch = _dispatch_table(rules, self.stats)
        self.gate = gate
        self.mapping = mapping
        self.rules = rules
        self._dispatch = dispatch  # what feed() reads

    @property
    def dispatch(self) -> dict[int, _Dispatch]:
        """msgid -> how :meth:`feed` handles it (time field, unpacking, compiled rules)."""
        return self._dispatch

    def settled(self) -> bool:
        """The vehicle is identified, the clock gives times (vehicle or receive time) and no frame
        is held for one: from here on a message's frames depend only on it and on the clock, and
        they never wait (what lets a replay map the rest of a log a message type at a time)."""
        return self.locked and (self.clock.synced or self.clock.fallback) and not self._pending

    def _note_foreign(self, sysid: int, compid: int, payload, now: Any = _CLOCK_NOW) -> None:
        """A heartbeat from a system that is not our vehicle: record it if it claims to be an autopilot
        (``now``: our vehicle's message time then; by default the clock's)."""
        lay = layout(_HEARTBEAT)
        try:
            autopilot = lay.unpack(payload)[lay.index["autopilot"]]
        except Exception:  # noqa: BLE001 - a bad payload is counted elsewhere
            return
        if autopilot == MAV_AUTOPILOT_INVALID:
            return  # ground stations, gimbals, cameras, routers: expected company
        seen = self.foreign_systems.get(sysid)
        if now is _CLOCK_NOW:
            now = self.clock.now
        if seen is None:
            seen = self.foreign_systems[sysid] = ForeignSystem(sysid, compid, first_seen_s=now)
            log.warning("system %d (component %d) sends vehicle heartbeats on this link; it is NOT the tracked "
                        "vehicle (system %s) and is ignored", sysid, compid,
                        self.target_system if self.target_system is not None else "not yet identified")
        seen.heartbeats += 1
        seen.last_seen_s = now

    def _try_lock(self, msgid: int, sysid: int, compid: int, payload) -> bool:
        if msgid != _HEARTBEAT:
            return False
        if self.target_system is not None and sysid != self.target_system:
            return False
        if self.target_component is not None and compid != self.target_component:
            return False
        lay = layout(_HEARTBEAT)
        vals = lay.unpack(payload)
        if vals[lay.index["autopilot"]] == MAV_AUTOPILOT_INVALID:
            return False
        self.target_system, self.target_component, self.locked = sysid, compid, True
        log.info("vehicle identified: system %d component %d", sysid, compid)
        return True

    def feed(self, recv_s: float, msgid: int, sysid: int, compid: int, payload) -> list | tuple:
        """Frames produced by one CRC-checked packet (often none). ``recv_s``: receive/tlog time."""
        return self.feed_from(recv_s, msgid, sysid, compid, payload, 0, len(payload))

    def feed_from(self, recv_s: float, msgid: int, sysid: int, compid: int, buf, start: int, end: int) -> list | tuple:
        """:meth:`feed` of the payload ``buf[start:end]``, read in place (a replay passes the whole
        tlog's bytes and each record's bounds: no slice per message)."""
        if not self.locked or sysid != self.target_system or compid != self.target_component:
            payload = buf[start:end]
            if msgid == _HEARTBEAT and self.target_system is not None and sysid != self.target_system:
                self._note_foreign(sysid, compid, payload)
            if not self.locked:
                if not self._try_lock(msgid, sysid, compid, payload):
                    self.stats.before_vehicle += 1
                    return _EMPTY
            else:
                self.stats.other_source += 1
                return _EMPTY
        clock = self.clock
        plan = self._dispatch.get(msgid)
        if plan is None:  # untimed and unmapped: it only dates frames held before the clock existed
            if clock.synced:
                return self._release_pending(clock.now, recv_s) if self._pending else _EMPTY
            t = clock.untimed(recv_s, msgid)
            if t is Verdict.REJECTED:  # a receive time the others disagree with (after the fallback)
                self.stats.time_rejected += 1
                return _EMPTY
            return self._release_pending(t, recv_s) if t is not None and self._pending else _EMPTY
        time_offset = plan.time_offset
        boot_s = released = None
        if time_offset is not None:
            at = start + time_offset
            if at + 4 <= end:
                boot_s = _unpack_uint32(buf, at)[0] / 1000.0
            else:  # MAVLink 2 truncates trailing zero bytes: a shorter field is little-endian all the same
                boot_s = int.from_bytes(buf[at:end], "little") / 1000.0
            t = clock.on_time_boot(boot_s, recv_s, msgid)
            if t.__class__ is Verdict:
                if t is Verdict.FALLBACK:
                    t = clock.receive_time(recv_s, msgid)
                if t is Verdict.REJECTED:
                    self.stats.time_rejected += 1
                    return _EMPTY
                if t is Verdict.ACQUIRING:
                    t = None  # hold the frames
            if t is not None and self._pending:
                released = self._release_pending(t, recv_s)
        else:
            t = clock.now if clock.synced else clock.untimed(recv_s, msgid)
            if t is Verdict.REJECTED:
                self.stats.time_rejected += 1
                return _EMPTY
            if t is not None and self._pending:
                released = self._release_pending(t, recv_s)
        emit = plan.emit
        if emit is None:
            return released or _EMPTY
        try:
            vals = plan.values(buf, start, end)
        except Exception:  # noqa: BLE001 - a bad payload is counted, never fatal
            self.stats.undecodable += 1
            return released or _EMPTY
        if t is not None:
            out = emit(t, vals)  # gated as they are made
        else:
            out = []
            self._hold(plan, vals, recv_s, boot_s)
        return released + out if released else out

    def _hold(self, plan: _Dispatch, vals: tuple, recv_s: float, boot_s: float | None) -> None:
        """Frames of a message that came before the clock had a time: kept as their values."""
        for rule in plan.rules:
            if rule.match and not all(_matches(vals[pos], wanted) for pos, wanted in rule.match):
                continue
            if rule.key_position is None:
                instances = rule.instances
            else:
                instances = rule.by_key.get(vals[rule.key_position])
                if instances is None:
                    self.stats.unmapped_keys[(plan.layout.name, vals[rule.key_position])] += 1
                    continue
            self._pending.extend((recv_s, boot_s, rule.frame_cls, inst.build(vals)) for inst in instances)

    def _gated(self, frames: list) -> list:
        gate = self.gate
        return [gate(f) for f in frames]

    def _release_pending(self, t_now: float, recv_now: float) -> list:
        """Frames held before the clock existed. A timed message gets its own time if it agrees with
        the adopted time (else it is dropped: it was the odd one out); an untimed one the latest
        timed time before it ("hold last"), or, before any, is back-dated by receive time from the
        first timed one."""
        out = []
        clock = self.clock
        fallback = clock.fallback
        anchor = next(((boot_s + clock.epoch_s, recv_s) for recv_s, boot_s, _c, _a in self._pending
                       if boot_s is not None and clock.agrees(boot_s)), (t_now, recv_now))
        held = None
        for recv_s, boot_s, cls, args in self._pending:
            if fallback:
                t = recv_s
            elif boot_s is not None:
                if not clock.agrees(boot_s):
                    self.stats.time_rejected += 1
                    continue
                t = held = boot_s + clock.epoch_s
            elif held is not None:
                t = held
            else:
                t = max(0.0, anchor[0] - (anchor[1] - recv_s))
            out.append(cls(t, *args))
            self.stats.frames_by_kind[FRAME_KIND_OF[cls]] += 1
        self._pending.clear()
        return self._gated(out) if self.gate is not None else out

    def flush(self) -> list:
        """At the end of a replay: frames still waiting for a clock, stamped with receive time."""
        out = [cls(recv_s, *args) for recv_s, _boot, cls, args in self._pending]
        self._pending.clear()
        for frame in out:
            self.stats.frames_by_kind[FRAME_KIND_OF[type(frame)]] += 1
        return self._gated(out) if self.gate is not None else out
