"""Fitting as a background job: flights from stored tlogs or uploaded files → the fitting
package's pure API (``fit_battery`` per pack, ``fit_motor``) → a merged parameter set in the store
(with provenance), ``result.json`` and plots on disk.

The job only translates: which files, which packs, where the results go; reading flights and
writing ``result.json``, predictions and plots are ``gcs_pdm.fitting.logs``'. The search itself
(SA → LM, train/validation/test) is ``gcs_pdm.fitting``'s.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Callable

from gcs_pdm.service.jobs import JobCancelled

log = logging.getLogger(__name__)


#: the request's ``settings``: top-level FitSettings fields a client may set (``base`` is the job's
#: ``base_set``), with ``search`` and ``cleaning`` as objects of SearchSettings/CleaningSettings fields
SETTINGS_TOP = ("model", "search", "cleaning", "reference", "init_samples", "soc_offset_range", "workers")


def _type_ok(value, default) -> bool:
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, type(default))


def check_settings(settings: dict) -> tuple[str, str] | None:
    """The first bad key of a fit request's ``settings`` as (dotted field, message), or None."""
    import dataclasses

    from gcs_pdm.fitting.cleaning import CleaningSettings
    from gcs_pdm.fitting.procedure import FitSettings
    from gcs_pdm.fitting.search import SearchSettings

    defaults = FitSettings()
    from gcs_pdm.models.variants import MODEL_VARIANTS

    for key, value in settings.items():
        if key not in SETTINGS_TOP:
            return f"settings.{key}", f"unknown fit setting {key!r}; expected one of {', '.join(SETTINGS_TOP)}"
        if key == "model":
            if value not in MODEL_VARIANTS:
                return "settings.model", f"expected one of {', '.join(MODEL_VARIANTS)}, got {value!r}"
            continue
        if key in ("search", "cleaning"):
            cls = SearchSettings if key == "search" else CleaningSettings
            if not isinstance(value, dict):
                return f"settings.{key}", f"{key} must be an object of {cls.__name__} fields"
            fields = {f.name: getattr(cls(), f.name) for f in dataclasses.fields(cls)}
            for k, v in value.items():
                if k not in fields:
                    return (f"settings.{key}.{k}",
                            f"unknown {key} setting {k!r}; expected one of {', '.join(fields)}")
                if not _type_ok(v, fields[k]):
                    return f"settings.{key}.{k}", f"expected {type(fields[k]).__name__}, got {v!r}"
        elif not _type_ok(value, getattr(defaults, key)):
            return f"settings.{key}", f"expected {type(getattr(defaults, key)).__name__}, got {value!r}"
        elif key == "reference":
            from gcs_pdm.models.params import BUILTIN_SETS

            if value not in BUILTIN_SETS:
                return f"settings.{key}", f"reference must be a built-in set: {', '.join(BUILTIN_SETS)}"
    return None


def check_save_as(service, name: str | None, overwrite: bool = False) -> str | None:
    """Why ``save_as`` cannot take the fit's result, or None: never a built-in or the active set
    (the vehicle's estimator and planner use it), an existing set only with ``overwrite``."""
    if not name:
        return None
    existing = {p["name"]: p for p in service.store.parameter_sets()}
    if name not in existing:
        return None
    if existing[name].get("builtin"):
        return f"{name!r} is a built-in parameter set"
    if name == service.store.active_parameter_set_name():
        return f"{name!r} is the active parameter set"
    if not overwrite:
        return f"parameter set {name!r} exists (set overwrite to replace it)"
    return None


def make_fit_job(service) -> Callable:
    def fit_job(request: dict, progress: Callable[[float, str], None], should_stop: Callable[[], bool]) -> dict:
        from gcs_pdm.fitting.logs import read_flights, write_outputs
        from gcs_pdm.fitting.procedure import FitSettings, fit_battery, fit_motor, merge_results
        from gcs_pdm.fitting.search import FitCancelled, SearchSettings
        from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

        job_dir = service.config.data_path / "jobs" / request.get("_job_id", "fit")
        job_dir.mkdir(parents=True, exist_ok=True)
        component = request["component"]
        refs = request["flights"]
        base = service.store.parameter_set(request["base_set"])
        opts = dict(request.get("settings") or {})
        search = SearchSettings(**opts.pop("search", {}))
        if "cleaning" in opts:
            from gcs_pdm.fitting.cleaning import CleaningSettings

            opts["cleaning"] = CleaningSettings(**opts["cleaning"])
        ref_name = opts.pop("reference", "previous_si")
        # the values not learned come from the requested base set itself (a user's set too)
        # the extended variant unless asked otherwise (issue 15: the default for new fits). The
        # estimator and the Monte Carlo fly an extended pack on its extended values; the planner's
        # vehicle simulator still flies its paper values, and /status says so once the set is active.
        model = opts.pop("model", "extended")
        settings = FitSettings(search=search, base=base.name, reference=ref_name, model=model, **opts)
        targets = list(request["packs"]) if component == "battery" else [None]
        # the request names the paper's packs (schemas.PackName) and the result is merged over a set
        # of the paper's layout: the flights are read as the paper's aircraft's, the edge540 preset
        # (a tlog's packs at BATTERY_STATUS ids 0-3, an autopilot log's at battery instances 0-3)
        paper = PRESETS[DEFAULT_PRESET]
        results, body = {}, {"component": component, "fits": {}, "plots": {}}
        for k, pack in enumerate(targets):
            lo, hi = k / len(targets), (k + 1) / len(targets)
            label = pack or "motor"

            def part(fraction: float, stage: str = "", lo=lo, hi=hi, label=label) -> None:
                progress(lo + (hi - lo) * fraction, f"{label}: {stage}")

            part(0.0, "loading flights")
            splits = {s: [f for ref in refs.get(s, [])
                          for f in read_flights(service.resolve_flight_ref(ref), component, pack or "all",
                                                vehicle=paper)]
                      for s in ("train", "validation", "test")}
            try:
                if component == "battery":
                    res = fit_battery(splits["train"], splits["validation"], splits["test"], settings, pack=pack,
                                      progress=part, should_stop=should_stop, base_set=base)
                else:
                    res = fit_motor(splits["train"], splits["validation"], splits["test"], settings,
                                    progress=part, should_stop=should_stop, base_set=base)
            except FitCancelled as exc:
                raise JobCancelled(str(exc)) from None
            results[label] = res
            body["fits"][label] = res.to_dict()
            written = write_outputs(res, job_dir / label)
            body["plots"].update({f"{label}_{Path(k).name}": str(v) for k, v in written.items() if k.startswith("plots/")})
        merged = merge_results(base, {p: r for p, r in results.items() if p != "motor"}, results.get("motor"),
                               name=request.get("save_as") or f"fit_{request.get('_job_id', 'job')}",
                               provenance={"source": "fit job", "job": request.get("_job_id")})
        body["parameter_set"] = merged.to_dict()
        (job_dir / "result.json").write_text(json.dumps(body, default=str, indent=1))
        if request.get("save_as"):
            # checked at submission; checked again now (the set may have been activated meanwhile). A
            # refusal keeps the result (result.json and the job's result hold the merged set).
            problem = check_save_as(service, merged.name, bool(request.get("overwrite")))
            if problem is None:
                try:
                    service.store.save_parameter_set(merged, provenance={"source": "fit", "job": request.get("_job_id")},
                                                     overwrite=bool(request.get("overwrite")))
                except Exception as exc:  # noqa: BLE001 - recorded in the result, the fit is kept
                    problem = str(exc)
            if problem is None:
                body["saved_as"] = merged.name
            else:
                log.warning("fit %s: result not saved as %r: %s", request.get("_job_id"), merged.name, problem)
                body["save_error"] = problem
            (job_dir / "result.json").write_text(json.dumps(body, default=str, indent=1))
        return body

    return fit_job
