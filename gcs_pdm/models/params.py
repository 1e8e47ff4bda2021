"""Parameter sets for the propulsion models: validated, JSON-serialisable, with units.

A parameter set holds, for each of the four packs, the battery equivalent-circuit parameters
(paper eqs. 1–6) and the pack's thermal parameters (eq. 7), and the motors' electrical/thermal
parameters. The kernel works on flat float vectors; ``pack_vector``/``motor_vector`` give them in
the fixed layouts of ``gcs_pdm.models.kernel``.

Built-in sets (see docs/model.md for the unit reading):

* ``paper``        — Tables I and II as printed, verbatim. Not physical as printed (R_p = 1e-4 Ω
                     would drain a pack in a fraction of a second); kept as the record.
* ``previous``     — the paper's "previous" rows, verbatim.
* ``paper_si``     — the physical reading of ``paper``; the default set.
* ``previous_si``  — the physical reading of ``previous``; the prior of the Table III experiment.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from gcs_pdm.models.variants import MODEL_VARIANTS

PACK_NAMES: tuple[str, ...] = ("LLF20", "ULA20", "LRF40", "URA40")
MOTOR_NAMES: tuple[str, ...] = ("fwd", "aft")

CELLS_PER_PACK = 5
PACK_CAPACITY_AH = 7.8
#: Usable charge of a 7800 mAh pack, C.
PACK_CAPACITY_C = PACK_CAPACITY_AH * 3600.0
#: Open-circuit voltage of a full 5S LiPo pack (4.2 V/cell).
PACK_FULL_VOLTAGE = 4.2 * CELLS_PER_PACK


class ParameterError(ValueError):
    """A parameter value that no physical component can have; the message names the field."""


def _unit(u: str, doc: str) -> Any:
    return field(metadata={"unit": u, "doc": doc})


@dataclass(frozen=True)
class BatteryParams:
    """Equivalent circuit of one pack (paper Fig. 2, eqs. 1–6)."""

    R_s: float = _unit("ohm", "series (ohmic) resistance of the R_s–C_s pair")
    R_p: float = _unit("ohm", "parasitic (self-discharge) resistance")
    R_cp0: float = _unit("ohm", "concentration-polarisation resistance, constant term")
    R_cp1: float = _unit("ohm", "concentration-polarisation resistance, exponential coefficient")
    R_cp2: float = _unit("1", "concentration-polarisation resistance, exponential rate in (1 - SoC)")
    C_s: float = _unit("F", "capacitance of the R_s–C_s pair")
    C_b: float = _unit("F", "bulk capacitance holding the charge q_b")
    C_cp: float = _unit("F", "concentration-polarisation capacitance")
    q_max: float = _unit("C", "charge q_b of a full pack (q_b = C_b * V_b)")
    C_max: float = _unit("C", "usable capacity: SoC = 1 - (q_max - q_b)/C_max")


@dataclass(frozen=True)
class ThermalParams:
    """Lumped thermal model (eq. 7): C_t dT/dt = R I^2 + h (T_a - T)."""

    C_t: float = _unit("J/K", "thermal inertia")
    h: float = _unit("W/K", "heat transfer coefficient to ambient")


#: open-circuit voltage per cell (V) at the kernel's knots ``EXT_OCV_SOC`` = 0, 0.03, 0.07, 0.12, 0.2,
#: 0.25 … 0.7, 0.725 … 1.0: typical discharge curves at rest (C/20, 25 °C) of a LiPo (LiCoO2/graphite) and a
#: Li-ion NMC/graphite cell. Starting points and fallbacks; a fit learns the pack's own.
OCV_PER_CELL: Mapping[str, tuple[float, ...]] = {
    "lipo": (
        3.27, 3.45, 3.6, 3.68, 3.73, 3.752, 3.77, 3.785, 3.8, 3.819, 3.84, 3.859, 3.88, 3.913, 3.95, 3.967, 3.984,
        4.002, 4.02, 4.039, 4.058, 4.078, 4.1, 4.123, 4.147, 4.173, 4.2),
    "li-ion": (
        3.0, 3.3, 3.42, 3.5, 3.57, 3.602, 3.63, 3.656, 3.68, 3.704, 3.73, 3.763, 3.8, 3.839, 3.88, 3.9, 3.919, 3.939,
        3.96, 3.983, 4.007, 4.033, 4.06, 4.088, 4.117, 4.148, 4.18),
}
CHEMISTRIES: tuple[str, ...] = tuple(OCV_PER_CELL)
#: extended-variant values other than the OCV for a 5S 7.8 Ah pack (docs/model.md)
_EXTENDED_DEFAULTS = dict(R_0=0.02, R_1=0.01, tau_1=20.0, R_2=0.01, tau_2=300.0, E_r=2500.0, E_ct=4000.0, k_soc=0.3, soc_knee=0.1,
                          b_ct=0.1, i_ct=20.0, k_d=1.0, tau_d=600.0,
                          C_max=PACK_CAPACITY_C, C_t=1000.0, h=2.0, dU_dT=0.0)
#: extended-variant fields that may be zero (the rest must be > 0); dU_dT may have either sign
_EXTENDED_MAY_BE_ZERO = {"E_r", "E_ct", "k_soc"}


def extended_default(chemistry: str = "lipo", cells: int = CELLS_PER_PACK) -> dict[str, float]:
    """Extended-variant values (EXT_PACK_PARAMS names) for a pack of ``cells`` in series."""
    from gcs_pdm.models.kernel import EXT_PACK_PARAMS

    try:
        ocv = np.asarray(OCV_PER_CELL[chemistry]) * cells
    except KeyError:
        raise ParameterError(f"chemistry: expected one of {', '.join(CHEMISTRIES)}, got {chemistry!r}") from None
    values = dict(_EXTENDED_DEFAULTS, ocv_0=float(ocv[0]))
    values.update({f"docv_{k}": float(ocv[k] - ocv[k - 1]) for k in range(1, len(ocv))})
    return {k: float(values[k]) for k in EXT_PACK_PARAMS}


@dataclass(frozen=True)
class PackParams:
    """One pack: the paper's circuit and thermal values, and which model variant the pack uses.

    ``model`` "paper" simulates ``battery``/``thermal`` (eqs. 1–7); "extended" simulates
    ``extended`` (kernel EXT_PACK_PARAMS names; docs/model.md). An extended pack keeps paper values
    too, so users of the kernel's paper layout (the powertrain) still have a circuit for it.
    """

    battery: BatteryParams
    thermal: ThermalParams
    model: str = "paper"
    extended: Mapping[str, float] | None = None

    def extended_vector(self) -> np.ndarray:
        from gcs_pdm.models.kernel import EXT_PACK_PARAMS

        if self.extended is None:
            raise ParameterError("this pack has no extended-variant values")
        return np.array([self.extended[k] for k in EXT_PACK_PARAMS], dtype=np.float64)


@dataclass(frozen=True)
class MotorParams:
    """One AXI 5330/F3A-class out-runner; both motors share these (one bracket sensor, paper §IV).

    Heat in the motor is ``R_w I^2 + P_iron`` (eq. 7 with R = R_w, plus a constant core loss so a
    lightly loaded motor still warms as real ones do; P_iron = 0 gives eq. 7 exactly).
    """

    R_w: float = _unit("ohm", "winding resistance (copper loss R_w I^2)")
    I_0: float = _unit("A", "no-load current (friction, windage, core loss)")
    P_iron: float = _unit("W", "part of the no-load loss dissipated as heat in the motor")
    C_t: float = _unit("J/K", "thermal inertia of motor and bracket")
    h: float = _unit("W/K", "heat transfer coefficient to ambient")


@dataclass(frozen=True)
class ParameterSet:
    name: str
    packs: Mapping[str, PackParams]
    motor: MotorParams
    description: str = ""
    #: False for verbatim transcriptions that are not physical as printed (never flown).
    physical: bool = True
    provenance: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        validate(self)

    # -- vectors for the kernel -------------------------------------------------------------
    def pack_matrix(self) -> np.ndarray:
        """(4, PACK_PARAM_COUNT) in PACK_NAMES order: the paper's four-pack layout (a vehicle's set,
        whose packs are a description's, has no such matrix: read its packs by name)."""
        missing = [n for n in PACK_NAMES if n not in self.packs]
        if missing:
            raise ParameterError(f"packs: missing {', '.join(missing)} (the paper's four-pack layout); this set's "
                                 f"packs are {', '.join(self.packs)}")
        return np.stack([pack_vector(self.packs[n]) for n in PACK_NAMES])

    def motor_vector(self) -> np.ndarray:
        return motor_vector(self.motor)

    # -- JSON --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "physical": self.physical,
            "provenance": dict(self.provenance),
            "packs": {n: _pack_dict(p) for n, p in self.packs.items()},
            "motor": dataclasses.asdict(self.motor),
            "units": units(),
        }

    def to_json(self, **kw: Any) -> str:
        return json.dumps(self.to_dict(), **kw)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "ParameterSet":
        try:
            packs_in = data["packs"]
            # the paper's four packs, or any packs of a vehicle's set (gcs-pdm fit --vehicle)
            names = PACK_NAMES if all(n in packs_in for n in PACK_NAMES) else tuple(packs_in)
            packs = {
                n: PackParams(
                    battery=_build(BatteryParams, packs_in[n]["battery"], f"packs.{n}.battery"),
                    thermal=_build(ThermalParams, packs_in[n]["thermal"], f"packs.{n}.thermal"),
                    model=str(packs_in[n].get("model", "paper")),
                    extended=(_build_extended(packs_in[n]["extended"], f"packs.{n}.extended")
                              if packs_in[n].get("extended") is not None else None),
                )
                for n in names
            }
            motor = _build(MotorParams, data["motor"], "motor")
        except KeyError as exc:
            raise ParameterError(f"missing field {exc.args[0]!r}") from None
        except TypeError as exc:
            raise ParameterError(f"malformed parameter set: {exc}") from None
        return cls(
            name=str(data.get("name", "unnamed")),
            packs=packs,
            motor=motor,
            description=str(data.get("description", "")),
            physical=bool(data.get("physical", True)),
            provenance=dict(data.get("provenance", {})),
        )

    @classmethod
    def from_json(cls, text: str) -> "ParameterSet":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ParameterError(f"not JSON: {exc}") from None
        return cls.from_dict(data)

    def replace(self, **changes: Any) -> "ParameterSet":
        return dataclasses.replace(self, **changes)

    def with_pack(self, name: str, pack: PackParams) -> "ParameterSet":
        packs = dict(self.packs)
        packs[name] = pack
        return dataclasses.replace(self, packs=packs)


def _build(cls: type, values: Mapping[str, Any], where: str) -> Any:
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [n for n in names if n not in values]
    if missing:
        raise ParameterError(f"{where}.{missing[0]}: missing")
    out = {}
    for n in names:
        v = values[n]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ParameterError(f"{where}.{n}: expected a number, got {v!r}")
        out[n] = float(v)
    return cls(**out)


def _pack_dict(p: PackParams) -> dict[str, Any]:
    out: dict[str, Any] = {"model": p.model, "battery": dataclasses.asdict(p.battery),
                           "thermal": dataclasses.asdict(p.thermal)}
    if p.extended is not None:
        out["extended"] = {k: float(v) for k, v in p.extended.items()}
    return out


def _build_extended(values: Mapping[str, Any], where: str) -> dict[str, float]:
    from gcs_pdm.models.kernel import EXT_PACK_PARAMS

    missing = [n for n in EXT_PACK_PARAMS if n not in values]
    if missing:
        raise ParameterError(f"{where}.{missing[0]}: missing")
    out = {}
    for n in EXT_PACK_PARAMS:
        v = values[n]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ParameterError(f"{where}.{n}: expected a number, got {v!r}")
        out[n] = float(v)
    return out


#: units of the extended variant's values (docs/model.md)
EXTENDED_UNITS: Mapping[str, str] = {
    "R_0": "ohm", "R_1": "ohm", "tau_1": "s", "R_2": "ohm", "tau_2": "s", "E_r": "K", "E_ct": "K", "k_soc": "1", "soc_knee": "1",
    "b_ct": "V", "i_ct": "A", "k_d": "s", "tau_d": "s",
    "C_max": "C", "C_t": "J/K", "h": "W/K", "dU_dT": "V/K", "ocv_0": "V",
}


def units() -> dict[str, dict[str, str]]:
    out = {
        cls.__name__: {f.name: f.metadata["unit"] for f in dataclasses.fields(cls)}
        for cls in (BatteryParams, ThermalParams, MotorParams)
    }
    from gcs_pdm.models.kernel import EXT_PACK_PARAMS

    out["extended"] = {k: EXTENDED_UNITS.get(k, "V") for k in EXT_PACK_PARAMS}
    return out


# Fields that may be zero (everything else must be strictly positive).
_MAY_BE_ZERO = {"R_cp1", "R_cp2", "P_iron", "I_0"}


def _check_record(obj: Any, where: str) -> None:
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise ParameterError(f"{where}.{f.name}: expected a number, got {v!r}")
        if not math.isfinite(v):
            raise ParameterError(f"{where}.{f.name}: must be finite, got {v!r}")
        if v < 0 or (v == 0 and f.name not in _MAY_BE_ZERO):
            raise ParameterError(f"{where}.{f.name}: must be {'>= 0' if f.name in _MAY_BE_ZERO else '> 0'} "
                                 f"{f.metadata['unit']}, got {v!r}")


def _check_variant(p: PackParams, where: str) -> None:
    if p.model not in MODEL_VARIANTS:
        raise ParameterError(f"{where}.model: expected one of {', '.join(MODEL_VARIANTS)}, got {p.model!r}")
    if p.model == "extended" and p.extended is None:
        raise ParameterError(f"{where}.extended: an extended pack needs its extended-variant values")
    if p.extended is None:
        return
    for k, v in _build_extended(p.extended, f"{where}.extended").items():
        if not math.isfinite(v):
            raise ParameterError(f"{where}.extended.{k}: must be finite, got {v!r}")
        if k == "dU_dT":
            continue
        if v < 0 or (v == 0 and k not in _EXTENDED_MAY_BE_ZERO):
            # docv_* > 0 is what keeps the open-circuit voltage monotone in SoC
            raise ParameterError(f"{where}.extended.{k}: must be {'>= 0' if k in _EXTENDED_MAY_BE_ZERO else '> 0'}"
                                 f" {EXTENDED_UNITS.get(k, 'V')}, got {v!r}")


def validate(ps: ParameterSet) -> None:
    if not ps.packs:
        raise ParameterError("packs: a parameter set needs at least one pack")
    for n in ps.packs:
        _check_record(ps.packs[n].battery, f"packs.{n}.battery")
        _check_record(ps.packs[n].thermal, f"packs.{n}.thermal")
        _check_variant(ps.packs[n], f"packs.{n}")
        b = ps.packs[n].battery
        if b.C_max > b.q_max:
            raise ParameterError(f"packs.{n}.battery.C_max: usable capacity {b.C_max} C exceeds q_max {b.q_max} C")
    _check_record(ps.motor, "motor")


# ---- flat vectors (layouts defined by the kernel) ------------------------------------------------

def pack_vector(p: PackParams) -> np.ndarray:
    from gcs_pdm.models.kernel import PACK_PARAMS

    values = {**dataclasses.asdict(p.battery), **dataclasses.asdict(p.thermal)}
    return np.array([values[k] for k in PACK_PARAMS], dtype=np.float64)


def pack_from_vector(v: np.ndarray) -> PackParams:
    from gcs_pdm.models.kernel import PACK_PARAMS

    d = dict(zip(PACK_PARAMS, (float(x) for x in v)))
    return PackParams(
        battery=BatteryParams(**{f.name: d[f.name] for f in dataclasses.fields(BatteryParams)}),
        thermal=ThermalParams(C_t=d["C_t"], h=d["h"]),
    )


def motor_vector(m: MotorParams) -> np.ndarray:
    from gcs_pdm.models.kernel import MOTOR_PARAMS

    d = dataclasses.asdict(m)
    return np.array([d[k] for k in MOTOR_PARAMS], dtype=np.float64)


def motor_from_vector(v: np.ndarray) -> MotorParams:
    from gcs_pdm.models.kernel import MOTOR_PARAMS

    return MotorParams(**dict(zip(MOTOR_PARAMS, (float(x) for x in v))))


# ---- the paper's tables, verbatim ----------------------------------------------------------------

# Table I as printed: R_s(x1e-3) R_p(x1e-4) R_cp0(x1e-2) R_cp1(x1e-16) R_cp2 C_s C_b C_cp
_TABLE_I = {
    "LLF20": (7.4, 0.9, 3.0, 1.2, 34.41, 112.3, 18.3, 316.1),
    "ULA20": (7.3, 1.0, 2.9, 1.1, 34.42, 111.2, 17.9, 317.7),
    "LRF40": (7.3, 1.1, 3.1, 1.1, 34.42, 112.8, 18.0, 317.2),
    "URA40": (7.1, 1.1, 3.4, 1.0, 34.46, 113.6, 18.2, 316.9),
}
_TABLE_I_PREVIOUS = (8.0, 1.0, 2.0, 1.1, 36.00, 115.0, 20.0, 315.0)
_TABLE_I_SCALE = (1e-3, 1e-4, 1e-2, 1e-16, 1.0, 1.0, 1.0, 1.0)
# Table II as printed: C_t(x1e-4), h
_TABLE_II = {
    "LLF20": (20.76, 11.68),
    "ULA20": (19.52, 11.94),
    "LRF40": (21.12, 11.38),
    "URA40": (18.27, 10.41),
}
_TABLE_II_BATTERY_PREVIOUS = (15.00, 12.00)
_TABLE_II_MOTOR = (10.32, 11.17)
_TABLE_II_MOTOR_PREVIOUS = (12.00, 10.00)
_TABLE_II_SCALE = (1e-4, 1.0)

# What the paper does not give: the pack's charge bookkeeping and the motor's electrical data.
# q_max for the verbatim sets follows q_b = C_b V_b at a full pack.
_AXI_5330 = dict(R_w=0.030, I_0=1.6, P_iron=15.0)

# ---- the physical reading (docs/model.md explains each factor) -----------------------------------
#: printed value x factor = SI value used by the *_si sets, in Table I column order.
READING_TABLE_I = (1e-3, 1e4, 1e-2, 1e-16, 1.0, 1.0, 1e3, 1.0)
#: C_t printed x 50 -> J/K (about 1 kJ/K for a 1 kg pack); h printed / 10 -> W/K.
READING_TABLE_II_PACK = (50.0, 0.1)
#: the motor and its aluminium bracket: C_t printed x 50 -> J/K, h printed / 10 -> W/K.
READING_TABLE_II_MOTOR = (50.0, 0.1)


def _pack(table_i: tuple[float, ...], scale_i: tuple[float, ...], table_ii: tuple[float, float],
          scale_ii: tuple[float, float]) -> PackParams:
    R_s, R_p, R_cp0, R_cp1, R_cp2, C_s, C_b, C_cp = (v * s for v, s in zip(table_i, scale_i))
    C_t, h = (v * s for v, s in zip(table_ii, scale_ii))
    q_max = C_b * PACK_FULL_VOLTAGE
    C_max = min(PACK_CAPACITY_C, q_max)
    return PackParams(
        BatteryParams(R_s=R_s, R_p=R_p, R_cp0=R_cp0, R_cp1=R_cp1, R_cp2=R_cp2, C_s=C_s, C_b=C_b, C_cp=C_cp,
                      q_max=q_max, C_max=C_max),
        ThermalParams(C_t=C_t, h=h),
    )


def _motor(table_ii: tuple[float, float], scale: tuple[float, float]) -> MotorParams:
    return MotorParams(C_t=table_ii[0] * scale[0], h=table_ii[1] * scale[1], **_AXI_5330)


def _build_sets() -> dict[str, ParameterSet]:
    paper = ParameterSet(
        name="paper",
        description="Tables I and II of the paper, verbatim as printed (not physical as printed)",
        physical=False,
        packs={n: _pack(_TABLE_I[n], _TABLE_I_SCALE, _TABLE_II[n], _TABLE_II_SCALE) for n in PACK_NAMES},
        motor=_motor(_TABLE_II_MOTOR, _TABLE_II_SCALE),
        provenance={"source": "paper Tables I and II"},
    )
    previous = ParameterSet(
        name="previous",
        description="The paper's 'previous' parameter rows, verbatim as printed (not physical as printed)",
        physical=False,
        packs={n: _pack(_TABLE_I_PREVIOUS, _TABLE_I_SCALE, _TABLE_II_BATTERY_PREVIOUS, _TABLE_II_SCALE)
               for n in PACK_NAMES},
        motor=_motor(_TABLE_II_MOTOR_PREVIOUS, _TABLE_II_SCALE),
        provenance={"source": "paper Tables I and II, 'previous' rows"},
    )
    paper_si = ParameterSet(
        name="paper_si",
        description="Physical reading of the paper's learned values (docs/model.md); the default set",
        packs={n: _pack(_TABLE_I[n], READING_TABLE_I, _TABLE_II[n], READING_TABLE_II_PACK) for n in PACK_NAMES},
        motor=_motor(_TABLE_II_MOTOR, READING_TABLE_II_MOTOR),
        provenance={"source": "paper Tables I and II", "reading": "docs/model.md"},
    )
    previous_si = ParameterSet(
        name="previous_si",
        description="Physical reading of the paper's 'previous' values (docs/model.md); the prior",
        packs={n: _pack(_TABLE_I_PREVIOUS, READING_TABLE_I, _TABLE_II_BATTERY_PREVIOUS, READING_TABLE_II_PACK)
               for n in PACK_NAMES},
        motor=_motor(_TABLE_II_MOTOR_PREVIOUS, READING_TABLE_II_MOTOR),
        provenance={"source": "paper Tables I and II, 'previous' rows", "reading": "docs/model.md"},
    )
    return {s.name: s for s in (paper, previous, paper_si, previous_si)}


BUILTIN_SETS: Mapping[str, ParameterSet] = _build_sets()
DEFAULT_SET_NAME = "paper_si"


def builtin(name: str = DEFAULT_SET_NAME) -> ParameterSet:
    try:
        return BUILTIN_SETS[name]
    except KeyError:
        raise KeyError(f"no built-in parameter set {name!r}; have {', '.join(BUILTIN_SETS)}") from None


def default_set() -> ParameterSet:
    return BUILTIN_SETS[DEFAULT_SET_NAME]


def degraded(params: ParameterSet, pack: str, capacity: float = 1.0, resistance: float = 1.0) -> ParameterSet:
    """``params`` with one pack aged: its charge-holding capacitance and capacity scaled by
    ``capacity`` (C_b, q_max, C_max together, so it is still full at 4.2 V/cell) and its plateau
    resistances R_s and R_cp0 by ``resistance``."""
    if pack not in params.packs:
        raise ParameterError(f"packs: no pack {pack!r}; have {', '.join(PACK_NAMES)}")
    if not (capacity > 0.0 and resistance > 0.0):
        raise ParameterError(f"degradation of {pack}: capacity and resistance factors must be > 0, "
                             f"got {capacity!r}, {resistance!r}")
    b = params.packs[pack].battery
    aged = dataclasses.replace(b, C_b=b.C_b * capacity, q_max=b.q_max * capacity, C_max=b.C_max * capacity,
                               R_s=b.R_s * resistance, R_cp0=b.R_cp0 * resistance)
    return params.with_pack(pack, PackParams(aged, params.packs[pack].thermal))


def perturbed(base: ParameterSet, rng: np.random.Generator, rel: float = 0.1, name: str = "perturbed",
              ) -> ParameterSet:
    """A set whose parameters differ from ``base`` by random factors in [1-rel, 1+rel]
    (log-uniform) — used for hidden "true" vehicles and synthetic flights. q_max keeps tracking
    C_b so a full pack stays at 4.2 V/cell, and C_max stays at the rated capacity."""
    from gcs_pdm.models.kernel import PACK_PARAMS

    packs = {}
    for n in PACK_NAMES:
        v = pack_vector(base.packs[n])
        base_v = v.copy()
        v = v * np.exp(rng.uniform(np.log(1 - rel), np.log(1 + rel), size=v.shape))
        i_cb, i_qmax, i_cmax = (PACK_PARAMS.index(k) for k in ("C_b", "q_max", "C_max"))
        # R_cp2 sits in an exponent: move it by a tenth of the spread, and perturb the end-of-discharge
        # resistance R_cp1 exp(R_cp2) by the spread itself, so the knee stays a LiPo knee
        i_r1, i_r2 = PACK_PARAMS.index("R_cp1"), PACK_PARAMS.index("R_cp2")
        v[i_r2] = base_v[i_r2] * (1.0 + rng.uniform(-rel, rel) / 10.0)
        v[i_r1] = v[i_r1] * np.exp(base_v[i_r2] - v[i_r2])
        v[i_qmax] = v[i_cb] * PACK_FULL_VOLTAGE
        # a pack holds its rated capacity (capacity loss is pack degradation, modelled apart): it
        # cannot be learned from flights that never reach empty, so it must not hide in the truth
        v[i_cmax] = min(base_v[i_cmax], v[i_qmax])
        packs[n] = pack_from_vector(v)
    m = motor_vector(base.motor) * np.exp(rng.uniform(np.log(1 - rel), np.log(1 + rel), size=5))
    return ParameterSet(name=name, packs=packs, motor=motor_from_vector(m),
                        description=f"{base.name} perturbed by up to {rel:.0%}",
                        provenance={"base": base.name, "relative_spread": rel})
