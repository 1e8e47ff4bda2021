"""Fitting a described vehicle's own packs (``gcs-pdm fit battery --vehicle FILE|PRESET``).

Each pack of the description is fitted from its own series in the logs (a tlog's BATTERY_STATUS
id, an autopilot log's DataFlash instance), with the search ranges and the starting point carried
to its cells in series and capacity (``fitting.problem.battery_bounds``, ``models.pack_scaling``).
The values a fit does not learn — the thermal ones when the logs carry no pack temperature — are
the pack's own: the chemistry default scaled to it (or whatever its description points at).

The result is a parameter set whose packs are the description's packs (by name), with the packs'
formats in its provenance, and a copy of the description whose fitted packs point at that set:
``gcs-pdm vehicle check DIR/vehicle.toml``, then ``serve``/``replay --vehicle DIR/vehicle.toml``.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from gcs_pdm.fitting import problem as pb
from gcs_pdm.models import kernel
from gcs_pdm.models.chemistry import chemistry as chemistry_table
from gcs_pdm.models.pack_scaling import scale_values
from gcs_pdm.models.params import (CELLS_PER_PACK, OCV_PER_CELL, PACK_CAPACITY_C, ParameterSet, builtin,
                                   extended_default, motor_from_vector, pack_from_vector)
from gcs_pdm.vehicle.description import PackSpec, VehicleDescription, dumps, from_dict
from gcs_pdm.vehicle.model_inputs import model_inputs, pack_parameters

#: the hand-written knot curves (models.params.OCV_PER_CELL) the chemistries that have one start from;
#: any other chemistry of models.chemistry starts from its own rested table (``ocv_knots_per_cell``)
OCV_CURVE_OF_CHEMISTRY = {"lipo": "lipo", "lihv": "lipo", "liion": "li-ion"}


def pack_format(spec: PackSpec) -> pb.PackFormat:
    """The pack's cells, capacity and its chemistry's rested empty and full cell: the fit's ranges
    are the cells times the chemistry's per-cell ones (``problem.scaled_bounds``)."""
    empty, full = chemistry_ocv_ends(spec.chemistry)
    return pb.PackFormat(cells=spec.cells_series, capacity_c=spec.capacity_c, full_cell_voltage=spec.full_cell_v,
                         empty_ocv_cell_v=empty, full_ocv_cell_v=full)


def ocv_knots_per_cell(chemistry: str) -> np.ndarray:
    """The rested cell voltage at the kernel's knots (``kernel.EXT_OCV_SOC``) an extended fit of this
    chemistry starts from: its hand-written knot curve where it has one (LiHV: the LiPo's, stretched
    to its full voltage by ``extended_start``), else its models.chemistry table sampled at the knots
    (LiFePO4). An unknown chemistry: ValueError naming the known ones."""
    table = chemistry_table(chemistry)
    curve = OCV_CURVE_OF_CHEMISTRY.get(chemistry)
    if curve is not None:
        return np.asarray(OCV_PER_CELL[curve], dtype=np.float64)
    knots = np.array([table.ocv(float(s)) for s in kernel.EXT_OCV_SOC])
    if np.any(np.diff(knots) <= 0.0):
        # the extended curve is parametrised by positive increments (a monotone curve)
        raise ValueError(f"chemistry {chemistry!r}: its rested curve is not increasing on the kernel's knots")
    return knots


def chemistry_ocv_ends(chemistry: str) -> tuple[float, float]:
    """(empty, full) rested cell voltage of the open-circuit curve a fit of this chemistry starts from."""
    knots = ocv_knots_per_cell(chemistry)
    return float(knots[0]), float(knots[-1])


def format_record(spec: PackSpec) -> dict:
    """What a parameter set's provenance says about a pack it holds (``model_inputs`` scales from it)."""
    return {"cells_series": spec.cells_series, "cells_parallel": spec.cells_parallel,
            "capacity_mah": spec.capacity_mah, "chemistry": spec.chemistry, "full_cell_voltage": spec.full_cell_v,
            "mavlink_battery_id": spec.mavlink_battery_id}


def extended_start(spec: PackSpec) -> dict[str, float]:
    """Extended-variant starting values for the pack: the chemistry's open-circuit-voltage curve
    stretched to its full-cell voltage, the rest (written for 5S 7.8 Ah) carried to its size."""
    knots = ocv_knots_per_cell(spec.chemistry)
    ocv = knots * spec.cells_series
    stretch = spec.full_cell_v / knots[-1]
    rest = {k: v for k, v in extended_default("lipo").items() if k != "ocv_0" and not k.startswith("docv_")}
    # the non-OCV defaults are a 5S 7.8 Ah pack's: carried to this pack's cells and capacity
    return {**scale_values(rest, CELLS_PER_PACK, PACK_CAPACITY_C, spec.cells_series, spec.capacity_c),
            "ocv_0": float(ocv[0]) * stretch,
            **{f"docv_{k}": float(ocv[k] - ocv[k - 1]) * stretch for k in range(1, len(ocv))}}


def base_set(desc: VehicleDescription, model: str, reference: str = "previous_si") -> ParameterSet:
    """A parameter set of the description's packs as they are now (chemistry default scaled to each,
    or what its ``parameters`` point at), with extended-variant starting values when ``model`` is
    "extended"; its motor is the description's first motor."""
    packs = {}
    for i, spec in enumerate(desc.packs):
        p = pack_from_vector(pack_parameters(spec, f"packs[{i}]"))
        if model == "extended":
            p = dataclasses.replace(p, extended=extended_start(spec))
        packs[spec.name] = p
    motor = motor_from_vector(model_inputs(desc).motor_matrix[0]) if desc.motors else builtin(reference).motor
    return ParameterSet(name=f"{desc.name}-start", packs=packs, motor=motor,
                        description=f"the packs of {desc.name} before fitting",
                        provenance={"vehicle": desc.name,
                                    "pack_formats": {s.name: format_record(s) for s in desc.packs}})


def _source_of(spec: PackSpec) -> str:
    ref = spec.parameters
    if ref.set == "chemistry-default":
        return f"the {spec.chemistry} chemistry default scaled to {spec.cells_series}S {spec.capacity_mah:.0f} mAh"
    return f"pack {ref.pack} of {ref.set}" + (" scaled to this pack" if ref.scale_to_pack else "")


def fit_packs(desc: VehicleDescription, read: Callable[[Sequence[Path], str], list],
              splits: Mapping[str, Sequence[Path]], settings, packs: Sequence[str] | None = None,
              progress: Callable[[str], Callable] | None = None) -> tuple[ParameterSet, dict]:
    """Fit each named pack (default: all) of ``desc``; ``read(paths, pack)`` gives a split's flights
    of one pack. Returns the merged set (its packs are the description's) and the FitResult per pack."""
    from gcs_pdm.fitting.procedure import fit_battery, merge_results

    start = base_set(desc, settings.model, settings.reference)
    results = {}
    for name in packs or desc.pack_names:
        spec = next(s for s in desc.packs if s.name == name)
        train, val, test = (read(splits[k], name) for k in ("train", "validation", "test"))
        res = fit_battery(train, val, test, settings, pack=name, base_set=start, pack_format=pack_format(spec),
                          progress=progress(name) if progress else None)
        if not res.thermal.get("fitted", True):
            th = start.packs[name].thermal
            res.thermal["reason"] += (f"; C_t = {th.C_t:.4g} J/K and h = {th.h:.4g} W/K are {_source_of(spec)}")
            res.thermal["kept_from"] = _source_of(spec)
        results[name] = res
    merged = merge_results(start, results, name=f"{desc.name}-fitted",
                           description=f"the packs of vehicle {desc.name} learned from flight logs",
                           provenance={"vehicle": desc.name, "model": settings.model,
                                       "pack_formats": {s.name: format_record(s) for s in desc.packs},
                                       "files": {k: [str(p) for p in v] for k, v in splits.items()}})
    return merged, results


def fit_motors(desc: VehicleDescription, read: Callable[[Sequence[Path], str | None], list],
               splits: Mapping[str, Sequence[Path]], settings, progress: Callable | None = None,
               ) -> tuple[ParameterSet, dict]:
    """The description's motors (their ESC indices; one thermal model for all, as the paper's pair)
    fitted from the logs; the set's packs are the description's as they are."""
    from gcs_pdm.fitting.procedure import fit_motor, merge_results

    start = base_set(desc, "paper", settings.reference)
    train, val, test = (read(splits[k], None) for k in ("train", "validation", "test"))
    res = fit_motor(train, val, test, settings, base_set=start, progress=progress)
    merged = merge_results(start, {}, res, name=f"{desc.name}-fitted",
                           description=f"the motors of vehicle {desc.name} learned from flight logs",
                           provenance={"vehicle": desc.name,
                                       "pack_formats": {s.name: format_record(s) for s in desc.packs},
                                       "files": {k: [str(p) for p in v] for k, v in splits.items()}})
    return merged, {"motor": res}


#: a flight's start read this far outside [0, 1] says the pack's full voltage is not the description's
START_SOC_SLACK = 0.05


def start_soc_warnings(res, spec: PackSpec) -> list[str]:
    """Flights whose start the fitted pack reads outside [0, 1]: the circuit is full at the
    description's full-cell voltage, so a pack resting below/above it starts "below empty"/"above
    full", and the fit bends the end-of-discharge terms to make up for it (docs/vehicles.md)."""
    out = []
    for p in res.predictions:
        soc = p.initial_soc
        if soc is not None and not (-START_SOC_SLACK <= soc <= 1.0 + START_SOC_SLACK):
            out.append(f"{p.name}: starts at SoC {soc:.2f} with full at {spec.full_cell_v:.2f} V/cell; set the "
                       f"pack's full_cell_voltage to what it rests at when full, then fit again")
    return sorted(set(out))


def described_with(desc: VehicleDescription, set_path: str | Path, packs: Sequence[str],
                   motors: bool = False) -> VehicleDescription:
    """``desc`` with the named packs' parameters (and with ``motors`` every motor's) taken from the
    fitted set at ``set_path``."""
    data = desc.to_dict()
    where = str(Path(set_path).resolve())
    for p in data["packs"]:
        if p["name"] in packs:
            p["parameters"] = {"set": where, "pack": p["name"], "scale_to_pack": False}
    for m in data["motors"] if motors else ():
        m.pop("values", None)
        m["parameter_set"] = where
    return from_dict(data)


def write_fitted(desc: VehicleDescription, merged: ParameterSet, packs: Sequence[str], out: Path,
                 motors: bool = False) -> tuple[Path, Path]:
    """``out/parameters.json`` and ``out/vehicle.toml`` (the description pointing at it)."""
    out.mkdir(parents=True, exist_ok=True)
    set_path = out / "parameters.json"
    set_path.write_text(merged.to_json(indent=2))
    desc_path = out / "vehicle.toml"
    desc_path.write_text(dumps(described_with(desc, set_path, packs, motors)))
    return set_path, desc_path
