"""Learn a whole ParameterSet — every pack and the motors — from tlogs (each tlog holds every pack
and the motors), with the full procedure per component."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

from gcs_pdm.fitting.logs import read_flights
from gcs_pdm.fitting.procedure import FitResult, FitSettings, fit_battery, fit_motor, merge_results
from gcs_pdm.models.params import ParameterSet, builtin

if TYPE_CHECKING:  # pragma: no cover
    from gcs_pdm.vehicle.description import VehicleDescription


def learn_from_tlogs(train: Sequence[str | Path], val: Sequence[str | Path], test: Sequence[str | Path],
                     settings: FitSettings, vehicle: "VehicleDescription", *, name: str = "learned",
                     provenance: Mapping[str, Any] | None = None,
                     progress: Callable[[float, str], None] | None = None,
                     should_stop: Callable[[], bool] | None = None) -> tuple[ParameterSet, dict[str, FitResult]]:
    """(learned set over ``settings.base``, fit result per pack and ``"motor"``). The ``vehicle``
    description says where each pack is in the tlogs; its pack names must be the base set's (the
    learned set replaces them there: ``edge540`` and a set of the paper's layout)."""
    base = builtin(settings.base)
    unknown = [p for p in vehicle.pack_names if p not in base.packs]
    if unknown:  # said before an hour of fitting, not after it
        raise ValueError(f"vehicle {vehicle.name}: pack(s) {', '.join(unknown)} are not in the base set "
                         f"{base.name!r} ({', '.join(base.packs)})")
    parts = vehicle.pack_names + ("motor",)
    results: dict[str, FitResult] = {}
    for j, part in enumerate(parts):
        def prog(f, stage, j=j, part=part):
            if progress is not None:
                progress((j + f) / len(parts), f"{part}: {stage}")
        kind = "motor" if part == "motor" else "battery"

        def load(paths):
            return [fl for p in paths for fl in read_flights(p, kind, pack=part if kind == "battery" else "all",
                                                              vehicle=vehicle)]
        split = (load(train), load(val), load(test))
        if kind == "motor":
            results[part] = fit_motor(*split, settings, progress=prog, should_stop=should_stop)
        else:
            results[part] = fit_battery(*split, settings, pack=part, progress=prog, should_stop=should_stop)
    prov = {"files": {"train": [str(p) for p in train], "validation": [str(p) for p in val],
                      "test": [str(p) for p in test]}, **(provenance or {})}
    merged = merge_results(base, {p: results[p] for p in vehicle.pack_names}, results["motor"], name=name,
                           provenance=prov)
    return merged, results
