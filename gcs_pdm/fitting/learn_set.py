"""Learn a whole ParameterSet — all four packs and the motors — from tlogs (each tlog holds every
pack and both motors), with the full procedure per component."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from gcs_pdm.fitting.logs import read_flights
from gcs_pdm.fitting.procedure import FitResult, FitSettings, fit_battery, fit_motor, merge_results
from gcs_pdm.models.params import PACK_NAMES, ParameterSet, builtin

PARTS = PACK_NAMES + ("motor",)


def learn_from_tlogs(train: Sequence[str | Path], val: Sequence[str | Path], test: Sequence[str | Path],
                     settings: FitSettings = FitSettings(), *, name: str = "learned",
                     provenance: Mapping[str, Any] | None = None,
                     progress: Callable[[float, str], None] | None = None,
                     should_stop: Callable[[], bool] | None = None) -> tuple[ParameterSet, dict[str, FitResult]]:
    """(learned set over ``settings.base``, fit result per pack and ``"motor"``)."""
    results: dict[str, FitResult] = {}
    for j, part in enumerate(PARTS):
        def prog(f, stage, j=j, part=part):
            if progress is not None:
                progress((j + f) / len(PARTS), f"{part}: {stage}")
        kind = "motor" if part == "motor" else "battery"

        def load(paths):
            return [fl for p in paths for fl in read_flights(p, kind, pack=part if kind == "battery" else "all")]
        split = (load(train), load(val), load(test))
        if kind == "motor":
            results[part] = fit_motor(*split, settings, progress=prog, should_stop=should_stop)
        else:
            results[part] = fit_battery(*split, settings, pack=part, progress=prog, should_stop=should_stop)
    prov = {"files": {"train": [str(p) for p in train], "validation": [str(p) for p in val],
                      "test": [str(p) for p in test]}, **(provenance or {})}
    merged = merge_results(builtin(settings.base), {p: results[p] for p in PACK_NAMES}, results["motor"], name=name,
                           provenance=prov)
    return merged, results
